"""HDR image metrics: mu-law PSNR / SSIM (the paper's), PU21-PSNR and HDR-FLIP (beyond the paper).

Conventions (docs/metrics.md):
- mu-law (HDR-NeRF / GaussHDR / Mono4DGS-HDR): T(H) = log(1 + mu x) / log(1 + mu), mu = 5000, with x
  = clip(H / max(H_gt), 0, 1) for the prediction AND the ground truth (GT-max normalisation,
  `norm="gt"`). `norm="own"` divides each image by its own max (HDR-GS); it hides global scale
  errors and is a labelled extra. The max is taken per image (per frame) over all pixels and
  channels.
- PU21-PSNR (Mantiuk & Azimi 2021, 'banding_glare' parameters): relative HDR is scaled so that
  max(H_gt) maps to `peak_nits` (4000 cd/m^2 by default; the choice moves the result by ~1.5 dB),
  each linear RGB channel is PU-encoded (luminance clamped to [0.005, 10000]) and PSNR uses peak
  256, as in the reference pu21_metric(..., 'PSNR').
- HDR-FLIP: NVIDIA FLIP in HDR mode (pip flip-evaluator), mean of the error map; both images divided
  by max(H_gt) (linear, non-negative) before evaluation.
"""

from __future__ import annotations

import flip_evaluator as flip
import numpy as np
import torch

from m4dgs.core.hdr import MU
from m4dgs.core.hdr import mu_law as _mu_law
from m4dgs.core.ssim import ssim as _ssim

from ._util import as_tensor, batched, check_pair, psnr_from_mse

PU21_BANDING_GLARE = (
    0.353487901,
    0.3734658629,
    8.277049286e-05,
    0.9062562627,
    0.09150303166,
    0.9099517204,
    596.3148142,
)
PU21_L_MIN = 0.005
PU21_L_MAX = 10000.0
PU21_PEAK = 256.0
PU21_DEFAULT_NITS = 4000.0

CONVENTIONS = {
    "hdr_mu_law": "HDR PSNR/SSIM: mu-law (mu=5000) on H/max(H_gt) clipped to [0,1] (prediction "
    "and GT)",
    "hdr_mu_law_own": "HDR PSNR/SSIM (own-max): mu-law (mu=5000) on H/max(H) per image (HDR-GS "
    "style; hides scale "
    "errors)",
    "pu21": "PU21-PSNR: banding_glare encoding, per RGB channel, peak 256; relative HDR scaled "
    "so max(H_gt) = "
    f"{PU21_DEFAULT_NITS:g} cd/m^2",
    "hdr_flip": "HDR-FLIP: flip-evaluator 'HDR' mode (default exposure range and ACES tone "
    "mapper), mean error map, "
    "inputs divided by max(H_gt)",
}


def mu_law(x, mu: float = MU) -> torch.Tensor:
    """mu-law tone curve log(1 + mu x) / log(1 + mu) of x clipped to [0, 1] (m4dgs.core.hdr), as a
    float64 tensor whatever the input (numpy, torch, list)."""
    return _mu_law(as_tensor(x, uint8_scale=False), mu)


def _normalise(
    pred: torch.Tensor, gt: torch.Tensor, norm: str
) -> tuple[torch.Tensor, torch.Tensor]:
    """Divide [N, H, W, C] HDR images by the per-image GT max ("gt") or each by its own max ("own"),
    clip to [0,1]."""

    def nmax(t):
        return t.amax(dim=(1, 2, 3), keepdim=True).clamp_min(1e-12)

    if norm == "gt":
        s = nmax(gt)
        return (pred / s).clamp(0, 1), (gt / s).clamp(0, 1)
    if norm == "own":
        return (pred / nmax(pred)).clamp(0, 1), (gt / nmax(gt)).clamp(0, 1)
    raise ValueError(f"norm must be 'gt' or 'own', got {norm!r}")


def hdr_tonemap_pair(
    pred, gt, *, norm: str = "gt", mu: float = MU
) -> tuple[torch.Tensor, torch.Tensor]:
    """mu-law tone-mapped prediction and ground truth, [N, H, W, C] float64 in [0, 1]."""
    g = batched(as_tensor(gt, uint8_scale=False))
    p = batched(as_tensor(pred, device=g.device, uint8_scale=False))
    check_pair(p, g, "hdr metric")
    pn, gn = _normalise(p, g, norm)
    return mu_law(pn, mu), mu_law(gn, mu)


def hdr_psnr(pred, gt, *, norm: str = "gt", mu: float = MU) -> float:
    """PSNR in the mu-law domain (data range 1), per frame then the mean. pred/gt: [H,W,3] or
    [N,H,W,3] linear HDR."""
    tp, tg = hdr_tonemap_pair(pred, gt, norm=norm, mu=mu)
    mse = ((tp - tg) ** 2).mean(dim=(1, 2, 3))
    return float(np.mean([psnr_from_mse(float(m), 1.0) for m in mse]))


def hdr_ssim(pred, gt, *, norm: str = "gt", mu: float = MU, crop: int = 0) -> float:
    """3DGS SSIM in the mu-law domain (convolutions in float32), mean over frames."""
    tp, tg = hdr_tonemap_pair(pred, gt, norm=norm, mu=mu)
    return float(_ssim(tp.float(), tg.float(), data_range=1.0, crop=crop).double().mean())


def pu21_encode(luminance, params=PU21_BANDING_GLARE) -> torch.Tensor:
    """PU21 encoding of ABSOLUTE linear values (cd/m^2), element-wise.

    V = max(p7 * (((p1 + p2 Y^p4) / (1 + p3 Y^p4))^p5 - p6), 0) with Y clamped to [0.005, 10000].
    """
    p1, p2, p3, p4, p5, p6, p7 = params
    y = as_tensor(luminance, uint8_scale=False).clamp(PU21_L_MIN, PU21_L_MAX)
    yp = y**p4
    v = p7 * (((p1 + p2 * yp) / (1.0 + p3 * yp)) ** p5 - p6)
    return v.clamp_min(0.0)


def pu21_psnr(pred, gt, *, peak_nits: float = PU21_DEFAULT_NITS, peak: float = PU21_PEAK) -> float:
    """PU21-PSNR of relative linear HDR images, per frame then the mean.

    Both images are multiplied by peak_nits / max(H_gt) (per frame), each RGB channel is
    PU21-encoded and the PSNR uses `peak` (256, as pu21_metric's 'PSNR')."""
    g = batched(as_tensor(gt, uint8_scale=False))
    p = batched(as_tensor(pred, device=g.device, uint8_scale=False))
    check_pair(p, g, "pu21_psnr")
    k = peak_nits / g.amax(dim=(1, 2, 3), keepdim=True).clamp_min(1e-12)
    ep, eg = pu21_encode(p.clamp_min(0) * k), pu21_encode(g * k)
    mse = ((ep - eg) ** 2).mean(dim=(1, 2, 3))
    return float(np.mean([psnr_from_mse(float(m), peak) for m in mse]))


def hdr_flip(pred, gt) -> float:
    """Mean HDR-FLIP error (lower is better) over frames; both images divided by max(H_gt),
    negatives clipped.

    Uses pip `flip-evaluator` (CPU): flip.evaluate(reference, test, "HDR") with its default exposure
    range (computed from the reference) and ACES tone mapper."""
    g = batched(as_tensor(gt, uint8_scale=False))
    p = batched(as_tensor(pred, device=g.device, uint8_scale=False))
    check_pair(p, g, "hdr_flip")
    if p.shape[-1] != 3:
        raise ValueError("hdr_flip: needs RGB images [.., H, W, 3]")
    s = g.amax(dim=(1, 2, 3), keepdim=True).clamp_min(1e-12)
    vals = []
    for pi, gi in zip((p / s).clamp_min(0), (g / s).clamp_min(0)):
        ref = np.ascontiguousarray(gi.cpu().numpy().astype(np.float32))
        test = np.ascontiguousarray(pi.cpu().numpy().astype(np.float32))
        _, mean_err, _ = flip.evaluate(ref, test, "HDR", applyMagma=False)
        vals.append(float(mean_err))
    return float(np.mean(vals))
