"""Held-out viewpoints: the same instant as a test frame, seen from cameras off the input path.

A test frame one frame away from a training frame on the same camera path measures interpolation
along that path. A generator with exact geometry can show the instant from elsewhere: each scene
spec lists views (`camera.views`, benchgen.spec.VIEW; three baselines by default), placed per test
frame relative to its camera and its look-at point, the point on the optical axis at the median
z-depth of the frame's central pixels (`pivot_distance`):

    c2w_view = swing(c2w_test, about the look-at point, yaw about the camera's up axis, then pitch
               about its right axis)  then  a translation [right, up, forward] * distance in the
               swung camera's frame (orientation kept)

Each view pixel also gets a co-visibility flag (`covisibility`): its surface point, at its own
position in each training frame (moving points move with their triangle), is in frame, in front
of the camera and unoccluded (the training frame's ray cast shows the same object at the same
depth, to rtol) in at least `min_count` training frames. Scores masked by it (mPSNR, mSSIM) ask
only for what the training frames saw.

The clip's camera-motion statistics (`camera_motion`) say how much "multi-view" signal a monocular
clip carries: the camera's angular speed about its look-at point against the angular speed of the
scene's own moving points seen from the same distance (their ratio is the effective multi-view
factor of the monocular dynamic view synthesis literature; high: the camera moves much more than
the scene, and frames of nearby times act as a multi-view rig).

Pure functions of numpy arrays and FrameStates; benchgen.make renders and writes the views.
"""

from __future__ import annotations

import dataclasses
from typing import Dict, List, Optional, Sequence

import numpy as np

from .groundtruth import DEFAULT_DEPTH_RTOL, project, surface_points, visibility_test
from .motion import axis_angle

#: fraction of the image (per side) whose central part sets the look-at distance
CENTRE_FRACTION = 0.5
#: a view whose nearest surface is closer than this fraction of the look-at distance is refused
#: as being inside or against geometry
MIN_NEAR_FRACTION = 0.05
#: and so is one that sees surfaces in less than this fraction of the pixels where its test frame
#: sees them (it looks past the scene, at the environment)
MIN_SURFACE_RATIO = 0.5


#: seeds of the views' renders: apart from the frames' own (settings.seed + g), so that a view's
#: noise is not the test frame's
VIEW_SEED_OFFSET = 7_000_003


def view_seed(base_seed: int, i: int, g: int) -> int:
    """Sampler seed of view i (its index in the spec's camera.views) of test frame g: per frame
    and view, so that the views render the same wherever and in whatever order they are
    rendered."""
    return int(base_seed) + VIEW_SEED_OFFSET * (int(i) + 1) + int(g)


def pivot_distance(depth: np.ndarray) -> float:
    """The look-at distance of a frame: the median z-depth of the surface pixels (depth > 0) in the
    central CENTRE_FRACTION of the image, else of all surface pixels; NaN without any. depth [H,
    W]."""
    H, W = depth.shape
    fy, fx = (1 - CENTRE_FRACTION) / 2, (1 - CENTRE_FRACTION) / 2
    c = depth[int(H * fy) : int(np.ceil(H * (1 - fy))), int(W * fx) : int(np.ceil(W * (1 - fx)))]
    for d in (c, depth):
        v = d[np.isfinite(d) & (d > 0)]
        if v.size:
            return float(np.median(v))
    return float("nan")


def view_c2w(c2w: np.ndarray, distance: float, orbit_deg, offset) -> np.ndarray:
    """[4, 4] OpenCV camera-to-world of a view (module docstring): the camera `c2w` swung about its
    look-at point (`distance` along its optical axis) by orbit_deg = [yaw, pitch] degrees (yaw about
    the camera's up axis, positive towards the camera's right; then pitch about the swung camera's
    right axis, positive up), then moved by offset = [right, up, forward] * distance in its own
    frame. The view keeps looking at the look-at point after the swing; the offset keeps its
    orientation."""
    c2w = np.asarray(c2w, np.float64)
    R, c = c2w[:3, :3], c2w[:3, 3]
    pivot = c + distance * R[:, 2]
    yaw, pitch = np.deg2rad(np.asarray(orbit_deg, np.float64))
    # OpenCV camera axes: x right, y down, z forward. A right-handed turn about y (down) by a
    # positive angle turns z towards x, which moves the centre (pivot - distance z) to the left;
    # one about x turns z towards -y (up), which moves the centre down: hence the minus signs
    R1 = axis_angle(R[:, 1], -yaw) @ R
    R2 = axis_angle(R1[:, 0], -pitch) @ R1
    out = np.eye(4)
    out[:3, :3] = R2
    centre = pivot - distance * R2[:, 2]
    right, up, forward = np.asarray(offset, np.float64) * distance
    out[:3, 3] = centre + right * R2[:, 0] - up * R2[:, 1] + forward * R2[:, 2]
    return out


def baseline(c2w_a: np.ndarray, c2w_b: np.ndarray, distance: float) -> Dict[str, float]:
    """How far view b is from camera a: the angle (degrees) between the two camera centres seen
    from a's look-at point, and the distance between the centres in units of the look-at
    distance."""
    c2w_a, c2w_b = np.asarray(c2w_a, np.float64), np.asarray(c2w_b, np.float64)
    pivot = c2w_a[:3, 3] + distance * c2w_a[:3, 2]
    u, v = c2w_a[:3, 3] - pivot, c2w_b[:3, 3] - pivot
    cos = float(np.dot(u, v) / max(np.linalg.norm(u) * np.linalg.norm(v), 1e-300))
    return {
        "angle_deg": float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))),
        "translation": float(np.linalg.norm(c2w_b[:3, 3] - c2w_a[:3, 3]) / distance),
    }


def placement_problem(depth: np.ndarray, distance: float, frame_surface: float) -> Optional[str]:
    """Why a view's ray cast (z-depth [H, W], 0 = no surface) shows a camera inside or against
    geometry, or looking past the scene (surfaces in fewer than MIN_SURFACE_RATIO x
    `frame_surface`, the fraction of its test frame's pixels that see one); None when it does
    not."""
    hit = np.isfinite(depth) & (depth > 0)
    if hit.mean() < MIN_SURFACE_RATIO * frame_surface:
        return (
            f"surfaces in {100 * hit.mean():.0f} % of its pixels, against "
            f"{100 * frame_surface:.0f} % in the test frame (looking past the scene?)"
        )
    near = hit & (depth < MIN_NEAR_FRACTION * distance)
    if near.mean() > 0.001:
        return (
            f"{100 * near.mean():.1f} % of its pixels see a surface closer than "
            f"{MIN_NEAR_FRACTION:g} x the look-at distance (inside or against geometry)"
        )
    return None


def covisibility(
    cast,
    train_states: Sequence,
    train_casts: Sequence,
    min_count: int = 2,
    rtol: float = DEFAULT_DEPTH_RTOL,
) -> np.ndarray:
    """[H, W] bool: the view pixel's surface point (cast: the view's benchgen.groundtruth.RayCast)
    is seen, in frame and unoccluded, by at least `min_count` of the training frames (their
    FrameStates and RayCasts; the point at its own position in each, so a moving point is looked
    for where it is then). Pixels without a surface are False."""
    count = np.zeros(cast.depth.shape, np.int32)
    for st, tc in zip(train_states, train_casts):
        p = surface_points(cast, st)
        uv, z = project(p, st)
        count += seen_in(uv, z, cast.instance, tc.depth, tc.instance, rtol)
    return (count >= min_count) & cast.hit


def seen_in(
    uv: np.ndarray,
    z: np.ndarray,
    instance: np.ndarray,
    depth_b: np.ndarray,
    inst_b: np.ndarray,
    rtol: float = DEFAULT_DEPTH_RTOL,
) -> np.ndarray:
    """[...] bool: surface points at pixel uv [..., 2] and z-depth z [...] of object `instance`
    [...] are seen by frame b (z-depth depth_b, objects inst_b [H, W]): in frame, in front of the
    camera, and the pixel holding uv or one of its 8 neighbours shows the same object at a depth
    within rtol of z. The neighbours make the test hold where a surface seen at a grazing angle
    changes depth by more than rtol across one pixel (benchgen.groundtruth.visibility_test, the
    flow's test, looks at the one pixel); an occluder in front still fails it, since every
    neighbour then shows the occluder or a depth far from z."""
    ok = np.zeros(np.shape(z), bool)
    H, W = depth_b.shape
    base = np.floor(np.nan_to_num(uv, nan=-1e9))
    for dj in (-1, 0, 1):
        for di in (-1, 0, 1):
            shifted = base + np.array([di, dj], np.float64) + 0.5
            inside = (
                np.isfinite(uv).all(axis=-1)
                & (shifted[..., 0] >= 0)
                & (shifted[..., 0] < W)
                & (shifted[..., 1] >= 0)
                & (shifted[..., 1] < H)
            )
            # the pixel holding uv must itself be in frame; its neighbours may not be
            if di == 0 and dj == 0:
                in_frame = inside
            ok |= inside & visibility_test(shifted, z, instance, depth_b, inst_b, rtol)
    return ok & in_frame


def view_state(state, c2w: np.ndarray):
    """A FrameState like `state` (same instant, same geometry) seen from `c2w`."""
    return dataclasses.replace(state, c2w=np.asarray(c2w, np.float64))


def camera_motion(
    c2w: np.ndarray,
    distances: np.ndarray,
    fps: float,
    points3d: Optional[np.ndarray] = None,
    dynamic: Optional[np.ndarray] = None,
) -> Dict[str, Optional[float]]:
    """Camera-motion statistics of a clip (module docstring).

    c2w [G, 4, 4] of every frame, distances [G] their look-at distances, points3d [N, G, 3] the
    world positions of the ground-truth track points in every frame and dynamic [N] which of them
    move. Returns (per second, means over consecutive frames): camera_deg_s, the angle between
    consecutive camera centres seen from the first one's look-at point; camera_speed, the
    centre's speed in look-at distances; scene_speed_m_s, the mean 3D speed of the moving points;
    scene_deg_s, that speed seen from the median look-at distance; and emf, camera_deg_s /
    scene_deg_s (None for a scene without moving points)."""
    c2w = np.asarray(c2w, np.float64)
    d = np.asarray(distances, np.float64)
    ang, trans = [], []
    for i in range(len(c2w) - 1):
        if not np.isfinite(d[i]) or d[i] <= 0:
            continue
        b = baseline(c2w[i], c2w[i + 1], d[i])
        ang.append(b["angle_deg"])
        trans.append(b["translation"])
    out: Dict[str, Optional[float]] = {
        "camera_deg_s": float(np.mean(ang) * fps) if ang else None,
        "camera_speed": float(np.mean(trans) * fps) if trans else None,
        "scene_speed_m_s": None,
        "scene_deg_s": None,
        "emf": None,
        "look_at_distance_median": float(np.nanmedian(d)) if np.isfinite(d).any() else None,
    }
    if points3d is None or dynamic is None or not np.any(dynamic):
        return out
    p = np.asarray(points3d, np.float64)[np.asarray(dynamic, bool)]
    step = np.linalg.norm(np.diff(p, axis=1), axis=-1)  # [N_dyn, G - 1]
    step = step[np.isfinite(step)]
    if not step.size:
        return out
    speed = float(step.mean() * fps)
    out["scene_speed_m_s"] = speed
    dist = out["look_at_distance_median"]
    if dist:
        out["scene_deg_s"] = float(np.degrees(speed / dist))
        if out["camera_deg_s"] is not None and out["scene_deg_s"] > 0:
            out["emf"] = out["camera_deg_s"] / out["scene_deg_s"]
    return out


def view_names(spec: dict) -> List[str]:
    """The names of a validated scene spec's held-out views, in order."""
    return [v["name"] for v in spec["camera"]["views"]]
