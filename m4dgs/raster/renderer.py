"""``render``: one differentiable Gaussian rasterization entry point over three backends (gsplat,
cpu, torch)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import NamedTuple, Optional

import torch
from torch import Tensor

from .binning import TILE_SIZE
from .cpu_backend import _load as _load_cpu
from .cpu_backend import bin_cpu, project_cpu, rasterize_cpu
from .gsplat_backend import gsplat_available, render_gsplat
from .projection import CAMERA_MODELS, project_gaussians
from .reference import rasterize_dense

BACKENDS = ("auto", "gsplat", "cpu", "torch")


@dataclass
class RenderMeta:
    """Per-Gaussian side outputs of one render.

    means2d: the screen-space means whose ``.grad`` is filled by backward (retain_grad is on): [N,
    2] for the
        cpu/torch backends, gsplat's [1, N, 2] for gsplat; use ``means2d_grad()`` for a uniform [N,
        2].
    radii: [N, 2] int32 per-axis pixel radius (0 = culled).  visible: [N] bool.  depths: [N] camera
    z. conics: [N, 3] inverse 2D covariance (inv00, inv01, inv11).  backend: the backend that ran.
    n_isects: number of (tile, Gaussian) pairs (-1 for the dense torch backend)."""

    means2d: Tensor
    radii: Tensor
    visible: Tensor
    depths: Tensor
    conics: Tensor
    backend: str
    n_isects: int

    def means2d_grad(self) -> Optional[Tensor]:
        """Gradient of the loss w.r.t. the 2D means, [N, 2] (None before backward)."""
        g = self.means2d.grad
        return None if g is None else g.reshape(-1, 2)


class RenderOutput(NamedTuple):
    """features [H, W, C] (background added), depth [H, W, 1] expected z, alpha [H, W, 1], meta."""

    features: Tensor
    depth: Tensor
    alpha: Tensor
    meta: RenderMeta


def resolve_backend(backend: str, device: torch.device) -> str:
    """Pick the backend: "auto" = gsplat on CUDA when it imports, else cpu when it compiles, else
    torch."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend != "auto":
        return backend
    if device.type == "cuda":
        if gsplat_available():
            return "gsplat"
        warnings.warn(
            "gsplat is not available for CUDA tensors; using the slow dense 'torch' rasterizer",
            stacklevel=3,
        )
        return "torch"
    if device.type == "cpu":
        module, reason = _load_cpu()
        if module is not None:
            return "cpu"
        warnings.warn(f"{reason}; using the slow dense 'torch' rasterizer", stacklevel=3)
    return "torch"


def render(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    features: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    camera_model: str = "pinhole",
    backend: str = "auto",
    background: Optional[Tensor] = None,
) -> RenderOutput:
    """Render N Gaussians into one camera.

    Args:
        means: [N, 3] world positions.  quats: [N, 4] (w, x, y, z), normalised inside. scales: [N,
        3] standard deviations (not log).  opacities: [N] in [0, 1]. features: [N, C] any number of
        channels (HDR colour, flow targets, ...). viewmat: [4, 4] world-to-camera.  K: [3, 3] pixel
        intrinsics (pixel centres at +0.5). width, height: image size in pixels. camera_model:
        "pinhole" or "ortho" (u = fx x + cx, v = fy y + cy; J = [[fx, 0, 0], [0, fy, 0]]). backend:
        "auto", "gsplat" (CUDA), "cpu" (C++/OpenMP) or "torch" (dense reference). background: [C]
        colour added as T_final * background (not to depth).

    Returns:
        RenderOutput(features [H, W, C], depth [H, W, 1] = accumulated z / max(alpha, 1e-10), alpha
        [H, W, 1], meta). Differentiable w.r.t. means, quats, scales, opacities, features and
        viewmat.
    """
    n = means.shape[0]
    if (
        means.shape != (n, 3)
        or quats.shape != (n, 4)
        or scales.shape != (n, 3)
        or opacities.shape != (n,)
    ):
        raise ValueError(
            "expected means [N, 3], quats [N, 4], scales [N, 3], opacities [N]; got "
            f"{tuple(means.shape)}, {tuple(quats.shape)}, {tuple(scales.shape)}, "
            f"{tuple(opacities.shape)}"
        )
    if features.dim() != 2 or features.shape[0] != n:
        raise ValueError(f"features must be [N, C] with N = {n}, got {tuple(features.shape)}")
    if camera_model not in CAMERA_MODELS:
        raise ValueError(f"camera_model must be one of {CAMERA_MODELS}, got {camera_model!r}")
    width, height = int(width), int(height)
    n_ch = features.shape[1]
    if background is not None and background.shape != (n_ch,):
        raise ValueError(f"background must be [C] = [{n_ch}], got {tuple(background.shape)}")
    chosen = resolve_backend(backend, means.device)

    if chosen == "gsplat":
        feat, depth, alpha, gmeta = render_gsplat(
            means, quats, scales, opacities, features, viewmat, K, width, height, camera_model
        )
        radii = gmeta["radii"][0]
        if radii.dim() == 1:  # older gsplat: one radius per Gaussian
            radii = radii[:, None].expand(-1, 2)
        meta = RenderMeta(
            means2d=gmeta["means2d"],
            radii=radii.to(torch.int32),
            visible=(radii > 0).all(dim=-1),
            depths=gmeta["depths"][0],
            conics=gmeta["conics"][0],
            backend="gsplat",
            n_isects=int(gmeta["flatten_ids"].numel()),
        )
    else:
        if chosen == "cpu" and means.device.type != "cpu":
            raise ValueError("the cpu backend needs CPU tensors")
        project = project_cpu if chosen == "cpu" else project_gaussians
        proj = project(means, quats, scales, opacities, viewmat, K, width, height, camera_model)
        means2d = proj.means2d
        if means2d.requires_grad:
            means2d.retain_grad()
        dtype = means.dtype
        # depth as an extra channel
        feats_d = torch.cat([features.to(dtype), proj.depths[:, None]], dim=-1)
        if chosen == "cpu":
            bins = bin_cpu(means2d, proj.radii, proj.depths, width, height, TILE_SIZE)
            acc, alpha = rasterize_cpu(
                means2d, proj.conics, opacities.to(dtype), feats_d, bins, width, height
            )
            n_isects = int(bins.flat_ids.numel())
        else:
            acc, alpha = rasterize_dense(
                means2d,
                proj.conics,
                opacities.to(dtype),
                feats_d,
                proj.depths,
                proj.visible,
                width,
                height,
            )
            n_isects = -1
        feat = acc[..., :n_ch]
        depth = acc[..., n_ch:] / alpha.clamp_min(1e-10)
        meta = RenderMeta(
            means2d, proj.radii, proj.visible, proj.depths, proj.conics, chosen, n_isects
        )
    if background is not None:
        feat = feat + (1.0 - alpha) * background.to(feat.dtype)
    return RenderOutput(feat, depth, alpha, meta)
