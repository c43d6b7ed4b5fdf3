"""Camera trajectories and object motion (benchgen.motion) against analytic answers and finite
differences."""

import math

import numpy as np
import pytest

from benchgen import motion as M
from benchgen.scene import load_scene
from benchgen.suite import builtin_scenes_dir

K = np.array([[100.0, 0, 64.0], [0, 100.0, 36.0], [0, 0, 1]])


def _project(c2w, p):
    """Independent pinhole projection of a world point: p_cam = R^T (p - T), u = fx x / z + cx."""
    pc = c2w[:3, :3].T @ (np.asarray(p, float) - c2w[:3, 3])
    return np.array([K[0, 0] * pc[0] / pc[2] + K[0, 2], K[1, 1] * pc[1] / pc[2] + K[1, 2]]), pc[2]


# --------------------------------------------------------------------------------------------------
# look-at
# --------------------------------------------------------------------------------------------------
def test_look_at_axis_aligned_case():
    # camera on -y looking at the origin along +y: x right = +x world, y down = -z world, z forward
    # = +y world
    c2w = M.look_at([0, -5, 0], [0, 0, 0])
    np.testing.assert_allclose(c2w[:3, :3], [[1, 0, 0], [0, 0, 1], [0, -1, 0]], atol=1e-12)
    np.testing.assert_allclose(c2w[:3, 3], [0, -5, 0])


@pytest.mark.parametrize("seed", range(5))
def test_look_at_points_at_target_with_world_up(seed):
    rng = np.random.default_rng(seed)
    eye = rng.uniform(-5, 5, 3)
    target = eye + np.r_[rng.uniform(-3, 3, 2), rng.uniform(-1, 1)] + np.r_[3.0, 0, 0]
    c2w = M.look_at(eye, target)
    R = c2w[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    fwd = (target - eye) / np.linalg.norm(target - eye)
    np.testing.assert_allclose(R[:, 2], fwd, atol=1e-12)  # +z points at the target
    assert abs(R[:, 0] @ [0, 0, 1]) < 1e-12  # no roll: image x is horizontal
    uv_t, z_t = _project(c2w, target)
    np.testing.assert_allclose(uv_t, K[:2, 2], atol=1e-9)  # the target is at the principal point
    uv_up, z_up = _project(c2w, target + [0, 0, 0.3])  # a point above the target ...
    assert z_up > 0 and uv_up[1] < uv_t[1]  # ... is higher in the image (smaller v)
    right = np.cross(fwd, [0, 0, 1])  # world direction to the viewer's right
    uv_r, _ = _project(c2w, target + 0.3 * right)
    assert uv_r[0] > uv_t[0]


def test_look_at_roll_and_degenerate_up():
    c2w = M.look_at([0, -5, 0], [0, 0, 0], roll_deg=90)
    uv_t, _ = _project(c2w, [0, 0, 0])
    uv_up, _ = _project(c2w, [0, 0, 0.5])
    assert uv_up[0] != pytest.approx(uv_t[0])  # rolled: "up" moves sideways
    down = M.look_at([0, 0, 5], [0, 0, 0])  # straight down: still a valid rotation
    np.testing.assert_allclose(down[:3, 2], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(down[:3, :3].T @ down[:3, :3], np.eye(3), atol=1e-12)


# --------------------------------------------------------------------------------------------------
# camera trajectories
# --------------------------------------------------------------------------------------------------
def test_orbit_constant_distance_and_sweep():
    target = np.array([0.5, -0.2, 1.0])
    r, h, start, sweep, T = 3.0, 0.8, -30.0, 80.0, 4.0
    for t in np.linspace(0, T, 17):
        c2w = M.orbit_c2w(t, T, target, r, h, start, sweep)
        eye = c2w[:3, 3]
        assert np.linalg.norm(eye - target) == pytest.approx(math.hypot(r, h), rel=1e-12)
        assert eye[2] - target[2] == pytest.approx(h)
        az = math.degrees(math.atan2(eye[1] - target[1], eye[0] - target[0]))
        assert az == pytest.approx(start + sweep * t / T, abs=1e-9)
        uv, _ = _project(c2w, target)
        np.testing.assert_allclose(uv, K[:2, 2], atol=1e-9)


def test_dolly_endpoints_fixed_orientation_and_ease():
    start, end, target, T = (
        np.array([-1.0, -3, 1.5]),
        np.array([1.0, -2, 1.4]),
        np.array([0, 1, 1]),
        3.0,
    )
    c0, c1 = M.dolly_c2w(0, T, start, end, target), M.dolly_c2w(T, T, start, end, target)
    np.testing.assert_allclose(c0[:3, 3], start)
    np.testing.assert_allclose(c1[:3, 3], end)
    np.testing.assert_allclose(c0[:3, :3], c1[:3, :3])  # pure translation
    mid = M.dolly_c2w(T / 2, T, start, end, target)
    np.testing.assert_allclose(mid[:3, 3], (start + end) / 2, atol=1e-12)  # smoothstep(1/2) = 1/2
    h = 1e-4  # eased: zero velocity at both ends, peak 1.5 |end - start| / T in the middle
    v0 = np.linalg.norm(M.dolly_c2w(h, T, start, end, target)[:3, 3] - start) / h
    vm = np.linalg.norm(M.dolly_c2w(T / 2 + h, T, start, end, target)[:3, 3] - mid[:3, 3]) / h
    assert v0 < 1e-3 and vm == pytest.approx(1.5 * np.linalg.norm(end - start) / T, rel=1e-3)
    tracked = M.dolly_c2w(T, T, start, end, target, track_target=True)
    np.testing.assert_allclose(_project(tracked, target)[0], K[:2, 2], atol=1e-9)


def test_handheld_follows_path_with_smooth_small_jitter():
    wp = [[-1.0, -3, 1.5], [0.0, -3.2, 1.6], [1.0, -3, 1.4]]
    tg = [[0, 1, 1.2]]
    T, sig = 3.0, 0.01
    for k, t in enumerate([0.0, T / 2, T]):
        c = M.handheld_c2w(t, T, wp, tg, position_m=sig, rotation_deg=0.3, seed=5)
        assert np.linalg.norm(c[:3, 3] - wp[k]) < 5 * sig * math.sqrt(3)
        # orientation stays within a few jitter-sigmas of the exact look-at
        R0 = M.look_at(c[:3, 3], tg[0])[:3, :3]
        ang = math.degrees(math.acos(np.clip((np.trace(R0.T @ c[:3, :3]) - 1) / 2, -1, 1)))
        assert ang < 5 * 0.3 * math.sqrt(3)
    no_jitter = M.handheld_c2w(T / 2, T, wp, tg, position_m=0, rotation_deg=0)
    np.testing.assert_allclose(no_jitter[:3, 3], wp[1], atol=1e-12)
    # jitter is smooth noise (strongly correlated at 30 fps), unit RMS, deterministic per seed
    ts = np.arange(0, 60, 1 / 30)
    n = np.array([M.smooth_noise(t, 3, 1.5) for t in ts])
    rho = np.mean([np.corrcoef(n[:-1, d], n[1:, d])[0, 1] for d in range(3)])
    assert rho > 0.95
    assert np.sqrt((n**2).mean()) == pytest.approx(1.0, rel=0.3)
    np.testing.assert_array_equal(M.smooth_noise(1.23, 3, 1.5), M.smooth_noise(1.23, 3, 1.5))
    assert not np.allclose(M.smooth_noise(1.23, 3, 1.5), M.smooth_noise(1.23, 4, 1.5))


# --------------------------------------------------------------------------------------------------
# keyframes
# --------------------------------------------------------------------------------------------------
KEYS = [
    {"time": 0.0, "position": [0, 0, 0], "rotate_deg": [0, 0, 0]},
    {"time": 0.5, "position": [1, 0.5, 0.2], "rotate_deg": [10, 0, 60]},
    {"time": 1.3, "position": [2, -0.5, 0.0], "rotate_deg": [0, 20, 150]},
    {"time": 2.0, "position": [2.5, 0.5, 0.6], "rotate_deg": [0, 0, 250]},
]


def test_keyframes_pass_through_keys():
    for k in KEYS:
        T = M.keyframes_transform(k["time"], KEYS)
        np.testing.assert_allclose(T[:3, 3], k["position"], atol=1e-12)
        np.testing.assert_allclose(T[:3, :3], M.euler_xyz_deg(k["rotate_deg"]), atol=1e-9)
        Tl = M.keyframes_transform(k["time"], KEYS, "linear")
        np.testing.assert_allclose(Tl[:3, 3], k["position"], atol=1e-12)
    # held outside the key range
    np.testing.assert_allclose(M.keyframes_transform(-1, KEYS), M.keyframes_transform(0, KEYS))
    np.testing.assert_allclose(M.keyframes_transform(9, KEYS), M.keyframes_transform(2.0, KEYS))


def _vel(f, t, h):
    return (f(t + h) - f(t - h)) / (2 * h)


def test_keyframes_are_c1():
    pos = lambda t: M.keyframes_transform(t, KEYS)[:3, 3]  # noqa: E731
    rot = lambda t: M.keyframes_transform(t, KEYS)[:3, :3]  # noqa: E731
    h = 1e-5
    for k in KEYS:
        t = k["time"]
        # one-sided velocities on both sides of each key agree (C1), including the clamped ends
        # (zero velocity)
        left = (pos(t) - pos(t - h)) / h
        right = (pos(t + h) - pos(t)) / h
        np.testing.assert_allclose(left, right, atol=1e-3)
        wl = rot(t) @ rot(t - h).T  # angular increments on both sides
        wr = rot(t + h) @ rot(t).T
        np.testing.assert_allclose((wl - wl.T) / (2 * h), (wr - wr.T) / (2 * h), atol=2e-3)
    # interior key velocity is the Catmull-Rom tangent (p[k+1] - p[k-1]) / (t[k+1] - t[k-1])
    p = np.array([k["position"] for k in KEYS])
    tk = np.array([k["time"] for k in KEYS])
    np.testing.assert_allclose(_vel(pos, tk[1], 1e-6), (p[2] - p[0]) / (tk[2] - tk[0]), atol=1e-4)
    # velocity is continuous everywhere: refining the grid shrinks the largest jump
    ts = np.linspace(-0.2, 2.2, 1201)
    v = np.array([_vel(pos, t, 1e-6) for t in ts])
    assert np.abs(np.diff(v, axis=0)).max() < 0.1


# --------------------------------------------------------------------------------------------------
# parametric rigid motion
# --------------------------------------------------------------------------------------------------
def test_translate_rotate_oscillate_analytic():
    T = M.translate_transform(2.0, [1, 2, 0], start_time=0.5, end_time=1.5)
    np.testing.assert_allclose(T[:3, 3], [1.0, 2.0, 0.0])
    np.testing.assert_allclose(M.translate_transform(0.2, [1, 2, 0], 0.5)[:3, 3], 0)
    pivot = np.array([1.0, 2.0, 3.0])
    R = M.rotate_transform(0.5, [0, 0, 2], 90.0, pivot)  # 45 degrees about z through pivot
    np.testing.assert_allclose(M.apply(R, pivot), pivot, atol=1e-12)
    np.testing.assert_allclose(
        M.apply(R, pivot + [1, 0, 0]), pivot + [math.sqrt(0.5), math.sqrt(0.5), 0], atol=1e-12
    )
    O = M.oscillate_transform(0.125, "translate", [0, 3, 0], 0.2, 2.0)  # sin(pi/2) = 1
    np.testing.assert_allclose(O[:3, 3], [0, 0.2, 0], atol=1e-12)
    # pendulum at +30 deg
    P = M.oscillate_transform(0.125, "rotate", [1, 0, 0], 30.0, 2.0, pivot=pivot)
    bob = M.apply(P, pivot - [0, 0, 1.0])
    np.testing.assert_allclose(
        bob, pivot + [0, math.sin(math.radians(30)), -math.cos(math.radians(30))], atol=1e-12
    )


# --------------------------------------------------------------------------------------------------
# articulated chains
# --------------------------------------------------------------------------------------------------
def test_chain_tip_planar_two_link():
    L0, L1 = 0.8, 0.5
    for a0, a1 in [(0.3, 0.9), (-0.5, 1.2), (0.0, 0.0)]:
        tip = M.chain_tip([L0, L1], [[0, 1, 0], [0, 1, 0]], [a0, a1])
        expected = [
            L0 * math.sin(a0) + L1 * math.sin(a0 + a1),
            0.0,
            L0 * math.cos(a0) + L1 * math.cos(a0 + a1),
        ]
        np.testing.assert_allclose(tip, expected, atol=1e-12)


def test_chain_tip_with_base_yaw():
    # base yaw psi about z, then a shoulder pitch: the planar answer rotated by psi about z
    L = [0.2, 0.7, 0.4]
    psi, a1, a2 = 0.7, 0.4, 0.8
    tip = M.chain_tip(L, [[0, 0, 1], [0, 1, 0], [0, 1, 0]], [psi, a1, a2])
    r = L[1] * math.sin(a1) + L[2] * math.sin(a1 + a2)
    z = L[0] + L[1] * math.cos(a1) + L[2] * math.cos(a1 + a2)
    np.testing.assert_allclose(tip, [r * math.cos(psi), r * math.sin(psi), z], atol=1e-12)


def test_joint_angles_formula():
    j = [
        {
            "base_deg": 10,
            "rate_deg_s": 20,
            "amplitude_deg": 30,
            "frequency_hz": 0.5,
            "phase_deg": 90,
        }
    ]
    t = 0.7
    expected = math.radians(10 + 20 * t + 30 * math.sin(2 * math.pi * 0.5 * t + math.pi / 2))
    assert M.joint_angles(t, j)[0] == pytest.approx(expected)


def test_scene_chain_links_stay_rigid():
    sc = load_scene(builtin_scenes_dir() / "tiny-flag-arm.yaml")
    idx = [o.name for o in sc.objects].index("arm")
    parts = sc.objects[idx].local.parts
    a, b = sc.object_vertices(idx, 0.0), sc.object_vertices(idx, 0.25)
    assert not np.allclose(a, b)
    for p in np.unique(parts):
        va, vb = a[parts == p], b[parts == p]
        da = np.linalg.norm(va[:, None] - va[None], axis=-1)
        db = np.linalg.norm(vb[:, None] - vb[None], axis=-1)
        np.testing.assert_allclose(da, db, atol=1e-9)


# --------------------------------------------------------------------------------------------------
# waving flag
# --------------------------------------------------------------------------------------------------
def test_flag_deformation_analytic_and_pole_fixed():
    from benchgen.meshes import grid

    W, Hh = 1.2, 0.8
    g = grid((W, Hh), (24, 8))
    A, lam, f, gr = 0.15, 0.9, 1.3, 1.5
    for t in (0.0, 0.37, 1.1):
        v = M.flag_deform(g.vertices, t, W, A, lam, f, gr)
        pole = g.vertices[:, 0] == 0
        np.testing.assert_array_equal(v[pole], g.vertices[pole])  # the pole edge never moves
        x = g.vertices[:, 0]
        dz = A * (x / W) ** gr * np.sin(2 * np.pi * (x / lam - f * t))
        np.testing.assert_allclose(v[:, 2] - g.vertices[:, 2], dz, atol=1e-12)
        assert np.abs(v[:, 2]).max() <= A + 1e-12
    # the wave travels away from the pole at phase speed f * lambda: the normalised profile at t +
    # dt equals the profile at t shifted by f * lambda * dt
    x = np.linspace(0.4, 1.1, 50)
    pts = lambda xx: np.stack([xx, np.zeros_like(xx), np.zeros_like(xx)], -1)  # noqa: E731
    dt = 0.05
    # noqa: E731
    shape = lambda xx, t: M.flag_deform(pts(xx), t, W, A, lam, f, gr)[:, 2] / (A * (xx / W) ** gr)
    np.testing.assert_allclose(shape(x, 0.3 + dt), shape(x - f * lam * dt, 0.3), atol=1e-12)


def test_scene_flag_pole_edge_fixed_in_world():
    sc = load_scene(builtin_scenes_dir() / "tiny-flag-arm.yaml")
    idx = [o.name for o in sc.objects].index("flag")
    pole = sc.objects[idx].local.vertices[:, 0] == 0
    v0 = sc.frame(0, 32, 18).meshes[idx].vertices
    v5 = sc.frame(5, 32, 18).meshes[idx].vertices
    np.testing.assert_allclose(v0[pole], v5[pole], atol=1e-12)
    assert np.abs(v0[~pole] - v5[~pole]).max() > 1e-3
