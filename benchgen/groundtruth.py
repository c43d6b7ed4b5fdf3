"""Exact ground truth from pixel-centre ray casts (docs/rendering.md "Ground truth definitions").

Pure numpy. The unit of correspondence is a surface point named by (mesh index, triangle,
barycentrics): the same triple gives the same material point in every frame, for rigid and for
deforming meshes alike, because a frame's world point is the barycentric combination of THAT frame's
triangle vertices (topology is fixed over time).

Definitions (all pixels are continuous coordinates with centres at integer + 0.5, OpenCV cameras,
z-depth):
- RayCast: per pixel of one frame, what the ray through the exact pixel centre hits first. No
  surface (environment): depth 0, instance 0, mesh -1, triangle -1, bary 0. (The clip's gt depth
  must be finite: 0 means "no surface".)
- flow F_{a->b}(x) = pi_b(P_b(corr_a(x))) - x; visible when the point is in front of camera b, lands
  inside the image, the pixel it lands in shows the same instance, and that pixel's z-depth agrees
  with the point's camera-b z-depth to a relative tolerance (default 3%). Pixels of a with no
  surface: invalid, flow = the rotation-only flow of a direction at infinity when cam_a is given,
  else 0. Flow is finite everywhere (0 where the point is behind b).
- tracks: query surface points from a uniform pixel grid on a few reference frames plus extra random
  pixels on dynamic objects; each is carried to every frame by its (mesh, triangle, bary) and tested
  for visibility as for flow. Tracks are NaN where the point is behind the camera (always invisible
  there); points3d is always finite.
- dynamic mask: pixels whose instance belongs to a mesh with MeshState.dynamic (own motion, not
  camera motion).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import numpy as np

from m4dgs.clip import Cameras, TrackSet
from m4dgs.core.hdr import mu_law

DEFAULT_DEPTH_RTOL = 0.03


@dataclass
class RayCast:
    """Per-pixel first hits of one frame. depth [H, W] float32 z-depth (0 = no surface); instance
    [H, W] int32 (0 = none); mesh [H, W] int32 index into FrameState.meshes (-1 = none); triangle
    [H, W] int64 (-1 = none); bary [H, W, 3] float64 barycentrics w.r.t. the triangle's vertices
    (faces[triangle])."""

    depth: np.ndarray
    instance: np.ndarray
    mesh: np.ndarray
    triangle: np.ndarray
    bary: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.mesh >= 0

    @property
    def shape(self) -> Tuple[int, int]:
        return tuple(self.depth.shape)


@dataclass
class SurfaceQueries:
    """N surface points: mesh [N], triangle [N], bary [N, 3], instance [N], dynamic [N] bool,
    ref_index [N] (position of the reference frame in the frame list) and ref_uv [N, 2] (the pixel
    centre it was picked at)."""

    mesh: np.ndarray
    triangle: np.ndarray
    bary: np.ndarray
    instance: np.ndarray
    dynamic: np.ndarray
    ref_index: np.ndarray
    ref_uv: np.ndarray

    def __len__(self) -> int:
        return int(self.mesh.shape[0])

    @staticmethod
    def concat(items: Sequence["SurfaceQueries"]) -> "SurfaceQueries":
        names = ("mesh", "triangle", "bary", "instance", "dynamic", "ref_index", "ref_uv")
        return SurfaceQueries(
            **{n: np.concatenate([getattr(q, n) for q in items], axis=0) for n in names}
        )


# --------------------------------------------------------------------------------------------------
# Cameras
# --------------------------------------------------------------------------------------------------
def _K_c2w(cam) -> Tuple[np.ndarray, np.ndarray]:
    """(K [3, 3], c2w [4, 4]) float64 from a (K, c2w) tuple or anything with .K and .c2w (a
    FrameState)."""
    if isinstance(cam, (tuple, list)):
        K, c2w = cam
    else:
        K, c2w = cam.K, cam.c2w
    return np.asarray(K, np.float64), np.asarray(c2w, np.float64)


def pixel_rays(
    K: np.ndarray, c2w: np.ndarray, width: int, height: int
) -> Tuple[np.ndarray, np.ndarray]:
    """Rays through the exact pixel centres: origin [3] and world directions [H*W, 3] (row-major
    pixels) scaled so that their camera-space z component is 1 (the ray parameter of a hit is its
    z-depth)."""
    K = np.asarray(K, np.float64)
    c2w = np.asarray(c2w, np.float64)
    v, u = np.meshgrid(
        np.arange(height, dtype=np.float64) + 0.5,
        np.arange(width, dtype=np.float64) + 0.5,
        indexing="ij",
    )
    y = (v.ravel() - K[1, 2]) / K[1, 1]
    x = (u.ravel() - K[0, 2] - K[0, 1] * y) / K[0, 0]
    d_cam = np.stack([x, y, np.ones_like(x)], axis=1)
    return c2w[:3, 3].copy(), d_cam @ c2w[:3, :3].T


def world_to_camera(points: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """Camera-space points [..., 3] of world points [..., 3] (OpenCV camera c2w [4, 4])."""
    c2w = np.asarray(c2w, np.float64)
    return (np.asarray(points, np.float64) - c2w[:3, 3]) @ c2w[:3, :3]


def project(points: np.ndarray, cam) -> Tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates [..., 2] (u = fx x / z + cx) and camera z [...] of world points [..., 3];
    uv is NaN where z <= 0."""
    K, c2w = _K_c2w(cam)
    pc = world_to_camera(points, c2w)
    z = pc[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        zs = np.where(z > 1e-12, z, np.nan)
        u = K[0, 0] * pc[..., 0] / zs + K[0, 1] * pc[..., 1] / zs + K[0, 2]
        v = K[1, 1] * pc[..., 1] / zs + K[1, 2]
    return np.stack([u, v], axis=-1), z


def cameras_from_states(states: Sequence) -> Cameras:
    """m4dgs.clip.Cameras (frames, K, c2w) of a list of FrameStates."""
    return Cameras(
        frames=np.array([int(s.g) for s in states], np.int64),
        K=np.stack([np.asarray(s.K, np.float64) for s in states]),
        c2w=np.stack([np.asarray(s.c2w, np.float64) for s in states]),
    )


# --------------------------------------------------------------------------------------------------
# Surface points
# --------------------------------------------------------------------------------------------------
def surface_points_of(
    mesh: np.ndarray, triangle: np.ndarray, bary: np.ndarray, frame_state
) -> np.ndarray:
    """World points [..., 3] of correspondences (mesh [...], triangle [...], bary [..., 3]) in
    `frame_state`'s geometry; NaN where mesh < 0."""
    mesh = np.asarray(mesh)
    out = np.full(mesh.shape + (3,), np.nan, np.float64)
    for j, ms in enumerate(frame_state.meshes):
        sel = mesh == j
        if not sel.any():
            continue
        V = np.asarray(ms.vertices, np.float64)
        tri = np.asarray(ms.faces, np.int64)[np.asarray(triangle)[sel]]
        b = np.asarray(bary, np.float64)[sel]
        out[sel] = b[:, 0:1] * V[tri[:, 0]] + b[:, 1:2] * V[tri[:, 1]] + b[:, 2:3] * V[tri[:, 2]]
    return out


def surface_points(corr: RayCast, frame_state) -> np.ndarray:
    """[H, W, 3] world points, in `frame_state` (ANY frame), of the surface points seen by `corr`'s
    pixels; NaN where `corr` has no surface."""
    return surface_points_of(corr.mesh, corr.triangle, corr.bary, frame_state)


def visibility_test(
    uv: np.ndarray,
    z: np.ndarray,
    instance: np.ndarray,
    depth_b: np.ndarray,
    inst_b: np.ndarray,
    rtol: float = DEFAULT_DEPTH_RTOL,
) -> np.ndarray:
    """Visible [...] bool: z > 0, uv inside the image, and the pixel containing uv shows `instance`
    at a z-depth within rtol * z of z.  uv [..., 2] pixels, z [...], instance [...] int; depth_b,
    inst_b [H, W] of frame b."""
    H, W = depth_b.shape
    ok = np.isfinite(uv).all(axis=-1) & (z > 0) & (np.asarray(instance) > 0)
    u = np.where(ok, uv[..., 0], -1.0)
    v = np.where(ok, uv[..., 1], -1.0)
    ok &= (u >= 0) & (u < W) & (v >= 0) & (v < H)
    i = np.clip(np.floor(u), 0, W - 1).astype(np.int64)
    j = np.clip(np.floor(v), 0, H - 1).astype(np.int64)
    db = depth_b[j, i].astype(np.float64)
    ok &= inst_b[j, i] == instance
    ok &= np.abs(db - z) <= rtol * np.abs(z)
    return ok


def flow_between(
    corr_a: RayCast,
    state_b,
    cam_b,
    depth_b: np.ndarray,
    inst_b: np.ndarray,
    cam_a=None,
    rtol: float = DEFAULT_DEPTH_RTOL,
) -> Tuple[np.ndarray, np.ndarray]:
    """Exact flow F_{a->b} [H, W, 2] float32 and visibility [H, W] bool of frame a's pixels in frame
    b.

    corr_a: RayCast of frame a; state_b: FrameState of b (its vertices); cam_b: (K, c2w) or
    FrameState of b; depth_b, inst_b: frame b's RayCast depth and instance. cam_a (optional): frame
    a's camera, used only for the flow of no-surface pixels (a direction at infinity); without it
    that flow is 0. See the module docstring."""
    H, W = corr_a.shape
    centres = np.stack(
        np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5, indexing="xy"), axis=-1
    ).astype(np.float64)
    P = surface_points(corr_a, state_b)
    uv, z = project(P, cam_b)
    vis = visibility_test(uv, z, corr_a.instance, depth_b, inst_b, rtol) & corr_a.hit
    flow = uv - centres
    if cam_a is not None:
        Ka, c2wa = _K_c2w(cam_a)
        Kb, c2wb = _K_c2w(cam_b)
        _, d = pixel_rays(Ka, c2wa, W, H)
        dir_b = d.reshape(H, W, 3) @ c2wb[:3, :3]  # camera-b directions of the rays at infinity
        with np.errstate(divide="ignore", invalid="ignore"):
            zb = np.where(dir_b[..., 2] > 1e-12, dir_b[..., 2], np.nan)
            uinf = np.stack(
                [
                    Kb[0, 0] * dir_b[..., 0] / zb + Kb[0, 2],
                    Kb[1, 1] * dir_b[..., 1] / zb + Kb[1, 2],
                ],
                -1,
            )
        flow = np.where(corr_a.hit[..., None], flow, uinf - centres)
    flow = np.where(np.isfinite(flow), flow, 0.0)
    return flow.astype(np.float32), vis


def dynamic_mask(inst: np.ndarray, frame_state) -> np.ndarray:
    """[H, W] bool: pixels whose instance belongs to a dynamic mesh of `frame_state`."""
    dyn_ids = [int(m.instance_id) for m in frame_state.meshes if m.dynamic]
    return (
        np.isin(inst, np.array(dyn_ids, dtype=np.asarray(inst).dtype))
        if dyn_ids
        else np.zeros(inst.shape, bool)
    )


# --------------------------------------------------------------------------------------------------
# Tracks
# --------------------------------------------------------------------------------------------------
def select_queries(
    corr: RayCast,
    frame_state,
    ref_index: int,
    num_grid: int = 256,
    num_dynamic: int = 64,
    rng: Optional[np.random.Generator] = None,
) -> SurfaceQueries:
    """Query surface points on one reference frame: the pixel centres of a uniform grid (about
    `num_grid` cells over the image, surface pixels only) plus up to `num_dynamic` random distinct
    dynamic-object pixels not on the grid."""
    rng = np.random.default_rng(0) if rng is None else rng
    H, W = corr.shape
    step = max(1, int(round(math.sqrt(H * W / max(num_grid, 1)))))
    jj, ii = np.meshgrid(
        np.arange(step // 2, H, step), np.arange(step // 2, W, step), indexing="ij"
    )
    grid = np.zeros((H, W), bool)
    grid[jj.ravel(), ii.ravel()] = True
    pick = grid & corr.hit
    dyn = dynamic_mask(corr.instance, frame_state) & ~grid
    flat = np.nonzero(dyn.ravel())[0]
    if flat.size and num_dynamic > 0:
        extra = rng.choice(flat, size=min(num_dynamic, flat.size), replace=False)
        pick[np.unravel_index(extra, pick.shape)] = True
    j, i = np.nonzero(pick)
    mesh = corr.mesh[j, i].astype(np.int64)
    dyn_flags = np.array([bool(m.dynamic) for m in frame_state.meshes], bool)
    return SurfaceQueries(
        mesh=mesh,
        triangle=corr.triangle[j, i].astype(np.int64),
        bary=corr.bary[j, i].astype(np.float64),
        instance=corr.instance[j, i].astype(np.int64),
        dynamic=dyn_flags[mesh],
        ref_index=np.full(j.shape, ref_index, np.int64),
        ref_uv=np.stack([i + 0.5, j + 0.5], axis=1).astype(np.float64),
    )


def track_frame(
    queries: SurfaceQueries,
    frame_state,
    depth: np.ndarray,
    inst: np.ndarray,
    rtol: float = DEFAULT_DEPTH_RTOL,
) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Queries carried to one frame: (uv [N, 2] (NaN behind the camera), points3d [N, 3] world,
    visible [N])."""
    P = surface_points_of(queries.mesh, queries.triangle, queries.bary, frame_state)
    uv, z = project(P, frame_state)
    vis = visibility_test(uv, z, queries.instance, depth, inst, rtol)
    return uv, P, vis


def default_reference_indices(num_frames: int, num_ref: int = 4) -> List[int]:
    """Evenly spaced positions 0 .. num_frames-1 (distinct) used as reference frames for the query
    points."""
    k = max(1, min(num_ref, num_frames))
    return sorted(set(int(round(x)) for x in np.linspace(0, num_frames - 1, k)))


def sample_tracks(
    casts: Sequence[RayCast],
    states: Sequence,
    ref_indices: Optional[Sequence[int]] = None,
    num_grid: int = 256,
    num_dynamic: int = 64,
    seed: int = 0,
    rtol: float = DEFAULT_DEPTH_RTOL,
) -> TrackSet:
    """Ground-truth TrackSet over ALL the given frames.

    casts: RayCast per frame; states: FrameState per frame (same order); ref_indices: positions of
    the reference frames (default: 4 evenly spaced). Returns TrackSet(tracks [N, G, 2], visible [N,
    G], frames [G], points3d [N, G, 3] world, dynamic [N])."""
    if len(casts) != len(states) or not states:
        raise ValueError(f"sample_tracks: {len(casts)} casts for {len(states)} states")
    refs = default_reference_indices(len(states)) if ref_indices is None else list(ref_indices)
    rng = np.random.default_rng(seed)
    q = SurfaceQueries.concat(
        [select_queries(casts[r], states[r], r, num_grid, num_dynamic, rng) for r in refs]
    )
    per = [track_frame(q, s, c.depth, c.instance, rtol) for c, s in zip(casts, states)]
    return TrackSet(
        tracks=np.stack([p[0] for p in per], 1).astype(np.float32),
        visible=np.stack([p[2] for p in per], 1),
        frames=np.array([int(s.g) for s in states], np.int64),
        points3d=np.stack([p[1] for p in per], 1).astype(np.float32),
        dynamic=q.dynamic.astype(bool),
    )


# --------------------------------------------------------------------------------------------------
# Noise and temporal floors
# --------------------------------------------------------------------------------------------------
def render_noise(img_a: np.ndarray, img_b: np.ndarray, mask: Optional[np.ndarray] = None) -> dict:
    """Monte Carlo noise from two renders of the same frame with different seeds ([H, W, 3] linear
    each).

    rel_std: the mean over pixels and channels (where the mean radiance m = (A + B) / 2 > 1e-6) of
    one render's relative standard deviation, estimated per pixel as |A - B| sqrt(pi) / 2 / m.
    For Gaussian pixel noise of std sigma, A - B has std sigma sqrt(2) and E|A - B| = 2 sigma /
    sqrt(pi), so this is unbiased for sigma / m; on denoised small-preset frames it agrees with the
    per-pixel std over 8 seeds within 1-3 % (docs/rendering.md, "Measured floors").
    rel_std_two_sample: |A - B| / sqrt(2) / m averaged the same way, i.e. sqrt(2 / pi) = 0.80 x
    rel_std; clips made before this distinction recorded this value as rel_std.
    tae_two_seeds: the HDR-TAE term of the pair with zero motion (mean over pixels of
    sum_c |A - B| / (A + B + 1e-10), channel-sum convention), i.e. the part of the HDR-TAE floor the
    noise alone explains; mu_psnr: mu-law PSNR of B against A (scale = max A). mask [H, W] bool
    (optional): the pixels to average over (e.g. surface pixels, as HDR-TAE's visibility does); the
    mu-law scale is always the max of the whole image A."""
    a = np.asarray(img_a, np.float64)
    b = np.asarray(img_b, np.float64)
    scale = float(a.max()) if a.max() > 0 else 1.0
    if mask is not None:
        mask = np.asarray(mask, bool)
        if not mask.any():
            return {
                "rel_std": 0.0,
                "rel_std_two_sample": 0.0,
                "tae_two_seeds": 0.0,
                "mu_psnr": float("inf"),
            }
        a, b = a[mask], b[mask]
    m = (a + b) / 2.0
    ok = m > 1e-6
    rel = np.abs(a - b) / math.sqrt(2.0) / np.where(ok, m, 1.0)
    tae = (np.abs(a - b) / (a + b + 1e-10)).sum(axis=-1).mean()
    mse = float(np.mean((mu_law(a / scale) - mu_law(b / scale)) ** 2))
    two = float(rel[ok].mean()) if ok.any() else 0.0
    return {
        "rel_std": two * math.sqrt(math.pi / 2.0),
        "rel_std_two_sample": two,
        "tae_two_seeds": float(tae),
        "mu_psnr": float(-10.0 * math.log10(mse)) if mse > 0 else float("inf"),
    }


#: brightness bands of :func:`render_bias`: quantiles of the reference's mean channel
BIAS_BANDS = ((0.0, 0.1), (0.1, 0.5), (0.5, 0.9), (0.9, 1.0))


def render_bias(img: np.ndarray, ref: np.ndarray, mask: Optional[np.ndarray] = None) -> dict:
    """How far a (denoised) render is from a high-sample reference of the same frame, per
    brightness band: what the ground truth gets wrong, as opposed to how much it varies
    (:func:`render_noise`).

    img, ref [H, W, 3] linear; mask [H, W] bool (optional): the pixels to use. Per pixel the
    relative error |img - ref| / ref of the mean channel's absolute difference (pixels with ref >
    1e-12); returns {"median_rel_error": [4 floats, darkest tenth, 10-50 %, 50-90 %, brightest
    tenth of the reference's brightness], "mean_rel_error": over all used pixels}."""
    a = np.asarray(img, np.float64)
    r = np.asarray(ref, np.float64)
    lum = r.mean(axis=-1)
    ok = lum > 1e-12
    if mask is not None:
        ok &= np.asarray(mask, bool)
    if not ok.any():
        return {"median_rel_error": [None] * len(BIAS_BANDS), "mean_rel_error": None}
    e = np.abs(a - r).mean(axis=-1)[ok] / lum[ok]
    lv = lum[ok]
    qs = np.quantile(lv, [b for b, _ in BIAS_BANDS] + [1.0])
    bands = []
    for k in range(len(BIAS_BANDS)):
        sel = (lv >= qs[k]) & ((lv < qs[k + 1]) if k < len(BIAS_BANDS) - 1 else (lv <= qs[k + 1]))
        bands.append(float(np.median(e[sel])) if sel.any() else None)
    return {"median_rel_error": bands, "mean_rel_error": float(e.mean())}
