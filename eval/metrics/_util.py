"""Small input helpers shared by the metric modules (numpy or torch in, float64 torch out);
`as_tensor` / `as_mask` live in m4dgs.core.tensors (the HDR-TAE of m4dgs.core.temporal uses them
too)."""

from __future__ import annotations

import math

import torch

from m4dgs.core.tensors import as_mask, as_tensor

__all__ = ["as_mask", "as_tensor", "batched", "check_pair", "psnr_from_mse"]


def check_pair(a: torch.Tensor, b: torch.Tensor, name: str) -> None:
    if a.shape != b.shape:
        raise ValueError(f"{name}: shape mismatch {tuple(a.shape)} vs {tuple(b.shape)}")
    if a.dim() not in (3, 4) or a.shape[-1] not in (1, 3):
        raise ValueError(
            f"{name}: expected [H, W, C] or [N, H, W, C] images with C in (1, 3), got "
            f"{tuple(a.shape)}"
        )


def batched(a: torch.Tensor) -> torch.Tensor:
    """[H, W, C] -> [1, H, W, C]; [N, H, W, C] unchanged."""
    return a[None] if a.dim() == 3 else a


def psnr_from_mse(mse: float, peak: float) -> float:
    """10 log10(peak^2 / mse); +inf for a zero error."""
    if mse <= 0.0:
        return math.inf
    return 10.0 * math.log10(peak * peak / mse)
