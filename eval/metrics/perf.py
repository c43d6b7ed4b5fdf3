"""Rendering speed and memory: FPS of a render callable (with warm-up and device synchronisation),
peak memory of a call (the device helpers are m4dgs.core.device's).

Convention: FPS = iterations / wall time of `iters` calls after `warmup` untimed calls, the device
synchronised before starting and after finishing the clock (CUDA kernels are asynchronous). The
paper measures FPS at 864x480."""

from __future__ import annotations

import time
from typing import Callable

from m4dgs.core.device import is_cuda, peak_memory_mib, reset_peak_memory, synchronize

CONVENTIONS = {
    "fps": "FPS: renders per second after warm-up, device synchronised, at the stated resolution",
    "peak_mem": "Peak memory: torch.cuda.max_memory_allocated during the call (GPU), process max "
    "RSS (CPU)",
}


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
    synchronize(device)
    t0 = clock()
    for _ in range(iters):
        render()
    synchronize(device)
    dt = clock() - t0
    fps = iters / dt if dt > 0 else float("inf")
    return {"fps": fps, "ms_per_frame": 1000.0 * dt / iters, "iters": iters, "seconds": dt}


def measure_peak_memory_mib(fn: Callable[[], object], *, device=None) -> float | None:
    """Peak memory while running `fn` once, in MiB (m4dgs.core.device.peak_memory_mib).

    On CUDA: torch.cuda.max_memory_allocated after a reset of the peak statistics (allocator memory
    only). On CPU: the process's maximum resident set size (ru_maxrss; a lifetime high-water mark,
    not specific to `fn`), or None where the resource module is unavailable."""
    dev = device if is_cuda(device) else None
    synchronize(dev)
    reset_peak_memory(dev)
    fn()
    synchronize(dev)
    return peak_memory_mib(dev)
