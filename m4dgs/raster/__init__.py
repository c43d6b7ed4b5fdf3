"""Differentiable Gaussian rasterization with three backends: gsplat (CUDA), cpu (C++/OpenMP), torch
(dense).

See docs/rasterizer.md for conventions and timings.
"""

from .binning import TileBins, bin_gaussians
from .cpu_backend import bin_cpu, cpu_available, extension_dir, load_extension, project_cpu
from .projection import (
    Projection,
    covariance_3d,
    intrinsics_ortho,
    project_gaussians,
    quat_to_rotmat,
)
from .renderer import BACKENDS, RenderMeta, RenderOutput, render, resolve_backend

__all__ = [
    "BACKENDS",
    "Projection",
    "RenderMeta",
    "RenderOutput",
    "TileBins",
    "bin_cpu",
    "bin_gaussians",
    "covariance_3d",
    "cpu_available",
    "extension_dir",
    "intrinsics_ortho",
    "load_extension",
    "project_cpu",
    "project_gaussians",
    "quat_to_rotmat",
    "render",
    "resolve_backend",
]
