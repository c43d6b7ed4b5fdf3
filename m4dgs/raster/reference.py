"""The ``torch`` backend: a slow, obvious, dense alpha-compositing reference (the test oracle and
the fallback).

Every pixel sees every visible Gaussian, sorted front to back; the same thresholds as the tile
rasterizers: alpha = min(0.999, o exp(-sigma)), contributions with alpha < 1/255 (or sigma < 0) are
dropped, and a Gaussian is kept only while the transmittance after it stays above 1e-4. Pixels are
processed in chunks; inside a chunk only the Gaussians that reach alpha >= 1/255 somewhere in the
chunk are kept (the others contribute exactly zero), which keeps memory bounded. No tiles and no
radii are used, so it also checks the binning of the tile backends. Works on any device; fine for
tests and small scenes."""

from __future__ import annotations

import torch
from torch import Tensor

from .projection import ALPHA_THRESHOLD

ALPHA_MAX = 0.999
T_MIN = 1e-4


def _alpha(pix: Tensor, means2d: Tensor, conics: Tensor, opacities: Tensor) -> Tensor:
    """Gated alpha [P, n] of n Gaussians at pixel centres pix [P, 2] (zero where skipped)."""
    d = means2d[None, :, :] - pix[:, None, :]  # [P, n, 2]
    dx, dy = d[..., 0], d[..., 1]
    sigma = 0.5 * (conics[:, 0] * dx * dx + conics[:, 2] * dy * dy) + conics[:, 1] * dx * dy
    alpha = torch.clamp_max(opacities[None, :] * torch.exp(-sigma), ALPHA_MAX)
    keep = (alpha >= ALPHA_THRESHOLD) & (sigma >= 0)
    return torch.where(keep, alpha, torch.zeros_like(alpha))


def rasterize_dense(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    features: Tensor,
    depths: Tensor,
    visible: Tensor,
    width: int,
    height: int,
    chunk: int = 256,
) -> tuple[Tensor, Tensor]:
    """Composite visible Gaussians (means2d [N, 2], conics [N, 3], opacities [N], features [N, C],
    depths [N], visible [N] bool) into features [H, W, C] and alpha [H, W, 1] (no background).
    Differentiable."""
    device, dtype = means2d.device, means2d.dtype
    n_ch = features.shape[1]
    ids = torch.nonzero(visible).squeeze(1)
    ids = ids[torch.argsort(depths.detach()[ids], stable=True)]  # front to back
    m, con, op, f = (
        means2d[ids],
        conics[ids].to(dtype),
        opacities[ids].to(dtype),
        features[ids].to(dtype),
    )
    ys, xs = torch.meshgrid(
        torch.arange(height, device=device, dtype=dtype),
        torch.arange(width, device=device, dtype=dtype),
        indexing="ij",
    )
    pixels = torch.stack([xs.reshape(-1), ys.reshape(-1)], dim=-1) + 0.5  # [P, 2] pixel centres
    out_f, out_a = [], []
    for start in range(0, pixels.shape[0], chunk):
        pix = pixels[start : start + chunk]
        with torch.no_grad():
            cols = torch.nonzero((_alpha(pix, m, con, op) > 0).any(dim=0)).squeeze(1)
        if cols.numel() == 0:
            out_f.append(torch.zeros(pix.shape[0], n_ch, device=device, dtype=dtype))
            out_a.append(torch.zeros(pix.shape[0], device=device, dtype=dtype))
            continue
        alpha = _alpha(pix, m[cols], con[cols], op[cols])  # [P, n], front to back
        with torch.no_grad():
            # stop (exclusive) once T would drop <= 1e-4
            included = torch.cumprod(1.0 - alpha, dim=1) > T_MIN
        alpha = alpha * included
        one_minus = 1.0 - alpha
        t_after = torch.cumprod(one_minus, dim=1)
        t_before = torch.cat([torch.ones_like(t_after[:, :1]), t_after[:, :-1]], dim=1)
        weights = alpha * t_before
        out_f.append(weights @ f[cols])
        out_a.append(1.0 - t_after[:, -1])
    feat = torch.cat(out_f, dim=0).reshape(height, width, n_ch)
    alpha = torch.cat(out_a, dim=0).reshape(height, width, 1)
    if not feat.requires_grad and torch.is_grad_enabled():
        # nothing visible: keep the (all-zero) outputs attached to the inputs, as the compiled
        # backends do
        anchor = (
            sum(t.sum() for t in (means2d, conics, opacities, features) if t.requires_grad) * 0.0
        )
        if isinstance(anchor, Tensor):
            feat, alpha = feat + anchor, alpha + anchor
    return feat, alpha
