"""Rendering speed and memory: FPS of a render callable (with warm-up and device synchronisation),
peak memory.

Convention: FPS = iterations / wall time of `iters` calls after `warmup` untimed calls, the device
synchronised before starting and after finishing the clock (CUDA kernels are asynchronous). The
paper measures FPS at 864x480."""

from __future__ import annotations

import time
from typing import Callable

import torch

CONVENTIONS = {
    "fps": "FPS: renders per second after warm-up, device synchronised, at the stated resolution",
    "peak_mem": "Peak memory: torch.cuda.max_memory_allocated during the call (GPU), process max "
    "RSS (CPU)",
}


def _sync(device) -> None:
    if device is not None and torch.device(device).type == "cuda" and torch.cuda.is_available():
        torch.cuda.synchronize(torch.device(device))


def measure_fps(
    render: Callable[[], object],
    *,
    warmup: int = 3,
    iters: int = 20,
    device=None,
    clock: Callable[[], float] = time.perf_counter,
) -> dict:
    """Time a zero-argument render callable.

    Args:
        render: callable producing one frame (its result is discarded).
        warmup: untimed calls first (kernel compilation, caches).
        iters: timed calls.
        device: torch device to synchronise (e.g. "cuda"); None or CPU -> no synchronisation.
        clock: time source in seconds (injectable for tests).
    Returns:
        {"fps", "ms_per_frame", "iters", "seconds"}.
    """
    if iters < 1:
        raise ValueError("measure_fps: iters must be >= 1")
    for _ in range(warmup):
        render()
    _sync(device)
    t0 = clock()
    for _ in range(iters):
        render()
    _sync(device)
    dt = clock() - t0
    fps = iters / dt if dt > 0 else float("inf")
    return {"fps": fps, "ms_per_frame": 1000.0 * dt / iters, "iters": iters, "seconds": dt}


def peak_memory_mib(fn: Callable[[], object], *, device=None) -> float | None:
    """Peak memory while running `fn` once, in MiB.

    On CUDA: torch.cuda.max_memory_allocated after a reset of the peak statistics (allocator memory
    only). On CPU: the process's maximum resident set size (ru_maxrss; a lifetime high-water mark,
    not specific to `fn`), or None where the resource module is unavailable."""
    if device is not None and torch.device(device).type == "cuda" and torch.cuda.is_available():
        dev = torch.device(device)
        torch.cuda.synchronize(dev)
        torch.cuda.reset_peak_memory_stats(dev)
        fn()
        torch.cuda.synchronize(dev)
        return torch.cuda.max_memory_allocated(dev) / 2**20
    fn()
    try:
        import resource
        import sys
    except ImportError:  # pragma: no cover - non-POSIX
        return None
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return rss / 2**20 if sys.platform == "darwin" else rss / 1024.0
