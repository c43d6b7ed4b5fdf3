"""Input conversion for code that accepts numpy arrays, torch tensors or nested lists (the metrics
of eval.metrics and the HDR-TAE of m4dgs.core.temporal): float64 torch tensors and bool masks; and a
row gather whose gradient does not depend on the CPU thread count."""

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


def gather_rows(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """x[idx] for x [N, ...] and integer idx of any shape S: [*S, ...], with a gradient that is the
    same bit for bit on any number of CPU threads.

    Advanced indexing's backward (index_put_ with accumulate) adds the gradients of repeated indices
    in parallel on the CPU, in an order that changes from call to call when torch has more than one
    thread (measured: the ARAP term's gradient took 20 different values in 20 calls on 2 threads);
    index_select's backward (index_add_) adds them in index order. On one thread the two give the
    same bits (tests/core/test_tensors.py)."""
    out = torch.index_select(x, 0, idx.reshape(-1))
    return out.reshape(*idx.shape, *x.shape[1:])
