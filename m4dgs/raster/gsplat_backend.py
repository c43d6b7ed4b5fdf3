"""The ``gsplat`` backend (CUDA only; gsplat is the optional ``gpu`` extra, imported lazily)."""

from __future__ import annotations

import torch
from torch import Tensor

from .projection import EPS2D, FAR_PLANE, NEAR_PLANE

GSPLAT_HINT = (
    "install the optional GPU extra: pip install 'mono4dgs-hdr[gpu]' (gsplat==1.5.3, needs CUDA)"
)


def import_gsplat():
    """The gsplat module; raises ImportError with an installation hint when it is missing."""
    try:
        import gsplat
    except Exception as exc:  # ImportError, or a broken CUDA build raising at import time
        raise ImportError(
            f"the gsplat backend needs gsplat: {GSPLAT_HINT} ({type(exc).__name__}: {exc})"
        ) from exc
    return gsplat


def gsplat_available() -> bool:
    """True when gsplat imports and CUDA is available."""
    if not torch.cuda.is_available():
        return False
    try:
        import_gsplat()
    except ImportError:
        return False
    return True


def render_gsplat(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    features: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    camera_model: str,
) -> tuple[Tensor, Tensor, Tensor, dict]:
    """gsplat.rasterization with colors [N, C], render_mode "RGB+ED", one camera, packed=False.

    Returns (features [H, W, C] without background, expected depth [H, W, 1], alpha [H, W, 1],
    gsplat's meta). ``meta["means2d"]`` is gsplat's [1, N, 2] tensor; its gradient is retained."""
    gsplat = import_gsplat()
    if not means.is_cuda:
        raise ValueError("the gsplat backend needs CUDA tensors")
    renders, alphas, meta = gsplat.rasterization(
        means,
        quats,
        scales,
        opacities,
        features,
        viewmat[None],
        K[None],
        int(width),
        int(height),
        near_plane=NEAR_PLANE,
        far_plane=FAR_PLANE,
        eps2d=EPS2D,
        sh_degree=None,
        tile_size=16,
        packed=False,
        render_mode="RGB+ED",
        camera_model=camera_model,
        rasterize_mode="classic",
    )
    if meta["means2d"].requires_grad:
        meta["means2d"].retain_grad()
    return renders[0, ..., :-1], renders[0, ..., -1:], alphas[0], meta
