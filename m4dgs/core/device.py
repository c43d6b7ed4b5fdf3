"""Torch devices: resolve "auto", read and reset the peak memory.

`resolve_device` is what `m4dgs train --device` and `eval score --device` accept; `peak_memory_mib`
is what run.json records (training) and what eval.metrics.perf measures around one call."""

from __future__ import annotations

import sys
from typing import Optional, Union

import torch

try:
    import resource
except ImportError:  # pragma: no cover - not POSIX
    resource = None

DeviceLike = Union[str, torch.device]


def resolve_device(device: DeviceLike = "auto") -> torch.device:
    """The torch device of `device`: "auto" is cuda when a CUDA device is available, else cpu;
    anything else is torch.device(device) (a torch.device is returned as it is)."""
    if isinstance(device, torch.device):
        return device
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def is_cuda(device: Optional[DeviceLike]) -> bool:
    """True for a CUDA device on a machine that has one (None and CPU devices: False)."""
    return device is not None and torch.device(device).type == "cuda" and torch.cuda.is_available()


def synchronize(device: Optional[DeviceLike]) -> None:
    """Wait for the device's queued kernels (CUDA); a no-op for None and CPU devices."""
    if is_cuda(device):
        torch.cuda.synchronize(torch.device(device))


def reset_peak_memory(device: Optional[DeviceLike]) -> None:
    """Start a new CUDA peak-memory window (torch.cuda.reset_peak_memory_stats); a no-op on the CPU,
    whose peak (the process's max RSS) cannot be reset."""
    if is_cuda(device):
        torch.cuda.reset_peak_memory_stats(torch.device(device))


def peak_memory_mib(device: Optional[DeviceLike]) -> Optional[float]:
    """Peak memory in MiB: on CUDA torch.cuda.max_memory_allocated (allocator memory since the last
    `reset_peak_memory`, or since the process started); on the CPU the process's maximum resident
    set size (ru_maxrss, a lifetime high-water mark: KiB on Linux, bytes on macOS), or None where
    the resource module is unavailable."""
    if device is not None and torch.device(device).type == "cuda":
        return torch.cuda.max_memory_allocated(torch.device(device)) / 2**20
    if resource is None:  # pragma: no cover - not POSIX
        return None
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 2**20 if sys.platform == "darwin" else rss / 1024.0
