"""The machine a run or a clip was made on, as recorded in run.json and clip.json.

On one machine a clip and a training run repeat bit for bit (docs/reliability.md). Across
machines they need not: torch dispatches its CPU kernels on the instruction set it finds
(`torch.backends.cpu.get_cpu_capability()`: AVX2 or AVX512 round differently), and Mitsuba's LLVM
backend and Open Image Denoise compile or pick kernels for the host CPU too. A clip regenerated on
another machine differed in its fifth digit (its HDR-TAE floor) and a run on it like a run with
another seed (docs/reliability.md, "Across machines"), so both files say where they were made.
"""

from __future__ import annotations

import platform
from pathlib import Path
from typing import Optional

import numpy as np
import torch


def cpu_model() -> str:
    """The CPU's model name ("model name" of /proc/cpuinfo on Linux, else what the platform
    module says; "" where neither knows)."""
    info = Path("/proc/cpuinfo")
    try:
        for line in info.read_text(errors="replace").splitlines():
            if line.lower().startswith("model name") and ":" in line:
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or ""


def cpu_capability() -> str:
    """The instruction set torch's CPU kernels dispatch on ("AVX2", "AVX512", ...; "DEFAULT" where
    torch cannot say): what the C++ rasterizer's build flags follow (m4dgs.raster.cpu_backend)
    and what rounds differently from one CPU to another."""
    try:
        return torch.backends.cpu.get_cpu_capability()
    except Exception:  # very old torch / unusual platform
        return "DEFAULT"


def gpu_name(device: Optional[torch.device] = None) -> Optional[str]:
    """The CUDA device's name when `device` is one, else None."""
    if device is not None and torch.device(device).type == "cuda":
        return torch.cuda.get_device_name(torch.device(device))
    return None


def host_info(device: Optional[torch.device] = None) -> dict:
    """{"machine", "cpu", "cpu_capability", "python", "numpy", "torch", "gpu"} of this process:
    the CPU architecture and model, the instruction set torch's CPU kernels dispatch on, the
    versions, and the CUDA device's name when `device` is one (else None). JSON-ready."""
    return {
        "machine": platform.machine(),
        "cpu": cpu_model(),
        "cpu_capability": cpu_capability(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "torch": torch.__version__,
        "gpu": gpu_name(device),
    }
