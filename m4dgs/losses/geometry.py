"""Geometry and motion supervision from 2D priors (paper appendix "Supervision from 2D Priors").

Depth: L_dep = |D~_t - D_t|_1 over the prior's valid pixels.

Flow / track: the rasterizer renders, at the query time t and from the camera of t, the Gaussians'
positions at the destination time t' as 3 extra alpha-blended feature channels (the
"destination-position map" P [H, W, 3]). Each pixel's predicted destination is the projection of its
blended destination position:

- Video space (stage 1, orthographic): P holds (x, y, z) of video Gaussians at t'; the destination
  pixel in continuous coordinates (pixel centres at integer + 0.5, m4dgs.core.camera) is
  ``u = (x + 1) W / 2, v = (y + 1) H / 2`` (`m4dgs.core.camera.ortho_to_pixel`). The authors
  write ``u = (x + 1) W / 2 - 0.5`` because they work in pixel-index coordinates (centre of pixel i
  at i); flows, being differences of two positions in the same coordinates, are identical in both
  conventions. Source pixel = the pixel's own centre, so
  ``F~_{t->t'}(p) = ortho_to_pixel(P(p)[:2]) - centre(p)``.
- World space (stage 2, pinhole): the paper's flow is F_{t->t'} = pi(K, w2c_t' mu_t') - pi(K, w2c_t
  mu_t). We blend *positions* and project *after* blending (the MoSca / Shape-of-Motion approach): P
  holds either world positions at t' (then pass ``w2c_dst`` = w2c_t' and they are moved to the
  destination camera after blending; rigid transforms commute with a normalised weighted mean, so
  this equals blending destination-camera positions) or positions already in the destination camera
  frame (``w2c_dst=None``). The source term pi(K, w2c_t mu_t) of the blended Gaussians is the pixel
  centre itself (the render is from camera t), so again F~ = pi(K, P_cam) - centre(p).
- If the rasterizer returns un-normalised blends (sum_i w_i mu_i with sum_i w_i = alpha < 1), pass
  ``alpha``: the map is divided by alpha before any transform or projection (an un-normalised blend
  would be shrunk towards the origin).
- A destination is valid when its depth in the destination camera is > z_min = 1e-4 (authors' mask;
  for video space z is the depth itself).

Flow loss (dense prior, between same-exposure frames t' = t +- N_e): mean over the prior's valid
pixels of the
per-pixel distance |F~ - F|. Track loss (sparse tracks, any t'): the destination-position map is
sampled bilinearly
at each track's source pixel, projected, and compared with the track's destination pixel. Paper: L1
distance
(|du| + |dv|), no clamp (default); authors' code: Euclidean (L2) pixel distance clamped at 100
(``norm="l2",
clamp=100``).
"""

from __future__ import annotations

import torch

from m4dgs.core.camera import ortho_to_pixel, pixel_centers, project_pinhole, transform_points
from m4dgs.core.warp import sample_map

Z_MIN = 1e-4  # authors: destination depth must exceed 1e-4
TRACK_CLAMP_AUTHORS = 100.0  # authors: L2 pixel distance clamped at 100


# --------------------------------------------------------------------------------------------------
# Depth
# --------------------------------------------------------------------------------------------------
def _ssi_normalise(d: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    """(d - median) / mean|d - median| over the mask (scale-and-shift normalisation)."""
    med = d[m].median()
    scale = (d[m] - med).abs().mean().clamp_min(1e-8)
    return (d - med) / scale


def depth_loss(
    pred: torch.Tensor,
    prior: torch.Tensor,
    valid: torch.Tensor | None = None,
    scale_shift_invariant: bool = False,
) -> torch.Tensor:
    """Masked L1 depth loss.

    Args:
        pred: [H, W] rendered depth D~_t. prior: [H, W] prior depth D_t; non-finite or non-positive
        prior pixels are always excluded. valid: optional [H, W] bool mask of usable prior pixels.
        scale_shift_invariant: compare after normalising each map by its median and mean absolute
        deviation over the
            valid pixels (an option of the authors' code for relative-depth priors); False = paper's
            plain L1.
    Returns:
        scalar: mean over valid pixels of |pred - prior| (0 if no pixel is valid).
    """
    m = torch.isfinite(prior) & (prior > 0)
    if valid is not None:
        m = m & valid.bool()
    if not bool(m.any()):
        return pred.sum() * 0.0
    prior = torch.where(m, prior, torch.zeros_like(prior))
    if scale_shift_invariant:
        pred, prior = _ssi_normalise(pred, m), _ssi_normalise(prior, m)
    return (pred - prior).abs()[m].mean()


# --------------------------------------------------------------------------------------------------
# Destination-position maps -> pixels / flow
# --------------------------------------------------------------------------------------------------
def normalize_by_alpha(
    feature_map: torch.Tensor, alpha: torch.Tensor, eps: float = 1e-6
) -> torch.Tensor:
    """Divide an alpha-blended feature map [..., C] by the accumulated alpha [...] or [..., 1]
    (clamped at eps)."""
    if alpha.dim() == feature_map.dim() - 1:
        alpha = alpha.unsqueeze(-1)
    return feature_map / alpha.clamp_min(eps)


def destination_pixels(
    positions: torch.Tensor,
    *,
    width: int | None = None,
    height: int | None = None,
    K: torch.Tensor | None = None,
    w2c_dst: torch.Tensor | None = None,
    z_min: float = Z_MIN,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Continuous destination pixel of blended destination positions.

    Args:
        positions: [..., 3] destination positions (alpha-normalised). width, height: image size;
        required for the orthographic video camera (K is None). K: [3, 3] pinhole intrinsics (world
        / camera space); None selects video space (orthographic). w2c_dst: optional [4, 4]
        world-to-camera of the destination frame, applied before projection (pinhole only). z_min:
        minimum destination depth of a valid point.
    Returns:
        (uv [..., 2] continuous pixel coordinates (centres at +0.5), valid [...] bool: depth >
        z_min). Invalid pixels get a finite (meaningless) uv.
    """
    if K is None:
        if width is None or height is None:
            raise ValueError(
                "destination_pixels: the orthographic video camera needs width and height"
            )
        uv = ortho_to_pixel(positions[..., :2], width, height)
        return uv, positions[..., 2] > z_min
    p = positions if w2c_dst is None else transform_points(w2c_dst.to(positions), positions)
    z = p[..., 2]
    valid = z > z_min
    z_safe = torch.where(valid, z, torch.ones_like(z))
    uv = project_pinhole(torch.cat([p[..., :2], z_safe[..., None]], dim=-1), K.to(positions))
    return uv, valid


def flow_from_destination_map(
    dest_map: torch.Tensor,
    *,
    K: torch.Tensor | None = None,
    w2c_dst: torch.Tensor | None = None,
    alpha: torch.Tensor | None = None,
    alpha_min: float = 1e-3,
    z_min: float = Z_MIN,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Rendered flow F~_{t->t'} from a rendered destination-position map (see the module docstring).

    Args:
        dest_map: [H, W, 3] blended destination positions (video (x, y, z) when K is None; world
        positions with
            ``w2c_dst``; destination-camera positions without).
        K: [3, 3] pinhole intrinsics, or None for the video-space orthographic camera. w2c_dst:
        optional [4, 4] world-to-camera of the destination frame t'. alpha: optional [H, W]
        accumulated alpha; the map is normalised by it and pixels with alpha <= alpha_min are
            invalid.
    Returns:
        (flow [H, W, 2] in pixels, valid [H, W] bool).
    """
    h, w = dest_map.shape[:2]
    valid_a = None
    if alpha is not None:
        dest_map = normalize_by_alpha(dest_map, alpha)
        valid_a = alpha.reshape(h, w) > alpha_min
    uv, valid = destination_pixels(dest_map, width=w, height=h, K=K, w2c_dst=w2c_dst, z_min=z_min)
    flow = uv - pixel_centers(w, h, dtype=uv.dtype, device=uv.device)
    if valid_a is not None:
        valid = valid & valid_a
    return flow, valid


def in_bounds(uv: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """[...] bool: uv [..., 2] lies between the first and last pixel centres (no border
    extrapolation)."""
    return (
        (uv[..., 0] >= 0.5)
        & (uv[..., 0] <= width - 0.5)
        & (uv[..., 1] >= 0.5)
        & (uv[..., 1] <= height - 0.5)
    )


# --------------------------------------------------------------------------------------------------
# Flow and track losses
# --------------------------------------------------------------------------------------------------
def _pixel_distance(d: torch.Tensor, norm: str) -> torch.Tensor:
    """[..., 2] displacement error -> [...] distance: "l1" = |dx| + |dy|, "l2" = Euclidean."""
    if norm == "l1":
        return d.abs().sum(-1)
    if norm == "l2":
        sq = (d * d).sum(-1)
        nz = sq > 1e-24
        return torch.where(
            nz, torch.sqrt(torch.where(nz, sq, torch.ones_like(sq))), torch.zeros_like(sq)
        )
    raise ValueError(f"unknown norm {norm!r} (use 'l1' or 'l2')")


def _masked_mean(x: torch.Tensor, m: torch.Tensor) -> torch.Tensor:
    m = m.to(x.dtype)
    return (x * m).sum() / m.sum().clamp_min(1.0)


def flow_loss(
    pred_flow: torch.Tensor,
    prior_flow: torch.Tensor,
    valid: torch.Tensor | None = None,
    norm: str = "l1",
    clamp: float | None = None,
) -> torch.Tensor:
    """Dense flow loss V * |F~ - F|.

    Args:
        pred_flow: [H, W, 2] rendered flow; prior_flow: [H, W, 2] prior flow F_{t->t'}. valid:
        optional [H, W] bool (prior's valid mask AND the rendered flow's valid mask). norm:
        per-pixel distance, "l1" (paper) or "l2"; clamp: optional upper clamp of the per-pixel
        distance.
    Returns:
        scalar: mean over valid pixels of the per-pixel distance (0 if none).
    """
    m = torch.isfinite(prior_flow).all(-1)
    if valid is not None:
        m = m & valid.bool()
    # masked pixels: zero error, zero gradient
    target = torch.where(m[..., None], prior_flow, pred_flow.detach())
    d = _pixel_distance(pred_flow - target, norm)
    if clamp is not None:
        d = d.clamp(max=clamp)
    return _masked_mean(d, m)


def track_loss(
    dest_map: torch.Tensor,
    src_uv: torch.Tensor,
    dst_uv: torch.Tensor,
    valid: torch.Tensor | None = None,
    *,
    K: torch.Tensor | None = None,
    w2c_dst: torch.Tensor | None = None,
    alpha: torch.Tensor | None = None,
    norm: str = "l1",
    clamp: float | None = None,
    z_min: float = Z_MIN,
) -> torch.Tensor:
    """Sparse track loss between times t (render) and t'.

    Args:
        dest_map: [H, W, 3] destination-position map rendered at t (see module docstring). src_uv:
        [N, 2] track positions at t (continuous pixels, centres at +0.5); dst_uv: [N, 2] positions
        at t'. valid: optional [N] bool (track visible at both t and t'). K, w2c_dst, alpha: camera
        of the destination (None K = video space) and optional alpha, as in
            `flow_from_destination_map`.
        norm / clamp: "l1" without clamp (paper, default) or "l2" with clamp=100 (authors).
    Returns:
        scalar: mean over valid tracks (in-bounds source, destination depth > z_min) of the pixel
        distance.
    """
    h, w = dest_map.shape[:2]
    m = in_bounds(src_uv, w, h) & torch.isfinite(dst_uv).all(-1)
    if valid is not None:
        m = m & valid.bool()
    if alpha is not None:
        dest_map = normalize_by_alpha(dest_map, alpha)
    pos = sample_map(dest_map, src_uv)  # [N, 3]
    uv_pred, ok = destination_pixels(pos, width=w, height=h, K=K, w2c_dst=w2c_dst, z_min=z_min)
    m = m & ok
    d = _pixel_distance(uv_pred - torch.where(m[:, None], dst_uv, uv_pred.detach()), norm)
    if clamp is not None:
        d = d.clamp(max=clamp)
    return _masked_mean(d, m)
