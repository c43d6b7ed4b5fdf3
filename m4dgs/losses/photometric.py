"""Photometric losses on LDR renders (paper appendix "Supervision from 2D Priors").

- LDR RGB loss: L_rgb = lambda_d * DSSIM(L~, L) + (1 - lambda_d) * |L~ - L|_1 with lambda_d = 0.2
and
  DSSIM = (1 - SSIM) / 2 (3DGS convention, m4dgs.core.ssim).
- Unit-exposure loss: L_ue = ||phi(0) - C0||_2^2 (HDR-NeRF), C0 = 0.73 for synthetic clips (f(1) of
the HDR-NeRF CRF),
  0.5 for real clips; read it from the clip's ``unit_exposure_value``.
"""

from __future__ import annotations

import torch

from m4dgs.core.ssim import ssim_map

LAMBDA_DSSIM = 0.2  # paper appendix, "LDR RGB Loss"


def _masked_mean(x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Mean of x [..., H, W, C] over the pixels where mask [..., H, W] (or [..., H, W, 1]) is true /
    weighted."""
    if mask is None:
        return x.mean()
    m = mask.to(x.dtype)
    if m.dim() == x.dim() - 1:
        m = m.unsqueeze(-1)
    m = m.expand_as(x)
    return (x * m).sum() / m.sum().clamp_min(1e-8)


def l1_loss(
    pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Mean absolute error over the (masked) pixels and all channels. pred, target [..., H, W, C] ->
    scalar."""
    return _masked_mean((pred - target).abs(), mask)


def dssim_loss(
    pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """(1 - SSIM) / 2 with SSIM the mean of the 3DGS SSIM map over the (masked) pixels. [..., H, W,
    C] -> scalar.

    Without a mask this equals ``m4dgs.core.ssim.dssim``. With a mask the SSIM map (computed on the
    full images) is averaged over the masked pixels only."""
    return (1.0 - _masked_mean(ssim_map(pred, target), mask)) / 2.0


def rgb_loss(
    pred: torch.Tensor,
    target: torch.Tensor,
    mask: torch.Tensor | None = None,
    lambda_d: float = LAMBDA_DSSIM,
) -> torch.Tensor:
    """LDR RGB loss (1 - lambda_d) * L1 + lambda_d * DSSIM.

    Args:
        pred: [..., H, W, 3] rendered LDR image (tone-mapped); target: same shape, the input frame
        in [0, 1]. mask: optional [..., H, W] (bool or weights) restricting both terms to the masked
        pixels. lambda_d: D-SSIM weight (0.2).
    Returns:
        scalar tensor.
    """
    loss = (1.0 - lambda_d) * l1_loss(pred, target, mask)
    if lambda_d > 0:
        loss = loss + lambda_d * dssim_loss(pred, target, mask)
    return loss


def unit_exposure_loss(phi0: torch.Tensor, c0: float, reduction: str = "sum") -> torch.Tensor:
    """||phi(0) - C0||^2.

    Args:
        phi0: [C] tone-mapper output at log2 exposure 0 (``ToneMapper.unit_exposure_value()``). c0:
        target (0.73 synthetic, 0.5 real; the clip's unit_exposure_value). reduction: "sum" =
        squared L2 norm over channels (paper's formula), "mean" = mean over channels (authors'
        code).
    Returns:
        scalar tensor.
    """
    sq = (phi0 - c0) ** 2
    if reduction == "sum":
        return sq.sum()
    if reduction == "mean":
        return sq.mean()
    raise ValueError(f"unit_exposure_loss: unknown reduction {reduction!r}")
