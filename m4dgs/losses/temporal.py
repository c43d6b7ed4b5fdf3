"""Losses between neighbouring frames: temporal luminance regularisation and photometric
reprojection.

Temporal luminance regularisation (TLR, paper Sec. 3.3.3):
    L_tlr = | V_{t->t'} * (H~_{t'->t} - H~_t) / (H~_{t'->t} + H~_t) |_1,   t' in {t - 1, t + 1},
where H~_{t'->t} = W(H~_{t'}, F~_{t->t'}) is the neighbour's HDR render backward-warped onto frame t
with the RENDERED flow (stopped gradients; the warped neighbour carries no gradient either). The
normalisation removes the HDR scale; the authors detach the denominator (default here,
``detach_denominator``). The value is the mean over valid
pixels and the three channels, so a global flicker of ratio r gives |r - 1| / (r + 1).

Validity V from depth order (`tlr_valid_mask`), made precise here: let z_ref(p) be the depth that
pixel p's surface point has at t' in the camera of t' (the z channel of the destination-position
map; the current depth D~_t(p) is a fallback when that is not available) and D_w(p) = W(D~_{t'},
F~_{t->t'})(p) the neighbour's rendered depth at the flowed position. The point is occluded at t'
when it lies behind the surface seen there by more than 10 %: ``z_ref > 1.1 * D_w`` (authors' 1.1
factor). ``mode="symmetric"`` also rejects ``D_w > 1.1 * z_ref`` (the flowed position shows
something farther than the point, e.g. at blended edges). Pixels whose flowed position leaves the
image are invalid.

HDR photometric reprojection loss (paper appendix, stage 2, static pixels only):
    u_{t->t'} = pi_K(R_t' R_t^-1 (pi_K^-1(u_t, D_t(u_t)) - T_t) + T_t')
in the paper, where [R | T] is WORLD-TO-CAMERA (x_cam = R x_world + T). With our camera-to-world
extrinsics (x_world = R_c x_cam + T_c, R_c = R^T, T_c = -R^T T) the same map reads
    x_t' = c2w_t'^-1 c2w_t x_t,   x_t = pi_K^-1(u_t, D_t(u_t)),   u_{t->t'} = pi_K(x_t'),
which is what `reprojection_coords` computes. The stage-1 HDR frame H_t' (stopped gradients) is
sampled bilinearly at u_{t->t'} and compared with H_t:
    L_pr = | (1 - M_t) * (H_{t'->t} - H_t) / (H_{t'->t} + H_t) |_1   (mean over static, in-bounds
    pixels).
Gradients reach the rendered depth D_t, H_t and the camera poses (through the sampling position).
The LDR variant (`ldr_reprojection_loss`, SplineGS-style baselines) uses a plain L1 between two LDR
frames: of the same exposure (i +- N_e), or consecutive and differently exposed (i +- 1) as
SplineGS-HDR in the paper (m4dgs.training.stage2.ldr_reprojection_refs)."""

from __future__ import annotations

import torch

from m4dgs.core.camera import (
    invert_rigid,
    pixel_centers,
    project_pinhole,
    transform_points,
    unproject_pinhole,
)
from m4dgs.core.warp import backward_warp
from m4dgs.losses.geometry import Z_MIN, in_bounds

TLR_DEPTH_RATIO = 1.1  # authors: occlusion test at 1.1x depth


def relative_difference(
    a: torch.Tensor,
    b: torch.Tensor,
    detach_denominator: bool = True,
    eps: float = 1e-10,
    floor: float | torch.Tensor = 0.0,
) -> torch.Tensor:
    """|a - b| / (a + b + eps + floor), elementwise; the denominator is detached when asked
    (authors). floor: a scalar (float or 0-d tensor, not differentiated) added to the denominator
    (TLR's `loss.tlr_den_floor`); 0 leaves the paper's normalisation, computed as before."""
    den = a + b + eps
    if not (isinstance(floor, float) and floor == 0.0):
        den = den + torch.as_tensor(floor, dtype=den.dtype, device=den.device).detach()
    if detach_denominator:
        den = den.detach()
    return (a - b).abs() / den


def _masked_channel_mean(err: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """err [H, W, C], valid [H, W] bool -> mean over valid pixels and channels (0 if none)."""
    m = valid.to(err.dtype)[..., None]
    err = torch.where(valid[..., None], err, torch.zeros_like(err))
    return (err * m).sum() / (m.sum() * err.shape[-1]).clamp_min(1.0)


def flow_in_bounds(flow: torch.Tensor) -> torch.Tensor:
    """[H, W] bool: pixel + flow lies between the first and last pixel centres."""
    h, w = flow.shape[:2]
    uv = pixel_centers(w, h, dtype=flow.dtype, device=flow.device) + flow
    return in_bounds(uv, w, h)


def tlr_valid_mask(
    flow: torch.Tensor,
    depth_nb: torch.Tensor,
    depth_ref: torch.Tensor,
    ratio: float = TLR_DEPTH_RATIO,
    mode: str = "occlusion",
) -> torch.Tensor:
    """Depth-order validity of warping frame t' onto frame t (see the module docstring).

    Args:
        flow: [H, W, 2] rendered flow F~_{t->t'}. depth_nb: [H, W] rendered depth at t'. depth_ref:
        [H, W] depth of each pixel's point at t' (z of the destination-position map), or D~_t.
        ratio: tolerance factor (1.1); mode: "occlusion" or "symmetric".
    Returns:
        [H, W] bool mask (no gradient).
    """
    with torch.no_grad():
        dw = backward_warp(depth_nb.detach()[..., None], flow.detach())[..., 0]
        ref = depth_ref.detach()
        valid = flow_in_bounds(flow) & (dw > 0) & (ref > 0) & (ref <= ratio * dw)
        if mode == "symmetric":
            valid = valid & (dw <= ratio * ref)
        elif mode != "occlusion":
            raise ValueError(f"tlr_valid_mask: unknown mode {mode!r}")
    return valid


def tlr_loss(
    hdr_t: torch.Tensor,
    hdr_nb: torch.Tensor,
    flow: torch.Tensor,
    valid: torch.Tensor | None = None,
    detach_denominator: bool = True,
    detach_neighbour: bool = True,
    den_floor: float | torch.Tensor = 0.0,
) -> torch.Tensor:
    """Temporal luminance regularisation for one neighbour t' (call for t - 1 and t + 1 and
    average).

    Args:
        hdr_t: [H, W, 3] HDR render at t (receives the gradient).
        hdr_nb: [H, W, 3] HDR render at the neighbour t' (detached when ``detach_neighbour``).
        flow: [H, W, 2] rendered flow F~_{t->t'} (always detached).
        valid: optional [H, W] bool (e.g. `tlr_valid_mask`); out-of-image flows are always excluded.
        detach_denominator: detach (H_w + H_t) as the authors do.
        den_floor: scalar added to the denominator (not differentiated; `tlr_den_floor` gives
            it from the render's median); 0 = the paper's.
    Returns:
        scalar: mean over valid pixels and channels of |H_w - H_t| / (H_w + H_t + den_floor).
    """
    nb = hdr_nb.detach() if detach_neighbour else hdr_nb
    flow = flow.detach()
    warped = backward_warp(nb, flow)
    m = flow_in_bounds(flow)
    if valid is not None:
        m = m & valid.bool()
    return _masked_channel_mean(
        relative_difference(warped, hdr_t, detach_denominator, floor=den_floor), m
    )


def tlr_den_floor(hdr_t: torch.Tensor, fraction: float) -> float | torch.Tensor:
    """The denominator floor of `loss.tlr_den_floor`: fraction x the median of the render hdr_t
    [H, W, 3] over pixels and channels (torch's median: the lower middle value; detached, 0-d), or
    the float 0.0 when fraction is 0 (the paper's TLR, computed exactly as without the option)."""
    if fraction == 0:
        return 0.0
    return fraction * hdr_t.detach().median()


def tlr_loss_neighbours(
    hdr_t: torch.Tensor,
    neighbours: list[dict],
    ratio: float = TLR_DEPTH_RATIO,
    mode: str = "occlusion",
    detach_denominator: bool = True,
) -> torch.Tensor:
    """TLR at query time t averaged over its neighbours (t - 1 and t + 1 in the paper).

    Args:
        hdr_t: [H, W, 3] HDR render at t. neighbours: one dict per neighbour t' with keys "hdr" [H,
        W, 3] (render at t'), "flow" [H, W, 2] (rendered
            F~_{t->t'}), and optionally "depth" [H, W] (render at t') with "depth_ref" [H, W] (depth
            of each pixel's point at t', e.g. z of the destination-position map, or D~_t) to apply
            the depth-order mask.
        ratio, mode: see `tlr_valid_mask`; detach_denominator: see `tlr_loss`.
    Returns:
        scalar: mean of the per-neighbour losses (0 for an empty list).
    """
    losses = []
    for nb in neighbours:
        valid = None
        if nb.get("depth") is not None and nb.get("depth_ref") is not None:
            valid = tlr_valid_mask(nb["flow"], nb["depth"], nb["depth_ref"], ratio, mode)
        losses.append(tlr_loss(hdr_t, nb["hdr"], nb["flow"], valid, detach_denominator))
    if not losses:
        return hdr_t.sum() * 0.0
    return torch.stack(losses).mean()


def reprojection_coords(
    depth_t: torch.Tensor,
    K: torch.Tensor,
    c2w_t: torch.Tensor,
    c2w_tp: torch.Tensor,
    z_min: float = Z_MIN,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Where each pixel of frame t lands in frame t' given its depth and the two camera poses.

    Args:
        depth_t: [H, W] z-depth at t; K: [3, 3]; c2w_t, c2w_tp: [4, 4] camera-to-world poses (may
        require grad).
    Returns:
        (uv [H, W, 2] continuous pixel coordinates in t' (centres at +0.5), valid [H, W] bool: depth
        in t' > z_min).
    """
    h, w = depth_t.shape
    dt = depth_t.dtype
    K = K.to(dt)
    x_t = unproject_pinhole(pixel_centers(w, h, dtype=dt, device=depth_t.device), depth_t, K)
    rel = invert_rigid(c2w_tp.to(dt)) @ c2w_t.to(dt)  # camera t -> camera t'
    x_tp = transform_points(rel, x_t)
    z = x_tp[..., 2]
    valid = z > z_min
    z_safe = torch.where(valid, z, torch.ones_like(z))
    uv = project_pinhole(torch.cat([x_tp[..., :2], z_safe[..., None]], dim=-1), K)
    return uv, valid


def _reproject(image_tp: torch.Tensor, depth_t, K, c2w_t, c2w_tp, z_min):
    """image_tp [H, W, C] sampled at u_{t->t'} -> (warped [H, W, C], valid [H, W])."""
    h, w = depth_t.shape
    uv, ok = reprojection_coords(depth_t, K, c2w_t, c2w_tp, z_min)
    flow = uv - pixel_centers(w, h, dtype=uv.dtype, device=uv.device)
    warped = backward_warp(image_tp.to(uv.dtype), flow)
    return warped, ok & in_bounds(uv, image_tp.shape[1], image_tp.shape[0])


def hdr_reprojection_loss(
    hdr_t: torch.Tensor,
    hdr_tp: torch.Tensor,
    depth_t: torch.Tensor,
    K: torch.Tensor,
    c2w_t: torch.Tensor,
    c2w_tp: torch.Tensor,
    dynamic_mask: torch.Tensor | None = None,
    detach_denominator: bool = False,
    z_min: float = Z_MIN,
) -> torch.Tensor:
    """HDR photometric reprojection loss L_pr (see the module docstring for the pose convention).

    Args:
        hdr_t: [H, W, 3] HDR image at t: the stage-1 frame (paper, stage2.pr_query="stage1") or the
        stage-2 render
            (gradient flows where it has one).
        hdr_tp: [H, W, 3] stage-1 HDR frame at t' (detached here).
        depth_t: [H, W] rendered depth at t (gradient flows).
        K: [3, 3] intrinsics; c2w_t, c2w_tp: [4, 4] camera-to-world poses (gradient flows).
        dynamic_mask: optional [H, W] bool M_t (True = dynamic pixel, excluded).
        detach_denominator: detach (H_w + H_t) (paper formula: not detached).
    Returns:
        scalar: mean over static, in-bounds pixels with positive depth in t' and over channels.
    """
    warped, valid = _reproject(hdr_tp.detach(), depth_t, K, c2w_t, c2w_tp, z_min)
    if dynamic_mask is not None:
        valid = valid & ~dynamic_mask.bool()
    return _masked_channel_mean(
        relative_difference(warped, hdr_t.to(warped.dtype), detach_denominator), valid
    )


def ldr_reprojection_loss(
    ldr_t: torch.Tensor,
    ldr_tp: torch.Tensor,
    depth_t: torch.Tensor,
    K: torch.Tensor,
    c2w_t: torch.Tensor,
    c2w_tp: torch.Tensor,
    dynamic_mask: torch.Tensor | None = None,
    z_min: float = Z_MIN,
) -> torch.Tensor:
    """Plain L1 photometric reprojection between two LDR frames (SplineGS-style baselines);
    meaningful for frames of the same exposure, biased by the exposure ratio between differently
    exposed ones (the paper's SplineGS-HDR case).

    Args:
        ldr_t, ldr_tp: [H, W, 3] LDR frames at t and t' (input frames); depth_t, K, c2w_t, c2w_tp,
        dynamic_mask as in
            `hdr_reprojection_loss`.
    Returns:
        scalar: mean over static, in-bounds pixels and channels of |L_{t'->t} - L_t|.
    """
    warped, valid = _reproject(ldr_tp, depth_t, K, c2w_t, c2w_tp, z_min)
    if dynamic_mask is not None:
        valid = valid & ~dynamic_mask.bool()
    return _masked_channel_mean((warped - ldr_t.to(warped.dtype)).abs(), valid)
