"""Learned logarithmic-domain tone mapper phi (paper Sec. 3.1 "HDR Gaussian Splatting"; appendix
"Implementation Details").

The LDR colour of an HDR irradiance H seen with exposure time dt is ``L = phi(log2(H + eps) +
log2(dt))`` (the paper writes phi(log(e dt)); the authors' code uses log2 with eps = 1e-6 and stores
exposures as log2 values, which only rescales the input axis). phi is three independent per-channel
MLPs ``Linear(1, 128) - Softplus - Linear(128, 1) - Sigmoid``. Here the three MLPs are stored as
stacked parameter tensors and evaluated with one einsum, so the cost does not grow with a Python
loop over channels.

Before training with the scene the authors pre-train phi for 1,000 iterations on a reference CRF
that is equal for R, G and B, with a monotonicity penalty and the unit-exposure term
(`pretrain_tonemapper`). The reference curve is a callable argument (e.g.
``m4dgs.core.crf.get_crf("hdrnerf")``), so this module does not depend on the CRF library."""

from __future__ import annotations

import math
from typing import Callable

import torch
import torch.nn as nn
import torch.nn.functional as F

from m4dgs.core.errors import NonFiniteError

#: eps added to the HDR irradiance before the logarithm (authors' code).
LOG_EPS = 1e-6


class ToneMapper(nn.Module):
    """Three per-channel MLPs phi_c: R -> (0, 1), evaluated in one batched einsum.

    Parameters (C = n_channels, D = hidden):
        w1 [C, D], b1 [C, D]: first layer (Linear(1, D) of each channel);
        w2 [C, D], b2 [C]:    second layer (Linear(D, 1) of each channel).
    Initialisation follows torch.nn.Linear (uniform in +-1/sqrt(fan_in)), so a channel is
    distributed exactly like ``nn.Sequential(nn.Linear(1, D), nn.Softplus(), nn.Linear(D, 1),
    nn.Sigmoid())``."""

    def __init__(
        self,
        hidden: int = 128,
        n_channels: int = 3,
        eps: float = LOG_EPS,
        generator: torch.Generator | None = None,
        lut_size: int = 512,
    ):
        super().__init__()
        self.lut_size = int(lut_size)
        self.hidden = int(hidden)
        self.n_channels = int(n_channels)
        self.eps = float(eps)
        c, d = self.n_channels, self.hidden

        def uni(shape, bound):
            return (torch.rand(shape, generator=generator) * 2.0 - 1.0) * bound

        self.w1 = nn.Parameter(uni((c, d), 1.0))  # fan_in 1
        self.b1 = nn.Parameter(uni((c, d), 1.0))
        self.w2 = nn.Parameter(uni((c, d), 1.0 / math.sqrt(d)))  # fan_in D
        self.b2 = nn.Parameter(uni((c,), 1.0 / math.sqrt(d)))

    def curve(self, z: torch.Tensor) -> torch.Tensor:
        """Evaluate phi on log2 exposures.

        Args:
            z: [..., C] log2 exposure per channel (log2(H) + log2(dt)); a [..., 1] input is
            broadcast to all channels.
        Returns:
            [..., C] LDR values in (0, 1).
        """
        h = F.softplus(z.unsqueeze(-1) * self.w1 + self.b1)  # [..., C, D]
        out = torch.einsum("...cd,cd->...c", h, self.w2) + self.b2
        return torch.sigmoid(out)

    def forward(self, hdr: torch.Tensor, log2_dt) -> torch.Tensor:
        """Tone-map HDR irradiance at an exposure.

        Args:
            hdr: [..., C] non-negative HDR irradiance. log2_dt: exposure as log2(dt): a float, a 0-d
            tensor, or a tensor of shape [...] (hdr.shape[:-1] or
                broadcastable to it, e.g. [B, 1, 1] for a batch of [B, H, W, C] images).
        Returns:
            [..., C] LDR colour in (0, 1): phi(log2(hdr + eps) + log2_dt).
        """
        z = torch.log2(hdr + self.eps)
        if isinstance(log2_dt, torch.Tensor) and log2_dt.dim() > 0:
            z = z + log2_dt.to(z.dtype).unsqueeze(-1)
        else:
            z = z + log2_dt
        if (
            self.lut_size > 1
            and z.numel() > 4 * self.lut_size * self.n_channels
            and z.shape[-1] == self.n_channels
        ):
            return self.curve_lut(z)
        return self.curve(z)

    def curve_lut(self, z: torch.Tensor) -> torch.Tensor:
        """phi through a piecewise-linear table of `lut_size` nodes spanning [min z, max z] of the
        input.

        The MLP is evaluated only at the nodes (cost independent of the image size: the exact path
        costs [H W, C, hidden] activations); values and gradients (w.r.t. z and the parameters) are
        those of the interpolant, whose error is below ~1e-5 for the smooth curves learned here
        (checked in the tests). Raises NonFiniteError when z holds NaN or infinite values."""
        c = self.n_channels
        zd = z.detach()
        lo, hi = torch.stack(torch.aminmax(zd)).tolist()  # one read from the device, not two
        if not (math.isfinite(lo) and math.isfinite(hi)):
            # NaN or an overflowed HDR value would otherwise become an out-of-range table index
            raise NonFiniteError(
                f"the tone mapper's input log2(H + eps) + log2(dt) spans {lo} .. {hi}: the HDR "
                "render holds NaN or values beyond float32's range"
            )
        if not hi > lo:
            return self.curve(z)
        nodes = torch.linspace(lo, hi, self.lut_size, dtype=z.dtype, device=z.device)
        table = self.curve(nodes[:, None].expand(-1, c))  # [L, C]
        pos = (z - lo) * ((self.lut_size - 1) / (hi - lo))
        i0 = pos.detach().floor().clamp(0, self.lut_size - 2).long()
        w = pos - i0.to(pos.dtype)
        ch = torch.arange(c, device=z.device)
        return table[i0, ch] * (1.0 - w) + table[i0 + 1, ch] * w

    def unit_exposure_value(self) -> torch.Tensor:
        """phi(0) per channel, shape [C] (the value constrained by the unit-exposure loss)."""
        return self.curve(self.w1.new_zeros(1, self.n_channels))[0]


def monotonicity_penalty(
    tm: ToneMapper, z_min: float = -10.0, z_max: float = 10.0, n: int = 1024
) -> torch.Tensor:
    """Mean ReLU of the negative slope of phi over a dense grid of its input z in [z_min, z_max].

    The authors apply it on the tone mapper's input axis over [-10, 10] (they call the axis ln x; it
    is the log2 exposure fed to the MLP). The slope is a finite difference on the sorted grid, so
    the penalty is zero exactly when phi is non-decreasing between grid points; summed over
    channels.

    Returns:
        scalar tensor.
    """
    z = torch.linspace(z_min, z_max, n, dtype=tm.w1.dtype, device=tm.w1.device)[:, None]
    y = tm.curve(z)  # [n, C]
    slope = (y[1:] - y[:-1]) / (z[1:] - z[:-1])
    return F.relu(-slope).mean(dim=0).sum()


def pretrain_tonemapper(
    tm: ToneMapper,
    target_crf: Callable[[torch.Tensor], torch.Tensor],
    *,
    iters: int = 1000,
    lr: float = 5e-3,
    z_range: tuple[float, float] = (-10.0, 10.0),
    n_samples: int = 512,
    mono_weight: float = 10.0,
    ue_weight: float = 10.0,
    c0: float | None = None,
) -> dict:
    """Fit phi to a reference CRF, equal for every channel (authors: 1,000 iterations before scene
    training).

    Loss = mean_c,z (phi_c(z) - f(2^z))^2 + mono_weight * monotonicity_penalty + ue_weight * mean_c
    (phi_c(0) - c0)^2, on a fixed grid of z (log2 exposure) in ``z_range``; Adam with learning rate
    ``lr``. Deterministic.

    Args:
        tm: the tone mapper (modified in place). target_crf: f(x) for linear exposure x = H * dt > 0
        (torch tensor in, same shape out, values in [0, 1]),
            e.g. the HDR-NeRF CRF (x / (x + 1)) ** (1 / 2.2).
        c0: unit-exposure target; defaults to f(1).
    Returns:
        dict with the final "fit", "mono", "ue" and "total" loss values (floats).
    """
    dev, dt = tm.w1.device, tm.w1.dtype
    z = torch.linspace(z_range[0], z_range[1], n_samples, dtype=dt, device=dev)[:, None]
    with torch.no_grad():
        target = target_crf(torch.exp2(z)).to(dt)  # [n, 1]
        if c0 is None:
            c0 = float(target_crf(torch.ones(1, dtype=dt, device=dev)).reshape(-1)[0])
    opt = torch.optim.Adam(tm.parameters(), lr=lr)
    fit = mono = ue = total = torch.zeros(())
    for _ in range(int(iters)):
        opt.zero_grad(set_to_none=True)
        fit = ((tm.curve(z) - target) ** 2).mean()
        mono = monotonicity_penalty(tm, z_range[0], z_range[1], n_samples)
        ue = ((tm.unit_exposure_value() - c0) ** 2).mean()
        total = fit + mono_weight * mono + ue_weight * ue
        total.backward()
        opt.step()
    return {
        "fit": float(fit.detach()),
        "mono": float(mono.detach()),
        "ue": float(ue.detach()),
        "total": float(total.detach()),
    }
