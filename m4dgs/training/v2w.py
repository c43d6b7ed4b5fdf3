"""Video-to-world (V2W) Gaussian transformation (paper sec. 3.3.2, Fig. 3(a); details from the
authors' code).

Turns the fully dynamic stage-1 *video* Gaussians (orthographic camera space, x, y in [-1, 1], z =
depth) into the stage-2 *world* Gaussians (static set + dynamic set) with the bundle-adjusted
cameras K, c2w_t:

1. Dynamic / static identification with occlusion handling (`dynamic_counts`, `classify_dynamic`):
   each video trajectory mu^v_t is looked up in the dynamic masks M_t at its nearest pixel; N_d
   counts the frames where the mask is 1 and the Gaussian is not occluded (o_t = [z^v_t > D_t(x,
   y)], D the rendered video depth); dynamic iff N_d / N_f > ratio (0.1). The occlusion test can be
   switched off (ablation (b)).
2. Position / rotation transform (`video_to_world_trajectories`): mu^w_t = R_t pi_K^-1(mu^v_t) +
   T_t, R^w_t = R_t R^v_t.
3. Static Gaussians: mean world position over the observed frames, Markley average of the world
   quaternions. Dynamic Gaussians: spline control points re-sampled from the world trajectory on the
   video knots (`m4dgs.core.spline.resample_control_points`) and a least-squares re-fit of the
   quaternion polynomial
   (`m4dgs.core.rotation.fit_rotation_poly`), optionally refined on 1 - |<q, q*>| (authors' code).
4. Opacity logits and colour features are copied (and, beyond the paper, the log2 gain over time
   of `ModelConfig.appearance_knots`: the world Gaussians share the video knots' frames).
5. Scales (`refit_scales`): min_{S^w} sum_t || Sigma'^v_t - Sigma'^w_t ||_1 with the video 2D
covariance from the
   orthographic camera (W^v = identity) and the world one from the pinhole EWA Jacobian in camera t
   (W^w = R_t^-1), both computed by the rasterizer's own `m4dgs.raster.projection.project_gaussians`
   (so the 1.3 tan-fov clamp and the 0.3 px^2 dilation are exactly the rasterizer's). Ablation (c)
   "inherit scale" (`ablation.cov_invariance = False`) instead copies the video scale *values*: the
   world Gaussian gets the same numbers (standard deviations) as the video one, now read in world
   units, i.e. world raw scale = scale_inverse(video_scales, world activation). Video scales are NDC
   / depth units (~0.01), so the inherited world Gaussians are far too small or large on screen -
   which is why the paper's ablation degrades.

"Observed frames" of a video Gaussian: z^v_t > 0 and (x^v_t, y^v_t) inside the image ([-1, 1)); the
spline is only an extrapolation elsewhere. Static means / quaternion averages and the dynamic
control-point fit use the observed frames (all frames with z > 0 when a Gaussian is never observed,
all frames when not even that).

Time is the training-frame index 0..T-1 (T = video.num_frames = len(c2w) = len(dynamic_masks)).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Dict, Optional, Tuple

import torch

from m4dgs.core import rotation as rot
from m4dgs.core import spline
from m4dgs.core.camera import quat_multiply, rotmat_to_quat, video_to_camera
from m4dgs.model.gaussians import (
    GAIN_KEY,
    VideoGaussians,
    WorldGaussians,
    scale_activation,
    scale_inverse,
)
from m4dgs.raster.projection import NEAR_PLANE
from m4dgs.training.config import AblationConfig, V2WConfig
from m4dgs.training.v2w_scales import (
    _as_tensor,
    cov2d_fit_error,
    pinhole_cov2d,
    refit_scales,
    video_cov2d,
)

Tensor = torch.Tensor

# The rasterizer (m4dgs.raster.projection) widens the field of view by 30 % inside the EWA Jacobian;
# the V2W refit uses that same code, so its clamp is always this one (the authors' 1.3).
RASTER_FOV_CLAMP = 1.3
# Default relative depth tolerance of the occlusion test: occluded iff z > (1 + tol) x rendered
# depth (the config's V2WConfig.occlusion_tol, where the reason is given).
OCCLUSION_TOL = 0.05


# --------------------------------------------------------------------------------------------------
# dynamic / static identification
# --------------------------------------------------------------------------------------------------
def video_pixels(positions_video: Tensor, width: int, height: int) -> Tuple[Tensor, Tensor, Tensor]:
    """Nearest pixel of video-space points.

    Args:
        positions_video: [..., 3] (x, y in [-1, 1], z = depth).
    Returns:
        (col [...] long, row [...] long, inside [...] bool): the pixel (floor of the continuous
        coordinate u = (x + 1) W / 2, v = (y + 1) H / 2, whose centre is the nearest) and whether
        the point is in the image (0 <= u < W, 0 <= v < H, finite) and in front of the camera (z >
        0). col / row are clamped into the image.
    """
    u = (positions_video[..., 0] + 1.0) * (width / 2.0)
    v = (positions_video[..., 1] + 1.0) * (height / 2.0)
    z = positions_video[..., 2]
    finite = torch.isfinite(positions_video).all(-1)
    inside = finite & (u >= 0) & (u < width) & (v >= 0) & (v < height) & (z > 0)
    col = torch.nan_to_num(u).floor().clamp(0, width - 1).long()
    row = torch.nan_to_num(v).floor().clamp(0, height - 1).long()
    return col, row, inside


def dynamic_counts(
    positions_video: Tensor,
    dynamic_masks: Tensor,
    rendered_depth: Optional[Tensor],
    width: int,
    height: int,
    occlusion_handling: bool = True,
    occlusion_tol: float = OCCLUSION_TOL,
) -> Tensor:
    """N_d of the paper: frames where the Gaussian falls on the dynamic mask and is not occluded.

    Args:
        positions_video: [N, T, 3] video trajectories at the T frames. dynamic_masks: [T, H, W] bool
        (True = dynamic region). rendered_depth: [T, H, W] rendered video depth, or None (no
        occlusion information). occlusion_handling: apply o_t = [z > (1 + occlusion_tol) D_t(pixel)]
        (pixels with D <= 0 or non-finite
            never occlude); False (ablation) or rendered_depth None ignores occlusion.
    Returns:
        [N] long counts. Frames where the point is outside the image or behind the camera never
        count.
    """
    n, t_count, _ = positions_video.shape
    if dynamic_masks.shape[0] != t_count:
        raise ValueError(
            f"dynamic_masks has {dynamic_masks.shape[0]} frames, trajectories have {t_count}"
        )
    if tuple(dynamic_masks.shape[1:]) != (height, width):
        raise ValueError(
            f"dynamic_masks is {tuple(dynamic_masks.shape[1:])}, expected (H, W) = "
            f"{(height, width)}"
        )
    masks = dynamic_masks.to(device=positions_video.device, dtype=torch.bool)
    col, row, inside = video_pixels(positions_video, width, height)
    frame = torch.arange(t_count, device=positions_video.device)[None, :].expand(n, -1)
    hit = masks[frame, row, col] & inside  # [N, T]
    if occlusion_handling and rendered_depth is not None:
        if tuple(rendered_depth.shape) != tuple(dynamic_masks.shape):
            raise ValueError(
                f"rendered_depth is {tuple(rendered_depth.shape)}, masks "
                f"{tuple(dynamic_masks.shape)}"
            )
        depth = rendered_depth.to(device=positions_video.device, dtype=positions_video.dtype)
        d = depth[frame, row, col]
        occluded = (
            torch.isfinite(d) & (d > 0) & (positions_video[..., 2] > (1.0 + occlusion_tol) * d)
        )
        hit = hit & ~occluded
    return hit.sum(dim=1)


def classify_dynamic(
    positions_video: Tensor,
    dynamic_masks: Tensor,
    rendered_depth: Optional[Tensor],
    width: int,
    height: int,
    ratio: float = 0.1,
    occlusion_handling: bool = True,
    occlusion_tol: float = OCCLUSION_TOL,
) -> Tensor:
    """Dynamic in world space iff N_d / N_f > ratio (strict), N_f = T the number of frames (paper
    sec. 3.3.2).

    Args: as `dynamic_counts`; ratio: the paper's threshold 0.1.
    Returns:
        [N] bool.
    """
    nd = dynamic_counts(
        positions_video,
        dynamic_masks,
        rendered_depth,
        width,
        height,
        occlusion_handling,
        occlusion_tol,
    )
    t_count = positions_video.shape[1]
    return nd.double() / float(max(t_count, 1)) > float(ratio)


def classify_by_motion(
    positions_world: Tensor, valid: Tensor, std_threshold: float = 0.02
) -> Tensor:
    """Fallback without dynamic masks (authors' code): dynamic iff the world-position spread over
    the valid frames,
    sqrt(mean_t |mu^w_t - mean|^2) (world units), is at least `std_threshold`.

    Args:
        positions_world: [N, T, 3]; valid: [N, T] bool (frames that count; all-False rows count all
        frames).
    Returns:
        [N] bool.
    """
    w = _frame_weights(valid)
    mean = (positions_world * w[..., None]).sum(1) / w.sum(1, keepdim=True)
    var = (((positions_world - mean[:, None]) ** 2).sum(-1) * w).sum(1) / w.sum(1)
    return var.sqrt() >= std_threshold


# --------------------------------------------------------------------------------------------------
# position / rotation transform
# --------------------------------------------------------------------------------------------------
def video_to_world_trajectories(
    positions_video: Tensor, quats_video: Tensor, K: Tensor, c2w: Tensor, width: int, height: int
) -> Tuple[Tensor, Tensor]:
    """mu^w_t = R_t pi_K^-1(mu^v_t) + T_t and R^w_t = R_t R^v_t (paper sec. 3.3.2).

    Args:
        positions_video: [N, T, 3] video-space positions; quats_video: [N, T, 4] (wxyz) video
        rotations. K: [3, 3] pinhole intrinsics (pixels); c2w: [T, 4, 4] camera-to-world of the T
        frames.
    Returns:
        (positions_world [N, T, 3], quats_world [N, T, 4] unit wxyz), dtype / device of
        positions_video.
    """
    K = _as_tensor(K, positions_video)
    c2w = _as_tensor(c2w, positions_video)
    if c2w.shape[0] != positions_video.shape[1]:
        raise ValueError(
            f"c2w has {c2w.shape[0]} frames, trajectories have {positions_video.shape[1]}"
        )
    p_cam = video_to_camera(positions_video, K, width, height)  # [N, T, 3]
    R, T = c2w[:, :3, :3], c2w[:, :3, 3]
    pos_w = torch.einsum("tij,ntj->nti", R, p_cam) + T[None]
    q_cam = rotmat_to_quat(R).to(quats_video.dtype)  # [T, 4]
    q_w = rot.quat_normalize(quat_multiply(q_cam[None].expand_as(quats_video), quats_video))
    return pos_w, q_w


def world_to_cameras(
    positions_world: Tensor, quats_world: Tensor, c2w: Tensor
) -> Tuple[Tensor, Tensor]:
    """World Gaussians seen from each camera t: means R_t^T (mu - T_t) and rotations R_t^-1 R^w (W^w
    = R_t^-1).

    Args:
        positions_world: [N, T, 3]; quats_world: [N, T, 4]; c2w: [T, 4, 4].
    Returns:
        (means_cam [N, T, 3], quats_cam [N, T, 4]).
    """
    c2w = _as_tensor(c2w, positions_world)
    R, T = c2w[:, :3, :3], c2w[:, :3, 3]
    means_cam = torch.einsum("tji,ntj->nti", R, positions_world - T[None])
    q_cam = rotmat_to_quat(R).to(quats_world.dtype)
    q_inv = rot.quat_conjugate(q_cam)
    quats_cam = quat_multiply(q_inv[None].expand_as(quats_world), quats_world)
    return means_cam, quats_cam


def pixel_weights(
    positions_world: Tensor,
    valid: Tensor,
    K: Tensor,
    c2w: Tensor,
    pixel_sigma: float,
    depth_sigma: float,
) -> Tuple[Tensor, Tensor]:
    """Weights that make a world-space least-squares error read like pixels (V2WConfig.world_fit
    "pixel", beyond the paper).

    A small displacement e of a point at depth z in camera t moves its pixel by about f / z times
    the part of e across the viewing ray d, and its depth by the part along d. So
    W_t = (f / (pixel_sigma z))^2 (I - d d^T) + (1 / (depth_sigma z))^2 d d^T
    counts e in tolerances: pixel_sigma pixels across the ray, depth_sigma of the depth along it.

    Args:
        positions_world: [N, T, 3] lifted world trajectories. valid: [N, T] bool (frames to fit).
        K: [3, 3] intrinsics (f = (fx + fy) / 2). c2w: [T, 4, 4] camera-to-world.
        pixel_sigma: px; depth_sigma: relative.
    Returns:
        (weights [N, T, 3, 3], zero where not valid or behind the camera; reg_scale [N]: the mean
        across-ray weight over the valid frames, which keeps a smoothness term as strong, relative
        to the data, as in the unweighted world fit).
    """
    dtype = positions_world.dtype
    K = _as_tensor(K, positions_world)
    c2w = _as_tensor(c2w, positions_world)
    f = 0.5 * (K[0, 0] + K[1, 1])
    centre = c2w[:, :3, 3]  # [T, 3]
    offset = positions_world - centre[None]  # [N, T, 3]
    dist = offset.norm(dim=-1).clamp_min(1e-12)
    d = offset / dist[..., None]
    z = torch.einsum("ti,nti->nt", c2w[:, :3, 2], offset)  # depth along the optical axis
    ok = valid & (z > NEAR_PLANE)
    zs = torch.where(ok, z, torch.ones((), dtype=dtype, device=z.device))
    across = (f / (pixel_sigma * zs)) ** 2
    along = (1.0 / (depth_sigma * zs)) ** 2
    dd = d[..., :, None] * d[..., None, :]
    eye = torch.eye(3, dtype=dtype, device=positions_world.device)
    w = across[..., None, None] * (eye - dd) + along[..., None, None] * dd
    w = w * ok[..., None, None].to(dtype)
    n_ok = ok.sum(1).clamp_min(1)
    reg_scale = torch.where(ok, across, torch.zeros((), dtype=dtype)).sum(1) / n_ok
    reg_scale = torch.where(ok.any(1), reg_scale, torch.ones((), dtype=dtype))
    return w, reg_scale


# --------------------------------------------------------------------------------------------------
# the whole transform
# --------------------------------------------------------------------------------------------------
def _frame_weights(valid: Tensor) -> Tensor:
    """[N, T] float weights: the valid frames, or all frames for rows without any."""
    has = valid.any(1, keepdim=True)
    return torch.where(has, valid, torch.ones_like(valid)).to(torch.float64)


def observed_frames(positions_video: Tensor, width: int, height: int) -> Tensor:
    """[N, T] bool frames where the video Gaussian is in front of the camera and inside the image;
    rows with no such frame fall back to their frames with z > 0 (then to all frames)."""
    _, _, inside = video_pixels(positions_video, width, height)
    front = torch.isfinite(positions_video).all(-1) & (positions_video[..., 2] > 0)
    obs = torch.where(inside.any(1, keepdim=True), inside, front)
    return torch.where(obs.any(1, keepdim=True), obs, torch.ones_like(obs))


def _refine_rotation_keep_best(
    coeffs: Tensor, target: Tensor, tn: Tensor, valid: Tensor, steps: int, lr: float
) -> Tensor:
    """`rot.refine_rotation_poly`, keeping per Gaussian whichever coefficients have the smaller mean
    angle error."""
    refined = rot.refine_rotation_poly(coeffs, target, tn, valid, steps=steps, lr=lr)
    w = valid.to(torch.float64)

    def err(c: Tensor) -> Tensor:
        ang = rot.relative_rotation_angle(
            rot.poly_evaluate(c.double(), tn.double()), target.double()
        )
        return (ang * w).sum(1) / w.sum(1).clamp_min(1)

    better = err(refined) < err(coeffs)
    return torch.where(better[:, None, None], refined.to(coeffs.dtype), coeffs)


def transform(
    video: VideoGaussians,
    K,
    c2w,
    dynamic_masks: Optional[Tensor],
    rendered_depth: Optional[Tensor],
    cfg: Optional[V2WConfig] = None,
    ablation: Optional[AblationConfig] = None,
    width: int = 0,
    height: int = 0,
    *,
    world_scale_kind: str = "exp",
    world_scale_max: float = 1.0,
    occlusion_tol: Optional[float] = None,
    frames_per_step: int = 1,
) -> Tuple[WorldGaussians, Dict[str, Any]]:
    """Video Gaussians -> world Gaussians (paper sec. 3.3.2).

    Args:
        video: the stage-1 Gaussians (T = video.num_frames training frames). K: [3, 3] pinhole
        intrinsics; c2w: [T, 4, 4] camera-to-world (bundle adjustment), torch or numpy.
        dynamic_masks: [T, H, W] bool (epipolar-error masks), or None: then the authors' fallback
        classifies by
            world-position spread (`classify_by_motion`, cfg.static_std_fallback).
        rendered_depth: [T, H, W] video depth rendered from `video` (for the occlusion test), or
        None (no occlusion). cfg: V2W settings; ablation: `occlusion_handling` (b) and
        `cov_invariance` (c) switches. width, height: image size in pixels. world_scale_kind /
        world_scale_max: the world scale activation (ModelConfig.world_scale_activation / _max).
        occlusion_tol: relative depth tolerance of the occlusion test; None = cfg.occlusion_tol
        (V2WConfig, default OCCLUSION_TOL).
        frames_per_step: frames per Gaussian per refit step (`refit_scales`).
    Returns:
        (WorldGaussians (static first, then dynamic, each in video order), report) with report keys:
        "num_static", "num_dynamic", "num_gaussians", "classification" ("masks" |
        "motion_fallback"), "occlusion_used", "cov_invariance", "scale_fit" (the `refit_scales`
        info, or the inherit-mode covariance error), "time_s" {classify, transform, scales, total};
        and "is_dynamic": [N] bool tensor (video order) - the only non-JSON entry.

    The steps of the module docstring, each a function: `_sample_video` (trajectories in video and
    world space), `_identify_dynamic` (1), `_static_set` / `_dynamic_set` (2, 3), `_world_scales`
    (5), `_assemble_world` (4: opacities and features copied, the two sets put together).
    """
    cfg = cfg or V2WConfig()
    ablation = ablation or AblationConfig()
    if occlusion_tol is None:
        occlusion_tol = cfg.occlusion_tol
    if width <= 0 or height <= 0:
        raise ValueError("transform: width and height (pixels) are required")
    t0 = time.perf_counter()
    timings: Dict[str, float] = {}
    v = _sample_video(video, K, c2w, width, height)

    # 1. dynamic / static identification
    tc = time.perf_counter()
    is_dyn, how, occlusion_used = _identify_dynamic(
        v, dynamic_masks, rendered_depth, cfg, ablation, width, height, occlusion_tol
    )
    timings["classify"] = time.perf_counter() - tc

    # 2./3. positions and rotations
    tt = time.perf_counter()
    s_idx = torch.where(~is_dyn)[0]
    d_idx = torch.where(is_dyn)[0]
    means_s, quats_s = _static_set(v, s_idx)
    degree = video.params["rot"].shape[1] - 1
    ctrl_d, coeffs_d = _dynamic_set(v, d_idx, cfg, degree)
    timings["transform"] = time.perf_counter() - tt

    # 5. scales
    tsc = time.perf_counter()
    order = torch.cat([s_idx, d_idx])
    pos_final, quat_final = _final_trajectories(v, means_s, quats_s, ctrl_d, coeffs_d)
    raw_w, fit_info = _world_scales(
        v,
        order,
        pos_final,
        quat_final,
        cfg,
        ablation,
        width,
        height,
        world_scale_kind,
        world_scale_max,
        frames_per_step,
    )
    timings["scales"] = time.perf_counter() - tsc

    # 4. opacities and features, and the world Gaussians
    world = _assemble_world(
        video,
        v,
        s_idx,
        d_idx,
        means_s,
        quats_s,
        ctrl_d,
        coeffs_d,
        raw_w,
        world_scale_kind,
        world_scale_max,
    )
    timings["total"] = time.perf_counter() - t0
    ns = s_idx.numel()
    report = {
        "num_static": int(ns),
        "num_dynamic": int(d_idx.numel()),
        "num_gaussians": int(ns + d_idx.numel()),
        "classification": how,
        "occlusion_used": occlusion_used,
        "cov_invariance": bool(ablation.cov_invariance),
        "scale_fit": fit_info,
        "time_s": {k: float(sec) for k, sec in timings.items()},
        "is_dynamic": is_dyn,
    }
    return world, report


@dataclass
class _Sampled:
    """The stage-1 Gaussians at every training frame (no gradient), in video and world space."""

    pos_v: Tensor  # [N, T, 3] video-space positions
    quat_v: Tensor  # [N, T, 4] video-space quaternions
    scales_v: Tensor  # [N, 3] video scales (activated)
    obs: Tensor  # [N, T] bool observed frames (`observed_frames`)
    pos_w: Tensor  # [N, T, 3] world trajectories
    quat_w: Tensor  # [N, T, 4] world quaternions
    times: Tensor  # [T] training-frame indices
    tn: Tensor  # [T] normalised times of the rotation polynomial
    knots: Tensor  # spline knots of the video Gaussians
    K: Tensor  # [3, 3]
    c2w: Tensor  # [T, 4, 4]
    dtype: torch.dtype  # of the video Gaussians' parameters
    device: torch.device

    @property
    def num_frames(self) -> int:
        return int(self.times.shape[0])


def _sample_video(video: VideoGaussians, K, c2w, width: int, height: int) -> _Sampled:
    """Positions, rotations and scales of the video Gaussians at the training frames, their
    observed frames and their world trajectories (step 2's mu^w_t = R_t pi_K^-1(mu^v_t) + T_t)."""
    ctrl_v = video.params["ctrl"].detach()
    dtype, device = ctrl_v.dtype, ctrl_v.device
    t_count = video.num_frames
    times = torch.arange(t_count, dtype=dtype, device=device)
    K_t = _as_tensor(K, ctrl_v)
    c2w_t = _as_tensor(c2w, ctrl_v)
    if c2w_t.shape[0] != t_count:
        raise ValueError(
            f"transform: c2w has {c2w_t.shape[0]} frames, the video Gaussians {t_count}"
        )
    with torch.no_grad():
        pos_v = video.positions(times).detach()  # [N, T, 3]
        quat_v = video.quats(times).detach()  # [N, T, 4]
        scales_v = video.scales().detach()
        obs = observed_frames(pos_v, width, height)
        pos_w, quat_w = video_to_world_trajectories(pos_v, quat_v, K_t, c2w_t, width, height)
        tn = rot.normalize_time(times, t_count).to(dtype)
    knots = video.knots.detach()
    return _Sampled(
        pos_v, quat_v, scales_v, obs, pos_w, quat_w, times, tn, knots, K_t, c2w_t, dtype, device
    )


def _identify_dynamic(
    v: _Sampled,
    dynamic_masks: Optional[Tensor],
    rendered_depth: Optional[Tensor],
    cfg: V2WConfig,
    ablation: AblationConfig,
    width: int,
    height: int,
    occlusion_tol: float,
) -> Tuple[Tensor, str, bool]:
    """Step 1: (is_dynamic [N] bool, "masks" | "motion_fallback", whether the occlusion test was
    used): the dynamic masks with the occlusion test (`classify_dynamic`), or without masks the
    authors' world-position spread fallback (`classify_by_motion`)."""
    occlusion_used = bool(
        ablation.occlusion_handling and rendered_depth is not None and dynamic_masks is not None
    )
    if dynamic_masks is None:
        with torch.no_grad():
            is_dyn = classify_by_motion(v.pos_w, v.obs, cfg.static_std_fallback)
        return is_dyn, "motion_fallback", occlusion_used
    with torch.no_grad():
        masks = torch.as_tensor(dynamic_masks).to(device=v.device, dtype=torch.bool)
        depth = (
            None
            if rendered_depth is None
            else torch.as_tensor(rendered_depth).to(device=v.device, dtype=v.dtype)
        )
        is_dyn = classify_dynamic(
            v.pos_v,
            masks,
            depth,
            width,
            height,
            cfg.dynamic_ratio,
            ablation.occlusion_handling,
            occlusion_tol,
        )
    return is_dyn, "masks", occlusion_used


def _static_set(v: _Sampled, s_idx: Tensor) -> Tuple[Tensor, Tensor]:
    """Step 3, static Gaussians: (means [Ns, 3], quaternions [Ns, 4]) = the weighted mean world
    position over the observed frames and the Markley average of the world quaternions."""
    with torch.no_grad():
        w_s = _frame_weights(v.obs[s_idx]).to(v.dtype)  # [Ns, T]
        means_s = (v.pos_w[s_idx] * w_s[..., None]).sum(1) / w_s.sum(1)[:, None]
        quats_s = rot.quat_average_markley(v.quat_w[s_idx], w_s).to(v.dtype)
    return means_s, quats_s


def _dynamic_set(v: _Sampled, d_idx: Tensor, cfg: V2WConfig, degree: int) -> Tuple[Tensor, Tensor]:
    """Step 3, dynamic Gaussians: (spline control points re-sampled from the world trajectory on the
    video knots, rotation-polynomial coefficients fitted by least squares, optionally refined)."""
    obs_d = v.obs[d_idx]
    with torch.no_grad():
        if cfg.world_fit == "pixel":
            weights, reg_scale = pixel_weights(
                v.pos_w[d_idx], obs_d, v.K, v.c2w, cfg.pixel_sigma, cfg.depth_sigma
            )
            ctrl_d = spline.fit_control_points_weighted(
                v.pos_w[d_idx],
                weights,
                v.times,
                v.knots,
                smooth=spline.RESAMPLE_SMOOTH,
                reg_scale=reg_scale,
            )
        elif cfg.resample == "lstsq":
            ctrl_d = spline.resample_control_points(
                v.pos_w[d_idx], v.times, v.knots, valid=obs_d, method="lstsq"
            )
        else:
            ctrl_d = spline.resample_control_points(
                v.pos_w[d_idx], v.times, v.knots, method=cfg.resample
            )
    coeffs_d = rot.fit_rotation_poly(v.quat_w[d_idx], v.tn, obs_d, degree=degree)
    if cfg.rotation_refine_steps > 0 and d_idx.numel() > 0:
        coeffs_d = _refine_rotation_keep_best(
            coeffs_d, v.quat_w[d_idx], v.tn, obs_d, cfg.rotation_refine_steps, cfg.rotation_refit_lr
        )
    return ctrl_d, coeffs_d


def _final_trajectories(
    v: _Sampled, means_s: Tensor, quats_s: Tensor, ctrl_d: Tensor, coeffs_d: Tensor
) -> Tuple[Tensor, Tensor]:
    """The final world Gaussians along time (what stage 2 renders): positions [N, T, 3] and
    quaternions [N, T, 4], static first then dynamic."""
    t_count = v.num_frames
    with torch.no_grad():
        pos_final = torch.cat(
            [means_s[:, None].expand(-1, t_count, -1), spline.evaluate(ctrl_d, v.knots, v.times)]
        )
        quat_final = torch.cat(
            [
                quats_s[:, None].expand(-1, t_count, -1),
                rot.poly_evaluate(coeffs_d, v.tn, normalize=True),
            ]
        )
    return pos_final, quat_final


def _world_scales(
    v: _Sampled,
    order: Tensor,
    pos_final: Tensor,
    quat_final: Tensor,
    cfg: V2WConfig,
    ablation: AblationConfig,
    width: int,
    height: int,
    world_scale_kind: str,
    world_scale_max: float,
    frames_per_step: int,
) -> Tuple[Tensor, Dict[str, Any]]:
    """Step 5: (raw world scales [N, 3] in `order`, fit info). With covariance invariance the scales
    are refitted so the world 2D covariances match the video ones (`refit_scales`, started at the
    NDC -> metric factor of the median depth); without (ablation (c)) the video scale values are
    inherited and only their covariance error is reported."""
    K_t = v.K
    with torch.no_grad():
        # the final world Gaussians seen from every camera
        means_cam, quats_cam = world_to_cameras(pos_final, quat_final, v.c2w)
        target = video_cov2d(v.pos_v[order], v.quat_v[order], v.scales_v[order], width, height)
        _, mu2d = pinhole_cov2d(
            means_cam, quats_cam, torch.ones_like(v.scales_v[order]), K_t, width, height
        )
        in_img = (
            (means_cam[..., 2] >= NEAR_PLANE)
            & (mu2d[..., 0] >= 0)
            & (mu2d[..., 0] < width)
            & (mu2d[..., 1] >= 0)
            & (mu2d[..., 1] < height)
        )
        _, _, inside_v = video_pixels(v.pos_v[order], width, height)
        fit_valid = in_img & inside_v
    if ablation.cov_invariance:
        # initial guess: the NDC -> metric factor of the back-projection, x_c = x_ndc (W/2) z / fx,
        # at the median depth
        z = torch.where(
            fit_valid, means_cam[..., 2], torch.full_like(means_cam[..., 2], float("nan"))
        )
        z_med = torch.nanmedian(z, dim=1).values
        z_med = torch.where(
            torch.isfinite(z_med),
            z_med,
            means_cam[..., 2].abs().median(dim=1).values.clamp_min(NEAR_PLANE),
        )
        init = v.scales_v[order] * (width / 2.0) * z_med[:, None] / K_t[0, 0]
        return refit_scales(
            target,
            means_cam,
            quats_cam,
            fit_valid,
            K_t,
            width,
            height,
            init,
            scale_kind=world_scale_kind,
            scale_max=world_scale_max,
            steps=cfg.scale_refit_steps,
            lr=cfg.scale_refit_lr,
            frames_per_step=frames_per_step,
            seed=cfg.seed,
        )
    # "inherit": the same scale values, read in world units
    raw_w = scale_inverse(v.scales_v[order], world_scale_kind, world_scale_max)
    err = cov2d_fit_error(
        target,
        means_cam,
        quats_cam,
        fit_valid,
        scale_activation(raw_w, world_scale_kind, world_scale_max),
        K_t,
        width,
        height,
    )
    has = fit_valid.any(1)
    fit_info = {
        "loss_l1": float(err["l1"][has].mean()) if has.any() else 0.0,
        "rel_err": float(err["rel"][has].mean()) if has.any() else 0.0,
        "num_fitted": 0,
        "steps": 0,
    }
    return raw_w, fit_info


def _assemble_world(
    video: VideoGaussians,
    v: _Sampled,
    s_idx: Tensor,
    d_idx: Tensor,
    means_s: Tensor,
    quats_s: Tensor,
    ctrl_d: Tensor,
    coeffs_d: Tensor,
    raw_w: Tensor,
    world_scale_kind: str,
    world_scale_max: float,
) -> WorldGaussians:
    """Step 4 and the result: opacity logits and colour features copied from the video Gaussians
    (with their log2 gain over time when they carry one, beyond the paper), the static set (mean +
    quaternion) and the dynamic set (spline + rotation polynomial)."""
    ns = s_idx.numel()
    opac = video.params["opacities"].detach()
    feats = video.params["features"].detach()
    gain = video.gain_values()
    static = {
        "means": means_s.clone(),
        "quats": quats_s.clone(),
        "scales": raw_w[:ns].clone(),
        "opacities": opac[s_idx].clone(),
        "features": feats[s_idx].clone(),
    }
    dynamic = {
        "ctrl": ctrl_d.to(v.dtype).clone(),
        "rot": coeffs_d.detach().to(v.dtype).clone(),
        "scales": raw_w[ns:].clone(),
        "opacities": opac[d_idx].clone(),
        "features": feats[d_idx].clone(),
    }
    if gain is not None:
        gain = gain.detach()
        static[GAIN_KEY] = gain[s_idx].clone()
        dynamic[GAIN_KEY] = gain[d_idx].clone()
    return WorldGaussians(
        static, dynamic, v.knots.clone(), v.num_frames, world_scale_kind, world_scale_max
    )


__all__ = [
    "OCCLUSION_TOL",
    "RASTER_FOV_CLAMP",
    "video_pixels",
    "dynamic_counts",
    "classify_dynamic",
    "classify_by_motion",
    "video_to_world_trajectories",
    "world_to_cameras",
    "video_cov2d",
    "pinhole_cov2d",
    "cov2d_fit_error",
    "refit_scales",
    "observed_frames",
    "transform",
]
