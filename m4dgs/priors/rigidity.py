"""Dynamic masks from a rigidity test: the prior flow against the flow a static scene would induce.

The paper's masks (m4dgs.priors.epipolar) threshold the distance of each flow end point from its
epipolar line. That test is blind to motion along the epipolar lines: on an orbiting or dollying
camera, an object that slides parallel to the camera translation keeps its flow on the epipolar line
and is labelled static (measured on the benchmark: mask recall 0.09 on conveyor-occlusion-orbit,
0.13 on lamp-room-orbit; docs/method.md).

Once bundle adjustment has produced cameras (K, c2w) and per-frame depth scales s_t, a static pixel
x of frame i with prior depth z_i(x) has a predicted position in frame j,

    x_ij = pi(K, w2c_j c2w_i (z_i(x) s_i K^-1 [x, 1])),

and the rigidity error is |F_{i->j}(x) - (x_ij - x)| in pixels. It sees motion in every direction,
including along the
epipolar line, at the price of depending on the depth prior and the cameras; so errors are
thresholded relative to each frame's median error (the typical static residual: flow noise +
depth-prior error + camera error), which keeps the test free of a resolution- or scene-dependent
pixel threshold. `method="union"` ORs these masks with the epipolar ones (each test catches motion
the other misses); `method="epipolar"` is the paper as written.

Time is the training-frame index 0..T-1; flow pairs are (i, j) training-frame indices of F_{i->j}.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Optional, Sequence, Tuple, get_args

import torch
from torch import Tensor

from m4dgs.core import camera as cam
from m4dgs.priors.epipolar import fill_from_nearest

MaskMethod = Literal["epipolar", "reprojection", "union"]
METHODS = get_args(MaskMethod)


@dataclass
class DynamicMaskConfig:
    """Which dynamic-mask test feeds camera initialisation, the V2W split and the stage-2 static
    masks.

    method: "epipolar" (sec. 3.2 as written: epipolar error of the prior flow), "reprojection"
    (rigidity error with the bundle-adjusted cameras and depth prior, this module) or "union" of the
    two (the tiny and small presets; see the module docstring for why: the epipolar test misses
    motion along the epipolar lines)."""

    method: MaskMethod = "epipolar"  # sec. 3.2 "Prior Precompute" (paper preset)
    median_factor: float = 3.0  # dynamic: rigidity error > median_factor x the frame's median error
    # ... and > this fraction of the image diagonal (floor for noise-free input)
    min_threshold: float = 1e-3
    combine: Literal["mean", "max"] = "mean"  # over a frame's flow pairs
    # re-run bundle adjustment once with the refined masks (static tracks chosen with the better
    # masks); the final masks are then recomputed with the refined cameras
    refine_cameras: bool = True
    # beyond the paper (off): OR the pixels of moving highlight chains into the masks after camera
    # initialisation (m4dgs.priors.highlight_tracks.highlight_masks), so that the Gaussians that
    # follow a mover a few pixels across are dynamic at the V2W hand-over; the bundle adjustment
    # keeps its own masks
    highlight_blobs: bool = False

    def validate(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"masks.method must be one of {METHODS}, got {self.method!r}")
        if self.combine not in ("mean", "max"):
            raise ValueError(f"masks.combine must be 'mean' or 'max', got {self.combine!r}")
        if not self.median_factor > 0:
            raise ValueError(f"masks.median_factor must be > 0, got {self.median_factor}")


def static_flow(depth_i: Tensor, K: Tensor, c2w_i: Tensor, c2w_j: Tensor) -> Tuple[Tensor, Tensor]:
    """Flow F_{i->j} a static scene with depth `depth_i` would induce between two pinhole cameras.

    Args:
        depth_i: [H, W] metric (world-unit) z-depth of frame i; <= 0 or non-finite = invalid.
        K: [3, 3] intrinsics shared by both frames (pixel centres at +0.5).
        c2w_i, c2w_j: [4, 4] camera-to-world (OpenCV: x right, y down, z forward).
    Returns:
        flow [H, W, 2] in pixels (undefined where not valid), valid [H, W] bool (depth valid and the
        point in front of camera j).
    """
    H, W = depth_i.shape
    dt = torch.float64
    pix = cam.pixel_centers(W, H, dtype=dt, device=depth_i.device)
    z = depth_i.to(dt)
    ok = torch.isfinite(z) & (z > 0)
    rel = cam.invert_rigid(c2w_j.to(dt)) @ c2w_i.to(dt)  # camera i -> camera j
    xj = cam.transform_points(
        rel, cam.unproject_pinhole(pix, torch.where(ok, z, torch.ones_like(z)), K.to(dt))
    )
    return (cam.project_pinhole(xj, K.to(dt)) - pix).float(), ok & (xj[..., 2] > 1e-9)


def segment_distance(p: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """[...] Euclidean distance from points p [..., 2] to the segments a..b [..., 2] (a point where
    a == b)."""
    ab = b - a
    t = ((p - a) * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(1e-12)
    return (p - (a + t.clamp(0, 1)[..., None] * ab)).norm(dim=-1)


def reprojection_error_maps(
    depth: Tensor,
    depth_scale: Tensor,
    K: Tensor,
    c2w: Tensor,
    flow: Tensor,
    flow_valid: Tensor,
    pairs: Sequence[Tuple[int, int]],
    combine: str = "mean",
    depth_tolerance: float = 0.0,
) -> Tuple[Tensor, Tensor]:
    """Per-training-frame rigidity error maps.

    Args:
        depth: [T, H, W] depth prior (prior units; <= 0 invalid); world depth of frame t is depth[t]
        * depth_scale[t]. depth_scale: [T] bundle-adjustment scale per frame. K: [3, 3]; c2w: [T, 4,
        4] bundle-adjusted cameras. flow: [P, H, W, 2] prior flow F_{i->j} in pixels; flow_valid:
        [P, H, W] bool. pairs: [P] (i, j) training-frame indices. combine: "mean" or "max" over the
        pairs whose source is frame t.
        depth_tolerance: delta >= 0. With 0 the error is the distance from the flow's end point to
        the static prediction; with delta > 0 it is the distance to the segment of the epipolar line
        that static points of depth z / (1 + delta) .. z (1 + delta) land on, so a depth prior wrong
        by up to that factor is no error. Not used by the trainer: it trades the recall of motion
        along the epipolar lines for precision (measured: bench/mask_bench.py, docs/method.md).
    Returns:
        error [T, H, W] float32 pixels (0 where no pair is valid), valid [T, H, W] bool (some pair
        valid). Frames that are the source of no pair copy the nearest such frame's maps.
    """
    T, H, W = depth.shape
    if flow.shape[0] != len(pairs):
        raise ValueError(f"flow has {flow.shape[0]} pairs, `pairs` lists {len(pairs)}")
    err = torch.zeros(T, H, W, dtype=torch.float32, device=depth.device)
    cnt = torch.zeros(T, H, W, dtype=torch.float32, device=depth.device)
    if not depth_tolerance >= 0:
        raise ValueError(f"depth_tolerance must be >= 0, got {depth_tolerance}")
    for p, (i, j) in enumerate(pairs):
        z = depth[i] * depth_scale[i].to(depth.dtype)
        pred, ok = static_flow(z, K, c2w[i], c2w[j])
        v = ok & flow_valid[p].bool().to(ok.device)
        f = flow[p].to(pred)
        d = (f - pred).norm(dim=-1)
        if depth_tolerance > 0:
            near, ok_n = static_flow(z / (1 + depth_tolerance), K, c2w[i], c2w[j])
            far, ok_f = static_flow(z * (1 + depth_tolerance), K, c2w[i], c2w[j])
            # where the nearer end falls behind camera j, the point distance stays
            d = torch.where(ok_n & ok_f, segment_distance(f, near, far), d)
        e = torch.where(v, d, torch.zeros_like(d))
        if combine == "mean":
            err[i] += e
        elif combine == "max":
            err[i] = torch.maximum(err[i], e)
        else:
            raise ValueError(f"combine must be 'mean' or 'max', got {combine!r}")
        cnt[i] += v.float()
    if combine == "mean":
        err = err / cnt.clamp_min(1)
    fill_from_nearest([err, cnt], {int(i) for i, _ in pairs})
    return err, cnt > 0


def relative_threshold_masks(
    error: Tensor, valid: Tensor, median_factor: float, min_threshold: float
) -> Tensor:
    """Dynamic masks [T, H, W] bool: error > max(median_factor * median_t, min_threshold * image
    diagonal), where median_t is the median error over frame t's valid pixels (pixels without a
    valid pair are never dynamic)."""
    T, H, W = error.shape
    floor = min_threshold * math.hypot(H, W)
    out = torch.zeros_like(valid)
    for t in range(T):
        if valid[t].any():
            thr = max(median_factor * float(error[t][valid[t]].median()), floor)
            out[t] = valid[t] & (error[t] > thr)
    return out


def rigidity_masks(
    depth: Tensor,
    depth_scale: Tensor,
    K: Tensor,
    c2w: Tensor,
    flow: Tensor,
    flow_valid: Tensor,
    pairs: Sequence[Tuple[int, int]],
    cfg: Optional[DynamicMaskConfig] = None,
) -> Tensor:
    """[T, H, W] bool dynamic masks from the rigidity test (reprojection_error_maps +
    relative_threshold_masks)."""
    cfg = cfg or DynamicMaskConfig()
    err, valid = reprojection_error_maps(
        depth, depth_scale, K, c2w, flow, flow_valid, pairs, cfg.combine
    )
    return relative_threshold_masks(err, valid, cfg.median_factor, cfg.min_threshold)
