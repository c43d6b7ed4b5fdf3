"""Video-to-world transform (m4dgs.training.v2w) against analytic answers.

The synthetic scene is built in numpy, independently of m4dgs.core.camera / the rasterizer: world
Gaussians with known positions / rotations / scales are projected per frame to video space (u = fx x
/ z + cx, x_v = 2 u / W - 1), their video rotations are R_t^T R_w, and their video scales solve the
3 linear equations that make the orthographic 2D covariance equal the pinhole EWA one at a reference
frame."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from m4dgs.model.gaussians import GAIN_KEY, VideoGaussians, scale_inverse
from m4dgs.training import v2w
from m4dgs.training.config import AblationConfig, V2WConfig

W = H = 64
FX = FY = 70.0
CX = CY = 32.0
K_NP = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
T = 8


# --------------------------------------------------------------------------------------------------
# numpy scene helpers (independent of the code under test)
# --------------------------------------------------------------------------------------------------
def _xyzw_to_wxyz(q):
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


def _wxyz_to_xyzw(q):
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def _rotmat(q_wxyz):
    return Rotation.from_quat(_wxyz_to_xyzw(np.asarray(q_wxyz, dtype=np.float64))).as_matrix()


def _quat(R):
    return _xyzw_to_wxyz(Rotation.from_matrix(R).as_quat())


def _cameras(moving: bool):
    c2w = np.tile(np.eye(4), (T, 1, 1))
    if moving:
        for t in range(T):
            c2w[t, :3, :3] = Rotation.from_rotvec([0.004 * t, 0.01 * t, -0.003 * t]).as_matrix()
            c2w[t, :3, 3] = [0.04 * t, -0.01 * t, 0.02 * t]
    return c2w


def _to_cam(c2w_t, p_w):
    R, Tt = c2w_t[:3, :3], c2w_t[:3, 3]
    return (p_w - Tt) @ R  # R^T (p - T)


def _to_video(p_c):
    u = FX * p_c[..., 0] / p_c[..., 2] + CX
    v = FY * p_c[..., 1] / p_c[..., 2] + CY
    return np.stack([2 * u / W - 1, 2 * v / H - 1, p_c[..., 2]], axis=-1)


def _pinhole_cov(p_c, M, s):
    """EWA 2D covariance (no dilation): J M diag(s^2) M^T J^T."""
    x, y, z = p_c
    J = np.array([[FX / z, 0, -FX * x / z**2], [0, FY / z, -FY * y / z**2]])
    A = J @ M
    return A @ np.diag(s**2) @ A.T


def _ortho_cov(M, s):
    Jo = np.array([[W / 2, 0, 0], [0, H / 2, 0]])
    A = Jo @ M
    return A @ np.diag(s**2) @ A.T


def _video_scales_matching(p_c, M, s_w):
    """Video scales s_v with ortho cov == pinhole cov (3 linear equations in s_v^2); None if not all
    positive."""
    C = _pinhole_cov(p_c, M, s_w)
    Jo = np.array([[W / 2, 0, 0], [0, H / 2, 0]])
    cols = Jo @ M  # [2, 3]: projected axis k is cols[:, k]
    A = np.stack([cols[0] ** 2, cols[0] * cols[1], cols[1] ** 2])  # [3 eqs, 3 unknowns]
    sv2 = np.linalg.solve(A, np.array([C[0, 0], C[0, 1], C[1, 1]]))
    if np.any(sv2 <= 0):
        return None
    return np.sqrt(sv2)


def _fit_poly_np(q_t, degree=3):
    """Least-squares cubic in normalised time through sign-aligned unit quaternions [T, 4]."""
    q = q_t.copy()
    for t in range(1, len(q)):
        if np.dot(q[t], q[t - 1]) < 0:
            q[t] = -q[t]
    tn = np.arange(len(q)) / (len(q) - 1)
    V = np.stack([tn**j for j in range(degree + 1)], axis=1)
    coeffs, *_ = np.linalg.lstsq(V, q, rcond=None)
    return coeffs  # [J, 4]


def _build_scene(moving=True, n_static=12, n_dynamic=4, seed=0):
    rng = np.random.default_rng(seed)
    c2w = _cameras(moving)
    frames = np.arange(T)
    gs = []  # dicts with world trajectory, world quats per frame, world scales, dynamic flag
    while sum(not g["dyn"] for g in gs) < n_static or sum(g["dyn"] for g in gs) < n_dynamic:
        dyn = sum(g["dyn"] for g in gs) < n_dynamic
        z0 = rng.uniform(3.0, 5.0)
        if dyn:  # left part of the image, moving
            xn, yn = rng.uniform(-0.1, 0.0), rng.uniform(-0.2, 0.2)
            vel = rng.uniform(-0.02, 0.02, 3)
            acc = rng.uniform(-0.002, 0.002, 3)
            p0 = np.array([xn * z0, yn * z0, z0])
            traj = p0 + frames[:, None] * vel + 0.5 * frames[:, None] ** 2 * acc
            q0 = Rotation.random(random_state=rng.integers(1 << 30))
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            rots = [Rotation.from_rotvec(axis * 0.03 * t) * q0 for t in frames]
            R_w = np.stack([r.as_matrix() for r in rots])
        else:  # right part, static
            xn, yn = rng.uniform(0.15, 0.35), rng.uniform(-0.3, 0.3)
            p0 = np.array([xn * z0, yn * z0, z0])
            traj = np.tile(p0, (T, 1))
            R_w = np.tile(
                Rotation.random(random_state=rng.integers(1 << 30)).as_matrix(), (T, 1, 1)
            )
        s_w = rng.uniform(0.04, 0.09, 3)
        # video scales from the reference frame (middle of the clip)
        t_ref = T // 2
        p_c_ref = _to_cam(c2w[t_ref], traj[t_ref])
        M_ref = c2w[t_ref, :3, :3].T @ R_w[t_ref]
        s_v = _video_scales_matching(p_c_ref, M_ref, s_w)
        if s_v is None or np.any(s_v >= 0.05):
            continue
        inside = [np.all(np.abs(_to_video(_to_cam(c2w[t], traj[t]))[:2]) < 0.95) for t in frames]
        assert all(inside)  # the whole trajectory stays in the image
        gs.append({"dyn": dyn, "traj": traj, "R_w": R_w, "s_w": s_w, "s_v": s_v})

    # video Gaussians: a control point at every frame (the spline interpolates them exactly at the
    # frames)
    ctrl, coeffs, scales = [], [], []
    for g in gs:
        p_c = np.stack([_to_cam(c2w[t], g["traj"][t]) for t in frames])
        ctrl.append(_to_video(p_c))
        R_v = np.stack([c2w[t, :3, :3].T @ g["R_w"][t] for t in frames])
        coeffs.append(_fit_poly_np(_quat(R_v)))
        scales.append(g["s_v"])
    n = len(gs)
    dt = torch.float32
    video = VideoGaussians(
        torch.tensor(np.stack(ctrl), dtype=dt),
        torch.tensor(np.stack(coeffs), dtype=dt),
        scale_inverse(torch.tensor(np.stack(scales), dtype=dt), "sigmoid", 0.05),
        torch.linspace(-1.0, 1.0, n, dtype=dt),
        torch.randn(n, 5, generator=torch.Generator().manual_seed(seed), dtype=dt),
        torch.arange(T, dtype=dt),
        T,
        scale_kind="sigmoid",
        scale_max=0.05,
    )
    # exact dynamic masks: disks of radius 3 px around the dynamic Gaussians' pixels
    masks = np.zeros((T, H, W), dtype=bool)
    yy, xx = np.mgrid[0:H, 0:W] + 0.5
    for g in gs:
        if not g["dyn"]:
            continue
        for t in frames:
            u, v = (_to_video(_to_cam(c2w[t], g["traj"][t]))[:2] + 1) * W / 2
            masks[t] |= (xx - u) ** 2 + (yy - v) ** 2 <= 9.0
    for g in gs:  # sanity of the construction: static Gaussians never fall on the masks
        if not g["dyn"]:
            for t in frames:
                u, v = (_to_video(_to_cam(c2w[t], g["traj"][t]))[:2] + 1) * W / 2
                assert not masks[t, int(v), int(u)]
    return gs, video, c2w, masks


def _cov_rel_err(gs_rows, world_scales, c2w, world_quats_t, world_pos_t):
    """Mean over Gaussians and frames of ||pinhole cov(world) - ortho cov(video)||_F / ||ortho
    cov||_F (numpy)."""
    errs = []
    for i, g in enumerate(gs_rows):
        e = []
        for t in range(T):
            p_c = _to_cam(c2w[t], world_pos_t[i, t])
            M_w = c2w[t, :3, :3].T @ _rotmat(world_quats_t[i, t])
            M_v = c2w[t, :3, :3].T @ g["R_w"][t]
            cv = _ortho_cov(M_v, g["s_v"])
            cw = _pinhole_cov(p_c, M_w, world_scales[i])
            e.append(np.linalg.norm(cw - cv) / np.linalg.norm(cv))
        errs.append(np.mean(e))
    return float(np.mean(errs))


def _angle(q_a, q_b):
    d = np.abs(np.sum(q_a * q_b, -1)) / (
        np.linalg.norm(q_a, axis=-1) * np.linalg.norm(q_b, axis=-1)
    )
    return 2 * np.arccos(np.clip(d, -1, 1))


# --------------------------------------------------------------------------------------------------
# tests
# --------------------------------------------------------------------------------------------------
def test_video_to_world_trajectories_matches_numpy():
    rng = np.random.default_rng(3)
    n = 5
    c2w = np.tile(np.eye(4), (T, 1, 1))
    c2w[:, :3, :3] = Rotation.random(T, random_state=1).as_matrix()
    c2w[:, :3, 3] = rng.normal(size=(T, 3))
    pv = np.concatenate([rng.uniform(-1, 1, (n, T, 2)), rng.uniform(1, 6, (n, T, 1))], -1)
    qv = _xyzw_to_wxyz(Rotation.random(n * T, random_state=2).as_quat()).reshape(n, T, 4)
    pw, qw = v2w.video_to_world_trajectories(
        torch.tensor(pv), torch.tensor(qv), torch.tensor(K_NP), torch.tensor(c2w), W, H
    )
    u = (pv[..., 0] + 1) * W / 2
    v = (pv[..., 1] + 1) * H / 2
    z = pv[..., 2]
    pc = np.stack([(u - CX) / FX * z, (v - CY) / FY * z, z], -1)
    want = np.einsum("tij,ntj->nti", c2w[:, :3, :3], pc) + c2w[None, :, :3, 3]
    np.testing.assert_allclose(pw.numpy(), want, atol=1e-10)
    Rw = np.einsum("tij,ntjk->ntik", c2w[:, :3, :3], _rotmat(qv.reshape(-1, 4)).reshape(n, T, 3, 3))
    np.testing.assert_allclose(
        _rotmat(qw.numpy().reshape(-1, 4)).reshape(n, T, 3, 3), Rw, atol=1e-10
    )


def _run(video, c2w, masks, cov_invariance=True, steps=1000, depth=None, occlusion=True):
    cfg = V2WConfig(scale_refit_steps=steps)
    abl = AblationConfig(cov_invariance=cov_invariance, occlusion_handling=occlusion)
    return v2w.transform(video, K_NP, c2w, torch.tensor(masks), depth, cfg, abl, W, H)


def test_transform_synthetic_scene():
    gs, video, c2w, masks = _build_scene(moving=True)
    world, rep = _run(video, c2w, masks)
    truth_dyn = np.array([g["dyn"] for g in gs])
    np.testing.assert_array_equal(rep["is_dynamic"].numpy(), truth_dyn)
    assert rep["num_static"] == (~truth_dyn).sum() and rep["num_dynamic"] == truth_dyn.sum()
    s_rows = [g for g in gs if not g["dyn"]]
    d_rows = [g for g in gs if g["dyn"]]
    order = np.concatenate([np.where(~truth_dyn)[0], np.where(truth_dyn)[0]])
    ns = len(s_rows)

    # static: mean position and averaged rotation
    np.testing.assert_allclose(
        world.static["means"].detach().numpy(), np.stack([g["traj"][0] for g in s_rows]), atol=1e-4
    )
    ang = _angle(
        world.static["quats"].detach().numpy().astype(np.float64),
        np.stack([_quat(g["R_w"][0]) for g in s_rows]),
    )
    assert ang.max() < 1e-3, ang
    # dynamic: refitted spline and rotation polynomial at the frame times
    times = torch.arange(T, dtype=torch.float32)
    pos_t = world.positions(times).detach().numpy().astype(np.float64)  # [N, T, 3], static first
    q_t = world.quats(times).detach().numpy().astype(np.float64)
    np.testing.assert_allclose(pos_t[ns:], np.stack([g["traj"] for g in d_rows]), atol=2e-4)
    ang_d = _angle(q_t[ns:], np.stack([np.stack([_quat(R) for R in g["R_w"]]) for g in d_rows]))
    assert ang_d.max() < 1e-3, ang_d
    # opacity and features inherited
    torch.testing.assert_close(
        torch.cat([world.static["opacities"], world.dynamic["opacities"]]),
        video.params["opacities"][order],
    )
    torch.testing.assert_close(world.features(), video.params["features"][order])

    # scales: the refit reproduces the video 2D covariances at least as well as the true world
    # scales do
    rows = [gs[i] for i in order]
    s_fit = world.scales().detach().numpy().astype(np.float64)
    err_fit = _cov_rel_err(rows, s_fit, c2w, q_t, pos_t)
    err_true = _cov_rel_err(rows, np.stack([g["s_w"] for g in rows]), c2w, q_t, pos_t)
    assert err_fit < 0.05, (err_fit, err_true)
    assert err_fit <= err_true + 0.005, (err_fit, err_true)
    rel_s = np.abs(s_fit / np.stack([g["s_w"] for g in rows]) - 1)
    assert np.median(rel_s) < 0.05, rel_s
    assert rep["scale_fit"]["rel_err"] < rep["scale_fit"]["rel_err_init"] + 1e-6

    # ablation "inherit scale": the video scale values in world units; the 2D covariances are badly
    # off
    world_i, rep_i = _run(video, c2w, masks, cov_invariance=False)
    np.testing.assert_allclose(
        world_i.scales().detach().numpy(), video.scales().detach().numpy()[order], rtol=1e-5
    )
    err_inh = _cov_rel_err(
        rows, world_i.scales().detach().numpy().astype(np.float64), c2w, q_t, pos_t
    )
    assert err_inh > 0.5, err_inh
    assert rep_i["scale_fit"]["rel_err"] > 10 * rep["scale_fit"]["rel_err"]


def test_refit_exact_with_static_camera():
    """Static camera: the video covariances are reproducible exactly, so the refit recovers the true
    world scales."""
    gs, video, c2w, masks = _build_scene(moving=False, n_static=8, n_dynamic=0, seed=1)
    world, rep = _run(video, c2w, masks)
    assert rep["num_dynamic"] == 0 and world.num_static == 8
    times = torch.arange(T, dtype=torch.float32)
    pos_t = world.positions(times).detach().numpy().astype(np.float64)
    q_t = world.quats(times).detach().numpy().astype(np.float64)
    s_fit = world.scales().detach().numpy().astype(np.float64)
    err = _cov_rel_err(gs, s_fit, c2w, q_t, pos_t)
    assert err < 2e-3, err
    np.testing.assert_allclose(s_fit, np.stack([g["s_w"] for g in gs]), rtol=0.01)


def test_occlusion_handling():
    """A static Gaussian behind a passing occluder: on the dynamic mask but deeper than the rendered
    depth."""
    n_frames, size = 10, 16
    masks = torch.zeros(n_frames, size, size, dtype=torch.bool)
    depth = torch.full((n_frames, size, size), 5.0)
    masks[:6, 6:10, 6:10] = True  # the occluder covers the centre during frames 0..5
    depth[:6, 6:10, 6:10] = 2.0
    # pixel (8, 8), depth 5 (behind the occluder)
    background = torch.tensor([0.0, 0.0, 5.0]).expand(n_frames, 3)
    occluder = torch.stack([torch.tensor([0.0, 0.0, 2.0])] * n_frames)  # on the occluder's surface
    pos = torch.stack([background, occluder])
    with_occ = v2w.classify_dynamic(pos, masks, depth, size, size, 0.1, occlusion_handling=True)
    without = v2w.classify_dynamic(pos, masks, depth, size, size, 0.1, occlusion_handling=False)
    assert with_occ.tolist() == [False, True]
    assert without.tolist() == [True, True]
    nd = v2w.dynamic_counts(pos, masks, depth, size, size, occlusion_handling=True)
    assert nd.tolist() == [0, 6]
    # within the relative tolerance the Gaussian still counts as on the visible surface
    near = torch.tensor([0.0, 0.0, 2.0 * (1 + 0.5 * v2w.OCCLUSION_TOL)]).expand(n_frames, 3)[None]
    assert v2w.dynamic_counts(near, masks, depth, size, size).item() == 6
    # no rendered depth: no occlusion information
    assert v2w.classify_dynamic(pos, masks, None, size, size).tolist() == [True, True]


def test_occlusion_switch_in_transform():
    """The ablation switch reaches the classification inside `transform`."""
    gs, video, c2w, masks = _build_scene(moving=True, n_static=4, n_dynamic=1, seed=2)
    truth_dyn = np.array([g["dyn"] for g in gs])
    # a foreground occluder in front of every static Gaussian on every frame: masks say dynamic
    # there
    depth = np.full((T, H, W), 50.0, dtype=np.float32)
    masks_occ = masks.copy()
    for g in gs:
        if g["dyn"]:
            continue
        for t in range(T):
            u, v = (_to_video(_to_cam(c2w[t], g["traj"][t]))[:2] + 1) * W / 2
            masks_occ[t, int(v), int(u)] = True
            depth[t, int(v), int(u)] = 1.0
    _, rep = _run(video, c2w, masks_occ, steps=5, depth=torch.tensor(depth), occlusion=True)
    np.testing.assert_array_equal(rep["is_dynamic"].numpy(), truth_dyn)
    assert rep["occlusion_used"]
    _, rep_off = _run(video, c2w, masks_occ, steps=5, depth=torch.tensor(depth), occlusion=False)
    assert rep_off["is_dynamic"].all() and not rep_off["occlusion_used"]


def test_sample_resampling_and_motion_fallback():
    """resample="sample" takes the world trajectory at the knots (exact here: a knot per frame);
    without masks the authors' fallback classifies by world-position spread."""
    gs, video, c2w, _ = _build_scene(moving=True, n_static=4, n_dynamic=2, seed=4)
    truth_dyn = np.array([g["dyn"] for g in gs])
    cfg = V2WConfig(scale_refit_steps=5, resample="sample", rotation_refine_steps=0)
    world, rep = v2w.transform(video, K_NP, c2w, None, None, cfg, AblationConfig(), W, H)
    assert rep["classification"] == "motion_fallback"
    np.testing.assert_array_equal(rep["is_dynamic"].numpy(), truth_dyn)
    pos = world.positions(torch.arange(T, dtype=torch.float32)).detach().numpy()
    ns = int((~truth_dyn).sum())
    np.testing.assert_allclose(pos[ns:], np.stack([g["traj"] for g in gs if g["dyn"]]), atol=1e-4)


@pytest.mark.parametrize(
    "n_hits,ratio,expect",
    [(1, 0.1, False), (2, 0.1, True), (2, 0.15, True), (2, 0.2, False), (3, 0.2, True)],
)
def test_ratio_boundary(n_hits, ratio, expect):
    """dynamic iff N_d / N_f > ratio (strict), N_f = 10 frames."""
    n_frames, size = 10, 8
    masks = torch.zeros(n_frames, size, size, dtype=torch.bool)
    masks[:n_hits, 2, 5] = True  # pixel column 5, row 2
    # pixel (5, 2) <-> continuous u in [5, 6), v in [2, 3): x = 2u/W - 1; use a point near the
    # pixel's edge
    x = 2 * 5.01 / size - 1
    y = 2 * 2.99 / size - 1
    p = torch.tensor([x, y, 1.0]).expand(n_frames, 3)[None]
    assert v2w.classify_dynamic(p, masks, None, size, size, ratio).item() is expect


def test_outside_points_do_not_count():
    n_frames, size = 4, 8
    masks = torch.ones(n_frames, size, size, dtype=torch.bool)
    pts = torch.tensor(
        [
            [1.0, 0.0, 1.0],  # u == W: outside (pixels cover [0, W))
            [0.99, 0.0, 1.0],  # inside, last column
            [-1.0, -1.0, 1.0],  # u = v = 0: inside, first pixel
            [0.0, 0.0, -1.0],  # behind the camera
        ]
    )[:, None].expand(-1, n_frames, -1)
    assert v2w.dynamic_counts(pts, masks, None, size, size).tolist() == [0, n_frames, n_frames, 0]


def test_the_hand_over_carries_the_gain_over_time():
    """Beyond the paper: video Gaussians with a log2 gain over time hand it to their world
    Gaussians (static first, then dynamic, each in video order); without one the world Gaussians
    have none either."""
    gs, video, c2w, masks = _build_scene(moving=True)
    plain, _ = _run(video, c2w, masks, steps=5)
    assert GAIN_KEY not in plain.static and GAIN_KEY not in plain.dynamic
    state = video.to_state()
    gain = torch.randn(len(video), 6, generator=torch.Generator().manual_seed(0))
    state["params"][GAIN_KEY] = gain
    gained = VideoGaussians.from_state(state)
    world, rep = _run(gained, c2w, masks, steps=5)
    dyn = rep["is_dynamic"]
    assert 0 < int(dyn.sum()) < len(video)
    torch.testing.assert_close(world.static[GAIN_KEY].detach(), gain[~dyn], rtol=0, atol=0)
    torch.testing.assert_close(world.dynamic[GAIN_KEY].detach(), gain[dyn], rtol=0, atol=0)
    # the curves over time are the video Gaussians' (same frames, same knots)
    order = torch.cat([torch.where(~dyn)[0], torch.where(dyn)[0]])
    times = torch.tensor([0.0, 2.5, 7.0])
    torch.testing.assert_close(world.log2_gain(times), gained.log2_gain(times)[order])
    # and everything else is what the transform gives without the gain
    for part in ("static", "dynamic"):
        for k, v in getattr(plain, part).items():
            assert torch.equal(getattr(world, part)[k], v), (part, k)


def _reprojection_px(world, c2w, video_px):
    """Pixel distance, per (Gaussian, frame), between world Gaussians projected by numpy and the
    video Gaussians' pixels [N, T, 2]."""
    pos = world.positions(torch.arange(T2, dtype=torch.float64)).detach().numpy()
    p_c = np.stack([_to_cam(c2w[t], pos[:, t]) for t in range(T2)], 1)
    uv = np.stack([FX * p_c[..., 0] / p_c[..., 2] + CX, FY * p_c[..., 1] / p_c[..., 2] + CY], -1)
    return np.linalg.norm(uv - video_px, axis=-1)


T2 = 17


@pytest.mark.parametrize("moving", [False, True])
def test_pixel_fit_keeps_the_stage1_pixel_path_under_a_jittery_depth(moving):
    """A mover crossing the image 6 px a frame whose stage-1 depth jumps between knots (as a depth
    prior's does on a 3-px object): lifted along the rays, its world path is not a spline on the
    knots, so the world fit (the paper's) misses its pixels; the pixel fit (world_fit "pixel")
    follows them, paying in depth instead."""
    from m4dgs.core import spline

    rng = np.random.default_rng(3)
    knots = spline.make_knots(T2, 4, dtype=torch.float64)
    k = knots.numel()
    n = 3
    ctrl = np.zeros((n, k, 3))
    tk = knots.numpy()
    for i in range(n):
        ctrl[i, :, 0] = -0.8 + 0.1 * tk + 0.05 * np.sin(tk + i)  # ~6 px a frame at W = 64
        ctrl[i, :, 1] = -0.3 + 0.2 * i + 0.05 * np.cos(0.7 * tk)
        ctrl[i, :, 2] = 2.5 * (1 + 0.3 * rng.choice([-1.0, 1.0], k))  # depth jumps of +-30 %
    dt = torch.float64
    rot_identity = torch.zeros(n, 4, 4, dtype=dt)  # rotation polynomial: constant identity
    rot_identity[:, 0, 0] = 1.0
    video = VideoGaussians(
        torch.tensor(ctrl, dtype=dt),
        rot_identity,
        scale_inverse(torch.full((n, 3), 0.01, dtype=dt), "sigmoid", 0.05),
        torch.zeros(n, dtype=dt),
        torch.zeros(n, 5, dtype=dt),
        knots,
        T2,
        scale_kind="sigmoid",
        scale_max=0.05,
    )
    c2w = np.tile(np.eye(4), (T2, 1, 1))
    if moving:
        for t in range(T2):
            c2w[t, :3, :3] = Rotation.from_rotvec([0.002 * t, 0.01 * t, 0.0]).as_matrix()
            c2w[t, :3, 3] = [0.03 * t, 0.0, 0.01 * t]
    masks = torch.ones(T2, H, W, dtype=torch.bool)  # every Gaussian moves
    with torch.no_grad():
        pv = video.positions(torch.arange(T2, dtype=dt)).numpy()
    video_px = np.stack([(pv[..., 0] + 1) * W / 2, (pv[..., 1] + 1) * H / 2], -1)
    assert ((video_px[..., 0] > 0) & (video_px[..., 0] < W)).all()  # in view throughout
    err = {}
    for fit in ("world", "pixel"):
        cfg = V2WConfig(scale_refit_steps=2, rotation_refine_steps=0, world_fit=fit)
        world, rep = v2w.transform(video, K_NP, c2w, masks, None, cfg, AblationConfig(), W, H)
        assert rep["num_dynamic"] == n
        err[fit] = _reprojection_px(world, c2w, video_px)
    assert np.median(err["world"]) > 0.5, np.median(err["world"])
    assert np.median(err["pixel"]) < np.median(err["world"]) / 3, (
        np.median(err["pixel"]),
        np.median(err["world"]),
    )
    assert err["pixel"].max() < 0.5 * err["world"].max()


def test_pixel_fit_is_exact_where_the_world_path_is_a_spline():
    """With a world path that is itself a spline on the knots (the synthetic scene's: a control
    point at every frame), both fits give the same world Gaussians."""
    gs, video, c2w, masks = _build_scene(moving=True, n_static=2, n_dynamic=3, seed=5)
    out = {}
    for fit in ("world", "pixel"):
        cfg = V2WConfig(scale_refit_steps=2, rotation_refine_steps=0, world_fit=fit)
        world, _ = v2w.transform(
            video, K_NP, c2w, torch.tensor(masks), None, cfg, AblationConfig(), W, H
        )
        out[fit] = world.positions(torch.arange(T, dtype=torch.float32)).detach().numpy()
    np.testing.assert_allclose(out["pixel"], out["world"], atol=2e-3)


def test_pixel_fit_needs_a_least_squares_resample():
    from m4dgs.training.config import ConfigError, validate

    with pytest.raises(ConfigError, match="world_fit"):
        validate(V2WConfig(world_fit="pixel", resample="sample"))
    with pytest.raises(ConfigError, match="pixel_sigma"):
        validate(V2WConfig(pixel_sigma=0.0))
