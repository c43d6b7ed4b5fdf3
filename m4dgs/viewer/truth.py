"""The ground truth of a benchgen clip at one of the viewer's named cameras, and the comparison
image (render | truth | per-pixel error) the viewer shows next to the free view.

The truth's LDR at any exposure is the clip's true camera response applied to its HDR frame, as the
generator makes every LDR image of the clip (m4dgs.core.crf.tonemap_ldr(hdr, 2^ev, clip crf)):
gt/hdr/<g>.exr at a training or test camera, gt/views/<view>/hdr/<g>.exr at a held-out view."""

from __future__ import annotations

from typing import Optional

import numpy as np

from m4dgs.viewer.cameras import NamedCamera
from m4dgs.viewer.frame import to_uint8, turbo

#: per-pixel error shown from 0 (blue) to this many 8-bit codes (red)
ERROR_RANGE = 64.0


def has_truth(clip, named: NamedCamera) -> bool:
    """Whether the clip has an HDR ground-truth frame (and a known camera response) at `named`."""
    if not clip.has_gt or clip.meta.crf is None:
        return False
    if named.kind == "view":
        return clip.path("gt", "views", named.view, "hdr").is_dir()
    return clip.has_gt_part("hdr")


def truth_ldr(clip, named: NamedCamera, ev: float) -> Optional[np.ndarray]:
    """uint8 [H, W, 3]: the true LDR image at `named`'s camera and frame, exposure 2^ev; None
    where the clip has none (has_truth)."""
    from m4dgs.core.crf import tonemap_ldr

    if not has_truth(clip, named):
        return None
    if named.kind == "view":
        hdr = clip.load_view_hdr(named.view, named.g)
    else:
        hdr = clip.load_gt_hdr(named.g)
    return tonemap_ldr(hdr, 2.0 ** float(ev), clip.meta.crf)


def error_map(render: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """uint8 [H, W, 3]: the per-pixel mean absolute difference of two uint8 images over the
    channels, in turbo from 0 to ERROR_RANGE codes."""
    err = np.abs(render.astype(np.float64) - truth.astype(np.float64)).mean(-1)
    return to_uint8(turbo(err / ERROR_RANGE))


def comparison(render: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """uint8 [H, 3 W + 4, 3]: render | truth | error map side by side, 2-pixel white gaps."""
    if render.shape != truth.shape:
        raise ValueError(f"comparison: render {render.shape} and truth {truth.shape} differ")
    gap = np.full((render.shape[0], 2, 3), 255, np.uint8)
    return np.concatenate([render, gap, truth, gap, error_map(render, truth)], axis=1)


def mean_abs_error(render: np.ndarray, truth: np.ndarray) -> float:
    """Mean absolute difference in 8-bit codes."""
    return float(np.abs(render.astype(np.float64) - truth.astype(np.float64)).mean())
