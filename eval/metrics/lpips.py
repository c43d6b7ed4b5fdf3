"""LPIPS (Zhang et al. 2018), AlexNet variant, in plain torch (no torchvision, no download).

Network: the AlexNet `features` convolutions (torchvision layout)
    conv0 3->64   k11 s4 p2, ReLU [tap 1], maxpool 3/2
    conv3 64->192 k5  s1 p2, ReLU [tap 2], maxpool 3/2
    conv6 192->384 k3 s1 p1, ReLU [tap 3]
    conv8 384->256 k3 s1 p1, ReLU [tap 4]
    conv10 256->256 k3 s1 p1, ReLU [tap 5]
LPIPS(x, y) = sum_l mean_hw( w_l . (n(f_l(x)) - n(f_l(y)))^2 ), with n() the unit-normalisation over
channels
(f / (||f||_2 + 1e-10)) and w_l >= 0 the 1x1 linear head of tap l. Inputs pass through the LPIPS
scaling layer
(x - shift) / scale with shift = (-0.030, -0.088, -0.188), scale = (0.458, 0.448, 0.450) (published
constants).

Input scaling: images in [0, 1]; `normalize_input=True` (standard) maps them to [-1, 1] first;
`normalize_input=False` feeds [0, 1] as the authors did (labelled convention "lpips_unnormalized").

Weights: ONE user-supplied torch file (`torch.save` of a dict of tensors; a top-level {"state_dict":
{...}} also works) holding both
  - the AlexNet convolutions, as torchvision names  features.{0,3,6,8,10}.{weight,bias}
    or as the lpips package's full-model names     net.slice{1..5}.{0,3,6,8,10}.{weight,bias}
  - the linear heads, as the lpips names           lin{0..4}.model.1.weight   ([1, C, 1, 1]; with
    dropout) or                                             lin{0..4}.model.0.weight   (heads saved
    without dropout)
Any missing tensor raises a KeyError naming the missing key; wrong shapes raise a ValueError.
Without a weights file, `lpips()` returns None and tables print "n/a" (never a made-up number).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from m4dgs.core.io import atomic_target

from ._util import as_tensor, batched, check_pair

# (torchvision index, in channels, out channels, kernel, stride, padding)
ALEX_CONVS = (
    (0, 3, 64, 11, 4, 2),
    (3, 64, 192, 5, 1, 2),
    (6, 192, 384, 3, 1, 1),
    (8, 384, 256, 3, 1, 1),
    (10, 256, 256, 3, 1, 1),
)
TAP_CHANNELS = (64, 192, 384, 256, 256)
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)
NORM_EPS = 1e-10
# the lpips package's slice number holding each torchvision conv index
_SLICE_OF = {0: 1, 3: 2, 6: 3, 8: 4, 10: 5}

CONVENTIONS = {
    "lpips": "LPIPS: AlexNet v0.1, inputs rescaled from [0,1] to [-1,1]",
    "lpips_unnormalized": "LPIPS: AlexNet v0.1, [0,1] inputs fed without rescaling to [-1,1] (as "
    "in the authors' "
    "code)",
    "lpips_na": "LPIPS: n/a without a user-supplied AlexNet + LPIPS weights file",
}


@dataclass
class LpipsWeights:
    """Canonical weights: conv_w[i] [Cout, Cin, k, k], conv_b[i] [Cout], lin[i] [1, C_i, 1, 1] (i =
    0..4)."""

    conv_w: list
    conv_b: list
    lin: list

    def to(self, device=None, dtype=None) -> "LpipsWeights":
        def mv(t):
            return t.to(device=device, dtype=dtype)

        return LpipsWeights(
            [mv(t) for t in self.conv_w], [mv(t) for t in self.conv_b], [mv(t) for t in self.lin]
        )

    def state_dict(self) -> dict:
        """Torchvision + lpips key layout (the file format `load_lpips_weights` reads)."""
        sd = {}
        for (idx, *_), w, b in zip(ALEX_CONVS, self.conv_w, self.conv_b):
            sd[f"features.{idx}.weight"] = w
            sd[f"features.{idx}.bias"] = b
        for i, l in enumerate(self.lin):
            sd[f"lin{i}.model.1.weight"] = l
        return sd


def _pick(sd: dict, candidates: list[str]) -> torch.Tensor:
    for k in candidates:
        if k in sd:
            return sd[k]
    raise KeyError(f"LPIPS weights: missing key {candidates[0]!r} (also tried {candidates[1:]})")


def weights_from_state_dict(sd: dict) -> LpipsWeights:
    """Map a state dict (layouts in the module docstring) to canonical weights, checking every
    shape."""
    if "state_dict" in sd and isinstance(sd["state_dict"], dict):
        sd = sd["state_dict"]
    conv_w, conv_b, lin = [], [], []
    for idx, cin, cout, k, _, _ in ALEX_CONVS:
        s = _SLICE_OF[idx]
        w = _pick(sd, [f"features.{idx}.weight", f"net.slice{s}.{idx}.weight"])
        b = _pick(sd, [f"features.{idx}.bias", f"net.slice{s}.{idx}.bias"])
        if tuple(w.shape) != (cout, cin, k, k) or tuple(b.shape) != (cout,):
            raise ValueError(
                f"LPIPS weights: conv features.{idx} has shapes {tuple(w.shape)}/{tuple(b.shape)}, "
                f"expected {(cout, cin, k, k)}/{(cout,)}"
            )
        conv_w.append(w.detach().float())
        conv_b.append(b.detach().float())
    for i, c in enumerate(TAP_CHANNELS):
        l = _pick(sd, [f"lin{i}.model.1.weight", f"lin{i}.model.0.weight"])
        if tuple(l.shape) != (1, c, 1, 1):
            raise ValueError(
                f"LPIPS weights: lin{i} has shape {tuple(l.shape)}, expected {(1, c, 1, 1)}"
            )
        if bool((l < 0).any()):
            raise ValueError(
                f"LPIPS weights: lin{i} has negative weights (LPIPS heads are non-negative)"
            )
        lin.append(l.detach().float())
    return LpipsWeights(conv_w, conv_b, lin)


def load_lpips_weights(path: str | os.PathLike) -> LpipsWeights:
    """Read the single LPIPS weights file (see module docstring for the accepted key layouts)."""
    sd = torch.load(os.fspath(path), map_location="cpu", weights_only=True)
    if not isinstance(sd, dict):
        raise ValueError(
            f"LPIPS weights: {path} does not hold a state dict (got {type(sd).__name__})"
        )
    return weights_from_state_dict(sd)


def save_lpips_weights(weights: LpipsWeights, path: str | os.PathLike) -> None:
    """Write weights in the torchvision + lpips layout (atomic: temp file in the same folder, then
    os.replace)."""
    with atomic_target(path, ".pth") as tmp:
        torch.save(weights.state_dict(), tmp)


def alexnet_taps(x: torch.Tensor, w: LpipsWeights) -> list[torch.Tensor]:
    """The five ReLU outputs of AlexNet `features` for x [N, 3, H, W] (already scaled)."""
    taps = []
    h = x
    for i, (idx, _, _, _, stride, pad) in enumerate(ALEX_CONVS):
        if idx in (3, 6):  # max-pool after the first two ReLU taps
            h = F.max_pool2d(h, kernel_size=3, stride=2)
        h = F.relu(F.conv2d(h, w.conv_w[i], w.conv_b[i], stride=stride, padding=pad))
        taps.append(h)
    return taps


def _scale_input(img: torch.Tensor, normalize_input: bool) -> torch.Tensor:
    x = img * 2.0 - 1.0 if normalize_input else img
    shift = torch.tensor(SHIFT, dtype=x.dtype, device=x.device).view(1, 3, 1, 1)
    scale = torch.tensor(SCALE, dtype=x.dtype, device=x.device).view(1, 3, 1, 1)
    return (x - shift) / scale


def lpips_distance(
    img1: torch.Tensor, img2: torch.Tensor, weights: LpipsWeights, *, normalize_input: bool = True
) -> torch.Tensor:
    """Per-image LPIPS for [N, H, W, 3] images in [0, 1] -> [N] tensor (differentiable)."""
    w = weights.to(device=img1.device, dtype=img1.dtype)
    a = _scale_input(img1.permute(0, 3, 1, 2), normalize_input)
    b = _scale_input(img2.permute(0, 3, 1, 2), normalize_input)
    fa, fb = alexnet_taps(a, w), alexnet_taps(b, w)
    total = torch.zeros(img1.shape[0], dtype=img1.dtype, device=img1.device)
    for l, (ta, tb) in enumerate(zip(fa, fb)):
        na = ta / (ta.pow(2).sum(dim=1, keepdim=True).sqrt() + NORM_EPS)
        nb = tb / (tb.pow(2).sum(dim=1, keepdim=True).sqrt() + NORM_EPS)
        d = F.conv2d((na - nb) ** 2, w.lin[l])  # [N, 1, h, w]
        total = total + d.mean(dim=(1, 2, 3))
    return total


def lpips(
    pred,
    gt,
    weights: LpipsWeights | str | os.PathLike | None = None,
    *,
    normalize_input: bool = True,
) -> float | None:
    """LPIPS (AlexNet) of [H, W, 3] / [N, H, W, 3] images in [0, 1], mean over images; None without
    weights.

    `weights` is a LpipsWeights object or the path of the single weights file; None -> returns None
    ("n/a"). Computed in float32 on the device of `gt` (torch input) or the CPU."""
    if weights is None:
        return None
    if not isinstance(weights, LpipsWeights):
        weights = load_lpips_weights(weights)
    g = batched(as_tensor(gt, dtype=torch.float32))
    p = batched(as_tensor(pred, dtype=torch.float32, device=g.device))
    check_pair(p, g, "lpips")
    with torch.no_grad():
        return float(lpips_distance(p, g, weights, normalize_input=normalize_input).mean())
