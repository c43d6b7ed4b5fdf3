"""CPU thread budgets: torch's intra-op threads and the OpenMP threads of the compiled kernels.

A training step on the CPU is a few compiled kernels (projection, tile rasterization forward and
backward: 40-45 % of a step) and about a thousand small torch operations on [120, 216, 3] images
and per-Gaussian tensors. The kernels split their tiles over threads with little overhead; torch's
operations on tensors that small lose about as much to synchronising a parallel region as they gain
from it. Measured on the 2-core machine (docs/performance.md, "Threads"): torch on one thread with
the kernels on both cores is 1.13-1.21x faster per step than both on two threads, and 1.15-1.28x
faster than both on one.

`use_threads(budget)` spends a budget that way (torch 1, kernels `budget`) when training on the
CPU; with a CUDA device the compiled CPU kernels are idle, so torch's own CPU work (camera
initialisation, data loading, scoring) gets the whole budget instead. The `m4dgs-eval run`
workers and the bench scripts call it, and the commands that train in their own process (`m4dgs
train --threads`, `m4dgs-eval job`, `m4dgs-eval run --jobs 1`) hold it while they train
(`threads_for`, which restores the counts from before); library functions do not change the
process's threads otherwise. `kernel_threads()` is what the CPU kernels use: the count set here, or
torch's own when nothing was set (so code that only calls `torch.set_num_threads` keeps its
behaviour). Both counts change float summation order (the projection's backward adds per-thread
partial camera gradients), so a run records both and shared phases are keyed by both
(m4dgs.training.pipeline)."""

from __future__ import annotations

import os
from contextlib import contextmanager
from typing import Iterator, Optional, Tuple

import torch

from m4dgs.core.device import resolve_device

_kernel_threads: Optional[int] = None


def set_kernel_threads(n: Optional[int]) -> None:
    """Threads of the compiled CPU kernels (None: follow torch.get_num_threads())."""
    global _kernel_threads
    if n is not None and int(n) < 1:
        raise ValueError(f"kernel threads must be >= 1, got {n!r}")
    _kernel_threads = None if n is None else int(n)


def kernel_threads() -> int:
    """Threads the compiled CPU kernels use: the value of set_kernel_threads, else torch's."""
    return _kernel_threads if _kernel_threads is not None else torch.get_num_threads()


def cpu_budget() -> int:
    """The CPUs this process may use (its affinity mask where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not Linux
        return max(1, os.cpu_count() or 1)


def use_threads(budget: Optional[int] = None, device=None) -> Tuple[int, int]:
    """Spend `budget` CPU threads (default: cpu_budget()) as measured fastest on the CPU: torch's
    intra-op operations on one thread, the compiled kernels on `budget`. When `device` is (or,
    "auto", resolves to) CUDA, the rasterizer runs on the GPU and torch gets all `budget` threads
    (the split is a CPU measurement; not measured on a GPU machine). Returns (torch threads, kernel
    threads)."""
    n = cpu_budget() if budget is None else int(budget)
    if n < 1:
        raise ValueError(f"a thread budget must be >= 1, got {budget!r}")
    # "auto" resolves as the trainer resolves it (m4dgs.core.device); no CUDA availability check
    # for an explicit "cuda": the split follows what the caller asked for
    t = n if device is not None and resolve_device(device).type == "cuda" else 1
    torch.set_num_threads(t)
    set_kernel_threads(n)
    return t, n


@contextmanager
def threads_for(budget: Optional[int] = None, device=None) -> Iterator[Tuple[int, int]]:
    """use_threads(budget, device) for the duration of a with block, then the counts from before."""
    before = (torch.get_num_threads(), _kernel_threads)
    try:
        yield use_threads(budget, device)
    finally:
        torch.set_num_threads(before[0])
        set_kernel_threads(before[1])
