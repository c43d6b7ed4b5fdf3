"""Input conversion for code that accepts numpy arrays, torch tensors or nested lists (the metrics
of eval.metrics and the HDR-TAE of m4dgs.core.temporal): float64 torch tensors and bool masks."""

from __future__ import annotations

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
