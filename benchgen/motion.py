"""Camera trajectories and object motion as pure functions of time (docs/scenes.md).

Conventions: world is right-handed and z-up; cameras are OpenCV (x right, y down, z forward) and
returned as 4x4 camera-to-world matrices (float64). Rigid object motions return 4x4 world transforms
M(t) that are applied on top of the object's static placement (world = M(t) @ placement @ local).
Angles are degrees at the spec level and radians inside unless a name says ``_deg``.

Contents:
- rotations: :func:`axis_angle`, :func:`euler_xyz_deg`, :func:`rigid`.
- :func:`look_at` (explicit OpenCV look-at), :func:`smooth_noise` (band-limited seeded jitter).
- splines: :func:`hermite_spline` (Catmull-Rom tangents, zero velocity at the end keys, so the
  clamped curve is C1 everywhere) and :func:`quat_spline` (the same Hermite curve on sign-aligned
  quaternion components, normalised; C1).
- cameras: :func:`static_c2w`, :func:`orbit_c2w`, :func:`dolly_c2w`, :func:`handheld_c2w`,
  :func:`camera_c2w`.
- objects: :func:`keyframes_transform`, :func:`translate_transform`, :func:`rotate_transform`,
  :func:`oscillate_transform`, :func:`rigid_motion`; :func:`joint_angles`, :func:`chain_fk`,
  :func:`chain_tip`, :func:`chain_vertices` (articulated); :func:`flag_deform` (non-rigid).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Optional, Sequence

import numpy as np

from m4dgs.core.camera import quat_to_rotmat, rotmat_to_quat

WORLD_UP = np.array([0.0, 0.0, 1.0])


# --------------------------------------------------------------------------------------------------
# Rotations
# --------------------------------------------------------------------------------------------------
def normalize(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    if n < 1e-12:
        raise ValueError("cannot normalise a zero vector")
    return v / n


def axis_angle(axis, angle: float) -> np.ndarray:
    """[3, 3] rotation by angle (radians, right-hand rule) about axis (Rodrigues)."""
    k = normalize(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)


def euler_xyz_deg(angles_deg) -> np.ndarray:
    """[3, 3] R = Rz(c) Ry(b) Rx(a) for angles_deg = (a, b, c): rotate about x, then y, then z
    (world axes)."""
    a, b, c = np.deg2rad(np.asarray(angles_deg, dtype=np.float64))
    return axis_angle([0, 0, 1], c) @ axis_angle([0, 1, 0], b) @ axis_angle([1, 0, 0], a)


def rigid(R=None, t=None) -> np.ndarray:
    """4x4 [R | t]."""
    M = np.eye(4)
    if R is not None:
        M[:3, :3] = R
    if t is not None:
        M[:3, 3] = t
    return M


def placement(translate, rotate_deg, scale) -> np.ndarray:
    """4x4 T(translate) R(rotate_deg) S(scale) of an object's static transform."""
    M = rigid(euler_xyz_deg(rotate_deg), translate)
    M[:3, :3] = M[:3, :3] * np.asarray(scale, dtype=np.float64)[None, :]
    return M


def apply(M: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Points [..., 3] transformed by 4x4 M."""
    return p @ M[:3, :3].T + M[:3, 3]


# --------------------------------------------------------------------------------------------------
# Cameras
# --------------------------------------------------------------------------------------------------
def look_at(eye, target, up=WORLD_UP, roll_deg: float = 0.0) -> np.ndarray:
    """OpenCV camera-to-world [4, 4] at eye looking at target.

    Columns of R are the camera axes in world coordinates: z = forward = (target - eye) / |.|, x =
    right =
    z x up / |.|, y = down = z x x. With up = world +z, image up (-y) has a positive world-z
    component. If forward is
    parallel to up, world +y is used as the up hint. roll_deg turns the camera about its optical
    axis (positive: camera x towards camera y)."""
    eye = np.asarray(eye, dtype=np.float64)
    z = normalize(np.asarray(target, dtype=np.float64) - eye)
    up = np.asarray(up, dtype=np.float64)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, np.array([0.0, 1.0, 0.0]))
    x = normalize(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=1)
    if roll_deg:
        R = R @ axis_angle([0, 0, 1], np.deg2rad(roll_deg))
    return rigid(R, eye)


def smooth_noise(
    t: float, seed: int, frequency_hz: float, dims: int = 3, terms: int = 6
) -> np.ndarray:
    """Band-limited deterministic noise [dims] with unit RMS: a seeded sum of sinusoids with
    frequencies in [0.2, 1] x frequency_hz (smooth, C-infinity in t; not white noise)."""
    rng = np.random.default_rng([int(seed), 0x5EED])
    f = rng.uniform(0.2, 1.0, (dims, terms)) * frequency_hz
    ph = rng.uniform(0, 2 * np.pi, (dims, terms))
    a = rng.uniform(0.5, 1.0, (dims, terms))
    norm = np.sqrt((a**2).sum(1) / 2)
    return (a * np.sin(2 * np.pi * f * t + ph)).sum(1) / norm


def static_c2w(position, target, roll_deg: float = 0.0) -> np.ndarray:
    return look_at(position, target, roll_deg=roll_deg)


def orbit_c2w(
    t: float,
    duration: float,
    target,
    radius: float,
    height: float,
    start_deg: float,
    sweep_deg: float,
    roll_deg: float = 0.0,
) -> np.ndarray:
    """Circular orbit at constant angular speed; azimuth = start + sweep * t / duration (0 = +x, CCW
    from above).

    Distance to the target is sqrt(radius**2 + height**2) at every t.
    """
    az = np.deg2rad(start_deg + sweep_deg * (t / duration if duration > 0 else 0.0))
    tg = np.asarray(target, dtype=np.float64)
    eye = tg + np.array([radius * np.cos(az), radius * np.sin(az), height])
    return look_at(eye, tg, roll_deg=roll_deg)


def _ease(s: float) -> float:
    """Smoothstep 3s^2 - 2s^3 (zero velocity at both ends)."""
    s = min(max(s, 0.0), 1.0)
    return s * s * (3 - 2 * s)


def dolly_c2w(
    t: float, duration: float, start, end, target, track_target: bool = False, ease: bool = True
) -> np.ndarray:
    """Straight rail from start to end over the clip; orientation fixed (look at target from start)
    unless tracking."""
    s = t / duration if duration > 0 else 0.0
    s = _ease(s) if ease else min(max(s, 0.0), 1.0)
    start, end = np.asarray(start, dtype=np.float64), np.asarray(end, dtype=np.float64)
    eye = (1 - s) * start + s * end
    if track_target:
        return look_at(eye, target)
    M = look_at(start, target)
    M[:3, 3] = eye
    return M


def handheld_c2w(
    t: float,
    duration: float,
    waypoints,
    targets,
    position_m: float = 0.01,
    rotation_deg: float = 0.3,
    frequency_hz: float = 1.5,
    seed: int = 0,
) -> np.ndarray:
    """Smooth hand-held path: Catmull-Rom through evenly timed waypoints, looking at (splined)
    targets, plus smooth seeded jitter of the centre (world, std position_m) and of the orientation
    (camera axes, std rotation_deg)."""
    wp = np.asarray(waypoints, dtype=np.float64)
    tg = np.asarray(targets, dtype=np.float64)
    eye = hermite_spline(np.linspace(0, duration, len(wp)), wp, t) if len(wp) > 1 else wp[0]
    look = hermite_spline(np.linspace(0, duration, len(tg)), tg, t) if len(tg) > 1 else tg[0]
    eye = eye + position_m * smooth_noise(t, seed, frequency_hz)
    M = look_at(eye, look)
    w = np.deg2rad(rotation_deg) * smooth_noise(t, seed + 1, frequency_hz)
    if np.linalg.norm(w) > 0:
        M[:3, :3] = M[:3, :3] @ axis_angle(w, np.linalg.norm(w))
    return M


def camera_c2w(traj: dict, t: float, duration: float, seed: int = 0) -> np.ndarray:
    """c2w [4, 4] of a validated ``camera.trajectory`` spec at time t (seconds); duration = (G - 1)
    / fps."""
    k = traj["type"]
    if k == "static":
        return static_c2w(traj["position"], traj["target"], traj["roll_deg"])
    if k == "orbit":
        return orbit_c2w(
            t,
            duration,
            traj["target"],
            traj["radius"],
            traj["height"],
            traj["start_deg"],
            traj["sweep_deg"],
            traj["roll_deg"],
        )
    if k == "dolly":
        return dolly_c2w(
            t,
            duration,
            traj["start"],
            traj["end"],
            traj["target"],
            traj["track_target"],
            traj["ease"],
        )
    if k == "handheld":
        j = traj["jitter"]
        s = seed if j["seed"] is None else j["seed"]
        return handheld_c2w(
            t,
            duration,
            traj["waypoints"],
            traj["targets"],
            j["position_m"],
            j["rotation_deg"],
            j["frequency_hz"],
            s,
        )
    raise ValueError(f"unknown trajectory type {k!r}")


# --------------------------------------------------------------------------------------------------
# Splines
# --------------------------------------------------------------------------------------------------
def _tangents(times: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Catmull-Rom tangents (p[k+1] - p[k-1]) / (t[k+1] - t[k-1]); zero at the first and last
    key."""
    m = np.zeros_like(values)
    if len(times) > 2:
        m[1:-1] = (values[2:] - values[:-2]) / (times[2:] - times[:-2])[:, None]
    return m


def hermite_spline(times, values, t: float) -> np.ndarray:
    """Cubic Hermite curve through (times[k], values[k]) [K, D] at t with Catmull-Rom interior
    tangents and zero end tangents; held constant outside [times[0], times[-1]] (so C1 for all
    t)."""
    tk = np.asarray(times, dtype=np.float64)
    p = np.asarray(values, dtype=np.float64)
    if t <= tk[0]:
        return p[0].copy()
    if t >= tk[-1]:
        return p[-1].copy()
    m = _tangents(tk, p)
    i = int(np.clip(np.searchsorted(tk, t, side="right") - 1, 0, len(tk) - 2))
    h = tk[i + 1] - tk[i]
    s = (t - tk[i]) / h
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    return h00 * p[i] + h10 * h * m[i] + h01 * p[i + 1] + h11 * h * m[i + 1]


def _align_quats(q: np.ndarray) -> np.ndarray:
    """Flip signs so consecutive quaternions are on the same hemisphere (shortest arcs)."""
    q = q.copy()
    for k in range(1, len(q)):
        if np.dot(q[k], q[k - 1]) < 0:
            q[k] = -q[k]
    return q


def quat_spline(times, quats, t: float) -> np.ndarray:
    """Unit quaternion (w, x, y, z) at t: Hermite spline of sign-aligned key quaternions, normalised
    (C1, passes through the keys)."""
    q = hermite_spline(times, _align_quats(np.asarray(quats, dtype=np.float64)), t)
    return q / np.linalg.norm(q)


def _slerp_np(q0, q1, s):
    d = float(np.dot(q0, q1))
    if d < 0:
        q1, d = -q1, -d
    if d > 1 - 1e-9:
        q = (1 - s) * q0 + s * q1
    else:
        th = np.arccos(d)
        q = (np.sin((1 - s) * th) * q0 + np.sin(s * th) * q1) / np.sin(th)
    return q / np.linalg.norm(q)


# --------------------------------------------------------------------------------------------------
# Rigid object motion
# --------------------------------------------------------------------------------------------------
@lru_cache(maxsize=256)
def _key_quats(rotations_deg: tuple) -> np.ndarray:
    """[K, 4] quaternions of the keys' Euler rotations (cached: the same keys are evaluated every
    frame)."""
    q = np.stack([rotmat_to_quat(euler_xyz_deg(r)) for r in rotations_deg])
    q.setflags(write=False)
    return q


def keyframes_transform(
    t: float, keys: Sequence[dict], interpolation: str = "catmull_rom"
) -> np.ndarray:
    """4x4 [R(t) | p(t)] from keys [{time, position, rotate_deg}] (clamped outside the key
    range)."""
    times = np.array([k["time"] for k in keys], dtype=np.float64)
    pos = np.array([k["position"] for k in keys], dtype=np.float64)
    quats = _key_quats(tuple(tuple(float(a) for a in k.get("rotate_deg", (0, 0, 0))) for k in keys))
    if interpolation == "catmull_rom":
        p = hermite_spline(times, pos, t)
        q = quat_spline(times, quats, t)
    else:
        tc = min(max(t, times[0]), times[-1])
        i = int(np.clip(np.searchsorted(times, tc, side="right") - 1, 0, len(times) - 2))
        s = (tc - times[i]) / (times[i + 1] - times[i])
        p = (1 - s) * pos[i] + s * pos[i + 1]
        q = _slerp_np(quats[i], quats[i + 1], s)
    return rigid(quat_to_rotmat(q), p)


def translate_transform(
    t: float, velocity, start_time: float = 0.0, end_time: Optional[float] = None
) -> np.ndarray:
    """4x4 translation by velocity * (clamp(t, start, end) - start)."""
    te = t if end_time is None else min(t, end_time)
    dt = max(te - start_time, 0.0)
    return rigid(None, np.asarray(velocity, dtype=np.float64) * dt)


def _about_pivot(R: np.ndarray, pivot) -> np.ndarray:
    c = np.asarray(pivot, dtype=np.float64)
    return rigid(R, c - R @ c)


def rotate_transform(t: float, axis, speed_deg_s: float, pivot) -> np.ndarray:
    """4x4 rotation by speed * t about the world axis through pivot."""
    return _about_pivot(axis_angle(axis, np.deg2rad(speed_deg_s * t)), pivot)


def oscillate_transform(
    t: float,
    mode: str,
    axis,
    amplitude: float,
    frequency_hz: float,
    phase_deg: float = 0.0,
    pivot=(0.0, 0.0, 0.0),
) -> np.ndarray:
    """4x4 sinusoidal oscillation: offset a(t) = amplitude sin(2 pi f t + phase); translate along
    the unit axis by a(t) metres, or rotate by a(t) degrees about the axis through pivot
    (pendulum)."""
    a = amplitude * np.sin(2 * np.pi * frequency_hz * t + np.deg2rad(phase_deg))
    if mode == "translate":
        return rigid(None, a * normalize(axis))
    return _about_pivot(axis_angle(axis, np.deg2rad(a)), pivot)


def rigid_motion(motion: dict, t: float, default_pivot) -> np.ndarray:
    """4x4 world transform of a validated rigid ``motion`` spec
    (none/keyframes/translate/rotate/oscillate) at t."""
    k = motion["type"]
    pivot = default_pivot if motion.get("pivot") is None else motion["pivot"]
    if k in ("none", "articulated", "flag"):
        return np.eye(4)
    if k == "keyframes":
        return keyframes_transform(t, motion["keys"], motion["interpolation"])
    if k == "translate":
        return translate_transform(t, motion["velocity"], motion["start_time"], motion["end_time"])
    if k == "rotate":
        return rotate_transform(t, motion["axis"], motion["speed_deg_s"], pivot)
    if k == "oscillate":
        return oscillate_transform(
            t,
            motion["mode"],
            motion["axis"],
            motion["amplitude"],
            motion["frequency_hz"],
            motion["phase_deg"],
            pivot,
        )
    raise ValueError(f"unknown motion type {k!r}")


# --------------------------------------------------------------------------------------------------
# Articulated chains
# --------------------------------------------------------------------------------------------------
def joint_angles(t: float, joints: Sequence[dict]) -> np.ndarray:
    """[n] radians: base + rate t + amplitude sin(2 pi f t + phase) per joint (spec values in
    degrees)."""
    out = []
    for j in joints:
        a = j.get("base_deg", 0.0) + j.get("rate_deg_s", 0.0) * t
        a += j.get("amplitude_deg", 0.0) * np.sin(
            2 * np.pi * j.get("frequency_hz", 0.0) * t + np.deg2rad(j.get("phase_deg", 0.0))
        )
        out.append(np.deg2rad(a))
    return np.asarray(out, dtype=np.float64)


def chain_fk(lengths: Sequence[float], axes: Sequence, angles: Sequence[float]) -> np.ndarray:
    """Forward kinematics: [n, 4, 4] frame of each link in the chain's local frame.

    Frame_0 = Rot(axis_0, angle_0); Frame_i = Frame_{i-1} Trans(0, 0, length_{i-1}) Rot(axis_i,
    angle_i). Link i occupies z in [0, length_i] of Frame_i; joint axes are expressed in the parent
    frame."""
    n = len(lengths)
    frames = np.zeros((n, 4, 4))
    M = np.eye(4)
    for i in range(n):
        if i > 0:
            M = M @ rigid(None, (0.0, 0.0, lengths[i - 1]))
        M = M @ rigid(axis_angle(axes[i], angles[i]))
        frames[i] = M
    return frames


def chain_tip(lengths: Sequence[float], axes: Sequence, angles: Sequence[float]) -> np.ndarray:
    """[3] end of the last link in the chain's local frame."""
    F = chain_fk(lengths, axes, angles)
    return apply(F[-1], np.array([0.0, 0.0, lengths[-1]]))


def chain_vertices(vertices: np.ndarray, parts: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """[V, 3] chain-local posed vertices: each link-local vertex transformed by the frame of its
    link."""
    R = frames[parts, :3, :3]  # [V, 3, 3]
    T = frames[parts, :3, 3]
    return np.einsum("vij,vj->vi", R, vertices) + T


# --------------------------------------------------------------------------------------------------
# Non-rigid: waving flag
# --------------------------------------------------------------------------------------------------
def flag_deform(
    vertices: np.ndarray,
    t: float,
    width: float,
    amplitude: float,
    wavelength: float,
    frequency_hz: float,
    growth: float = 1.5,
    sag: float = 0.0,
) -> np.ndarray:
    """[V, 3] deformed grid vertices (grid-local: x from the pole, y along the pole, sheet normal
    +z).

    A sine wave travelling away from the pole, displacement along z:
        dz = amplitude * (x / width) ** growth * sin(2 pi (x / wavelength - f t)),
    plus a droop dy = -sag * (x / width) ** 2. Vertices at x = 0 (the pole edge) never move.
    """
    v = np.array(vertices, dtype=np.float64, copy=True)
    s = np.clip(v[:, 0] / width, 0.0, None)
    env = amplitude * s**growth
    v[:, 2] += env * np.sin(2 * np.pi * (v[:, 0] / wavelength - frequency_hz * t))
    v[:, 1] -= sag * s**2
    return v
