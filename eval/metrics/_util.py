"""Small input helpers shared by the metric modules (numpy or torch in, float64 torch out)."""

from __future__ import annotations

import math

import numpy as np
import torch


def as_tensor(x, *, device=None, dtype=torch.float64, uint8_scale: bool = True) -> torch.Tensor:
    """Convert a numpy array / torch tensor / nested list to a float64 torch tensor.

    uint8 inputs are read as 8-bit images and divided by 255 when `uint8_scale` is True. The device
    follows a torch input unless `device` is given."""
    if isinstance(x, torch.Tensor):
        t = x.detach()
    else:
        t = torch.as_tensor(np.asarray(x))
    is_u8 = t.dtype == torch.uint8
    if device is not None:
        t = t.to(device)
    t = t.to(dtype)
    if is_u8 and uint8_scale:
        t = t / 255.0
    return t


def as_mask(m, like: torch.Tensor) -> torch.Tensor:
    """Convert a mask (bool / 0-1 numbers, numpy or torch) to a bool tensor on `like`'s device."""
    t = m.detach() if isinstance(m, torch.Tensor) else torch.as_tensor(np.asarray(m))
    return (t.to(like.device) > 0.5) if t.dtype != torch.bool else t.to(like.device)


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
