"""MoSca-style camera initialisation (m4dgs.priors.camera_init) on a self-contained synthetic scene.

The scene generator below is test-only: a box-shaped room (5 planes) seen from a smoothly moving
camera with a known focal length, two moving spheres, exact raycast depth maps, exact tracks
(projection + occlusion test) and exact flow (rigid motion for the room, + sphere translation on the
spheres). Independent answers: the generator's cameras, focal and dynamic labels;
eval.metrics.geometry.ate for the trajectory error."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from m4dgs.clip import Cameras, ClipMeta, ClipWriter, Exposures, FlowSet, Split, TrackSet
from m4dgs.core.camera import K_from_fov, make_c2w, project_pinhole, umeyama_sim3
from m4dgs.core.warp import sample_per_frame
from m4dgs.priors.camera_init import (
    CameraInitConfig,
    chain_poses,
    initialize_cameras,
    robust_sim3,
    search_fov,
    select_static_tracks,
    umeyama_sim3_batched,
)
from m4dgs.priors.epipolar import EpipolarConfig, dynamic_masks, epipolar_error_maps

# --------------------------------------------------------------------------------------------------
# Synthetic scene (test-only generator)
# --------------------------------------------------------------------------------------------------
PLANES = [  # n . X = d, room interior (OpenCV-like world: y down, z forward)
    (np.array([1.0, 0, 0]), -4.0),  # left wall x = -4
    (np.array([1.0, 0, 0]), 4.0),  # right wall x = 4
    (np.array([0, 1.0, 0]), 1.5),  # floor y = 1.5
    (np.array([0, 1.0, 0]), -2.0),  # ceiling y = -2
    (np.array([0, 0, 1.0]), 12.0),  # back wall z = 12
]
# static spheres (centre, radius): non-planar structure against plane-degenerate epipolar fits
STATIC_BALLS = [
    (np.array([-2.6, 0.6, 8.5]), 0.9),
    (np.array([2.5, 0.9, 9.5]), 0.6),
    (np.array([0.3, -1.2, 10.0]), 0.7),
    (np.array([-1.8, -1.1, 4.5]), 0.4),
    (np.array([3.0, -0.8, 6.0]), 0.5),
    (np.array([0.6, 1.1, 4.0]), 0.35),
]
RADIUS = 0.7  # moving spheres
N_STATIC_OBJECTS = len(PLANES) + len(STATIC_BALLS)


def sphere_centres(s):
    """Centres of the two moving spheres at normalised time s in [0, 1]: [2, 3]."""
    return np.array(
        [
            [-1.0, 0.6 - 1.4 * s, 6.0],
            [1.3 + 0.3 * math.sin(2 * math.pi * s), -0.7 + 1.2 * s, 7.0 - 1.0 * s],
        ]
    )


def camera_pose(s):
    """c2w [4, 4] at normalised time s: sideways + forward translation, pan (yaw) and a little
    pitch/roll."""
    C = np.array([2.0 * s - 1.0, 0.25 * math.sin(2 * math.pi * s), 1.2 * s])
    yaw = math.radians(18.0 * (s - 0.5))
    pitch = math.radians(4.0 * math.sin(math.pi * s))
    roll = math.radians(2.0 * s)
    Ry = np.array(
        [[math.cos(yaw), 0, math.sin(yaw)], [0, 1, 0], [-math.sin(yaw), 0, math.cos(yaw)]]
    )
    Rx = np.array(
        [[1, 0, 0], [0, math.cos(pitch), -math.sin(pitch)], [0, math.sin(pitch), math.cos(pitch)]]
    )
    Rz = np.array(
        [[math.cos(roll), -math.sin(roll), 0], [math.sin(roll), math.cos(roll), 0], [0, 0, 1]]
    )
    return make_c2w(Ry @ Rx @ Rz, C)


def cast(o, rw, centres):
    """Ray parameter t [...] of the first hit and the object id [...] for rays o + t rw (rw [...,
    3]).

    Ids: planes 0..4, static balls 5..10, moving spheres 11, 12 (centres [2, 3] at this time).
    """
    ts = []
    for n, d in PLANES:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (d - o @ n) / (rw @ n)
        ts.append(np.where(t > 1e-6, t, np.inf))
    for c, r in list(STATIC_BALLS) + [(c, RADIUS) for c in centres]:
        oc = o - c
        a = (rw * rw).sum(-1)
        b = 2 * (rw @ oc)
        disc = b * b - 4 * a * (oc @ oc - r * r)
        t = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
        ts.append(np.where((disc > 0) & (t > 1e-6), t, np.inf))
    ts = np.stack(ts)
    return ts.min(0), ts.argmin(0)


def raycast(c2w, K, W, H, centres, uv=None):
    """Exact z-depth and hit id of pixel centres [H, W] (or of the continuous pixels uv [...,
    2])."""
    if uv is None:
        ys, xs = np.meshgrid(np.arange(H) + 0.5, np.arange(W) + 0.5, indexing="ij")
    else:
        xs, ys = uv[..., 0], uv[..., 1]
    rc = np.stack([(xs - K[0, 2]) / K[0, 0], (ys - K[1, 2]) / K[1, 1], np.ones_like(xs)], -1)
    return cast(c2w[:3, 3], rc @ c2w[:3, :3].T, centres)  # rc has z = 1, so t is the z-depth


def project(c2w, K, Xw):
    Xc = (Xw - c2w[:3, 3]) @ c2w[:3, :3]
    z = Xc[..., 2]
    zs = np.where(np.abs(z) > 1e-9, z, 1e-9)
    uv = np.stack([K[0, 0] * Xc[..., 0] / zs + K[0, 2], K[1, 1] * Xc[..., 1] / zs + K[1, 2]], -1)
    return uv, z


def _visible(uv, z, depth, W, H, tol=0.01):
    inside = (
        (z > 0.05) & (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H)
    )
    xi = np.clip(np.floor(uv[..., 0]).astype(int), 0, W - 1)
    yi = np.clip(np.floor(uv[..., 1]).astype(int), 0, H - 1)
    return inside & (z <= depth[yi, xi] * (1 + tol) + 0.02)


def make_scene(
    T=24,
    W=128,
    H=96,
    fov=50.0,
    n_static=600,
    n_dynamic=60,
    flow_gap=3,
    seed=0,
    depth_drift=0.0,
    depth_noise=0.0,
    track_jitter=0.0,
    flow_noise=0.0,
):
    """Synthetic clip data (dict of numpy arrays) with exact ground truth and optionally degraded
    priors."""
    rng = np.random.default_rng(seed)
    K = K_from_fov(W, H, fov)
    ss = np.linspace(0, 1, T)
    c2w = np.stack([camera_pose(s) for s in ss])
    cents = np.stack([sphere_centres(s) for s in ss])  # [T, 2, 3]
    depth, hit = zip(*[raycast(c2w[t], K, W, H, cents[t]) for t in range(T)])
    depth, hit = np.stack(depth), np.stack(hit)
    dyn_mask = hit >= N_STATIC_OBJECTS
    # static points: random pixels of the static scene in 3 key frames, lifted exactly
    pts = []
    for t in (0, T // 2, T - 1):
        uv = np.stack([rng.uniform(0, W, 4 * n_static), rng.uniform(0, H, 4 * n_static)], -1)
        z, hid = raycast(c2w[t], K, W, H, cents[t], uv)
        uv, z = (
            uv[hid < N_STATIC_OBJECTS][: n_static // 3],
            z[hid < N_STATIC_OBJECTS][: n_static // 3],
        )
        rc = np.stack(
            [(uv[:, 0] - K[0, 2]) / K[0, 0], (uv[:, 1] - K[1, 2]) / K[1, 1], np.ones(len(z))], -1
        )
        pts.append(c2w[t, :3, 3] + (rc * z[:, None]) @ c2w[t, :3, :3].T)
    Xs = np.concatenate(pts)  # [Ns, 3]
    Ns = Xs.shape[0]
    # dynamic points on the spheres
    dirs = rng.normal(size=(n_dynamic, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    which = np.arange(n_dynamic) % 2
    tracks = np.zeros((Ns + n_dynamic, T, 2))
    vis = np.zeros((Ns + n_dynamic, T), bool)
    p3 = np.zeros((Ns + n_dynamic, T, 3))
    for t in range(T):
        uv, z = project(c2w[t], K, Xs)
        tracks[:Ns, t], p3[:Ns, t] = uv, Xs
        vis[:Ns, t] = _visible(uv, z, depth[t], W, H)
        Xd = cents[t, which] + RADIUS * dirs
        uv, z = project(c2w[t], K, Xd)
        facing = ((c2w[t, :3, 3] - Xd) * dirs).sum(-1) > 0
        tracks[Ns:, t], p3[Ns:, t] = uv, Xd
        vis[Ns:, t] = facing & _visible(uv, z, depth[t], W, H, tol=0.02)
    dynamic = np.arange(Ns + n_dynamic) >= Ns
    # exact flow between frames flow_gap apart (both directions)
    pairs, flows, valids = [], [], []
    ys, xs = np.meshgrid(np.arange(H) + 0.5, np.arange(W) + 0.5, indexing="ij")
    for a in range(T):
        for b in (a - flow_gap, a + flow_gap):
            if not 0 <= b < T:
                continue
            rc = np.stack(
                [(xs - K[0, 2]) / K[0, 0], (ys - K[1, 2]) / K[1, 1], np.ones_like(xs)], -1
            )
            Xw = c2w[a, :3, 3] + (rc * depth[a][..., None]) @ c2w[a, :3, :3].T
            for k in range(2):
                sel = hit[a] == N_STATIC_OBJECTS + k
                Xw[sel] += cents[b, k] - cents[a, k]
            uv, z = project(c2w[b], K, Xw)
            pairs.append((a, b))
            flows.append(np.stack([uv[..., 0] - xs, uv[..., 1] - ys], -1))
            valids.append(_visible(uv, z, depth[b], W, H, tol=0.02))
    flow = np.stack(flows)
    # degraded priors
    drift = np.exp(depth_drift * np.sin(2 * np.pi * ss * 1.3 + 0.4)) if depth_drift else np.ones(T)
    dprior = depth * drift[:, None, None]
    if depth_noise:
        dprior = dprior * np.exp(rng.normal(0, depth_noise, dprior.shape))
    tr_prior = tracks + (rng.normal(0, track_jitter, tracks.shape) if track_jitter else 0)
    if flow_noise:
        flow = flow + rng.normal(0, flow_noise, flow.shape)
    return {
        "W": W,
        "H": H,
        "K": K,
        "fov": fov,
        "c2w": c2w,
        "depth": depth,
        "depth_prior": dprior.astype(np.float32),
        "drift": drift,
        "dyn_mask": dyn_mask,
        "tracks": TrackSet(
            tr_prior.astype(np.float32), vis, np.arange(T), p3.astype(np.float32), dynamic
        ),
        "flow": FlowSet(np.asarray(pairs, np.int64), flow.astype(np.float32), np.stack(valids)),
    }


def write_synthetic_clip(root, **kw) -> Path:
    """The synthetic scene as a clip folder (training frames = all frames, 2 alternating
    exposures)."""
    sc = make_scene(**kw)
    T, W, H = sc["c2w"].shape[0], sc["W"], sc["H"]
    dts = [0.125 if t % 2 == 0 else 2.0 for t in range(T)]
    meta = ClipMeta(
        name=Path(root).name,
        width=W,
        height=H,
        fps=24.0,
        frames=list(range(T)),
        split=Split(train=list(range(T)), test=[]),
        exposures=Exposures(train_dt=dts, observed=[0.125, 2.0], novel=[]),
        generator={"kind": "tests/priors/test_camera_init.py synthetic room"},
    )
    wr = ClipWriter(root, meta)
    for t in range(T):
        wr.write_input_ldr(t, np.full((H, W, 3), 128, np.uint8))
        wr.write_prior_depth(t, sc["depth_prior"][t])
        wr.write_gt_depth(t, sc["depth"][t].astype(np.float32))
        wr.write_gt_dynamic_mask(t, sc["dyn_mask"][t])
    ts = sc["tracks"]
    wr.write_prior_tracks(TrackSet(ts.tracks, ts.visible, ts.frames))
    wr.write_gt_tracks(ts)
    wr.write_prior_flow(sc["flow"])
    wr.write_gt_cameras(Cameras(np.arange(T), np.repeat(sc["K"][None], T, 0), sc["c2w"]))
    wr.finalize()
    return Path(root)


def _errors(res, sc):
    from eval.metrics.geometry import ate

    gt = sc["c2w"]
    gt_rel = np.linalg.inv(gt[0]) @ gt  # world = first camera, like the estimate
    est = res.c2w.numpy()
    a = ate(est, gt_rel)
    path_len = np.linalg.norm(np.diff(gt_rel[:, :3, 3], axis=0), axis=1).sum()
    ferr = abs(float(res.K[0, 0]) / sc["K"][0, 0] - 1)
    return a / path_len, ferr


# --------------------------------------------------------------------------------------------------
# Tests
# --------------------------------------------------------------------------------------------------
def test_sample_per_frame_matches_direct_bilinear():
    rng = np.random.default_rng(0)
    maps = torch.as_tensor(rng.uniform(1, 2, (3, 7, 9)))
    uv = torch.tensor([[[2.5, 3.5], [4.0, 1.0], [0.2, 6.9]]], dtype=torch.float64)  # [1, 3, 2]
    out = sample_per_frame(maps, uv)
    m = maps.numpy()
    assert abs(float(out[0, 0]) - m[0, 3, 2]) < 1e-12  # pixel centre -> the pixel's value
    # (4.0, 1.0): index (3.5, 0.5) -> mean of the 4 neighbours
    assert abs(float(out[0, 1]) - m[1, 0:2, 3:5].mean()) < 1e-12
    assert abs(float(out[0, 2]) - m[2, 6, 0]) < 1e-12  # clamped to the border


def test_batched_umeyama_matches_shared_umeyama():
    rng = np.random.default_rng(0)
    src = torch.as_tensor(rng.normal(size=(2, 3, 20, 3)))
    dst = torch.as_tensor(rng.normal(size=(2, 3, 20, 3)))
    w = torch.as_tensor(rng.uniform(0, 1, (2, 3, 20)))
    w[0, 1, 15:] = 0  # padding
    s, R, t = umeyama_sim3_batched(src, dst, w)
    for a in range(2):
        for b in range(3):
            s1, R1, t1 = umeyama_sim3(src[a, b], dst[a, b], weights=w[a, b])
            assert abs(float(s[a, b]) - float(s1)) < 1e-10
            assert torch.allclose(R[a, b], R1, atol=1e-10) and torch.allclose(
                t[a, b], t1, atol=1e-10
            )


def test_symmetric_scale_removes_regression_dilution():
    # two noisy copies of one point cloud with a true relative scale of 1.5: Umeyama's forward scale
    # is biased low by the noise variance ratio, the symmetric estimate is not (to first order)
    rng = np.random.default_rng(0)
    X = rng.normal(size=(4000, 3)) * np.array([1.0, 0.6, 0.3]) + np.array([0, 0, 5.0])
    src = torch.as_tensor(X + rng.normal(0, 0.15, X.shape))
    dst = torch.as_tensor(1.5 * X + rng.normal(0, 0.15 * 1.5, X.shape))
    K = torch.as_tensor(K_from_fov(100, 100, 60.0))
    uv = project_pinhole(dst, K)
    s_fwd, _, _ = umeyama_sim3(src, dst)
    s_sym, _, _, _ = robust_sim3(src, dst, uv, K, iters=1, scale_px=1e9, symmetric_scale=True)
    assert float(s_fwd) < 1.5 * 0.97
    assert abs(float(s_sym) / 1.5 - 1) < 0.01


def test_select_static_tracks_rule():
    vis = torch.tensor([[1, 1, 1, 1], [1, 1, 0, 0], [1, 0, 0, 0], [1, 1, 1, 1]], dtype=torch.bool)
    dyn = torch.tensor([[0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [0, 0, 0, 1]], dtype=torch.bool)
    ok = torch.ones(4, 4, dtype=torch.bool)
    assert select_static_tracks(vis, dyn, ok, 2, 0.3).tolist() == [True, False, False, True]
    assert select_static_tracks(vis, dyn, ok, 2, 0.2).tolist() == [True, False, False, False]


@pytest.fixture(scope="module")
def exact_scene():
    return make_scene(seed=0)


def _lifted(sc, static_only=True):
    ts = sc["tracks"]
    uv = torch.as_tensor(ts.tracks, dtype=torch.float64)
    vis = torch.as_tensor(ts.visible)
    if static_only:
        keep = ~torch.as_tensor(ts.dynamic)
        uv, vis = uv[keep], vis[keep]
    d = sample_per_frame(torch.as_tensor(sc["depth_prior"], dtype=torch.float64), uv)
    # exact per-track depth from the generator's 3D points (no bilinear blur across depth edges)
    p3 = (
        torch.as_tensor(ts.points3d, dtype=torch.float64)[~torch.as_tensor(ts.dynamic)]
        if static_only
        else None
    )
    c2w = torch.as_tensor(sc["c2w"])
    z = torch.einsum("tji,ntj->nti", c2w[:, :3, :3], p3 - c2w[None, :, :3, 3])[..., 2]
    return uv, z * torch.as_tensor(sc["drift"])[None], vis & (d > 0)


def test_fov_search_recovers_true_fov(exact_scene):
    sc = exact_scene
    uv, depth, usable = _lifted(sc)
    cfg = CameraInitConfig(fov_step_deg=2.0, fov_refine=False)
    fov, diag = search_fov(uv, depth / depth[usable].median(), usable, sc["W"], sc["H"], cfg)
    assert abs(fov - sc["fov"]) <= 2.0 + 1e-9
    assert not diag["fov_fallback"]
    sc2 = np.asarray(diag["fov_scores"])
    assert sc2.min() < 1e-3 and sc2.max() > 1.0  # exact data: zero error at the truth, clear curve


def test_chained_poses_exact(exact_scene):
    sc = exact_scene
    uv, depth, usable = _lifted(sc)
    K = torch.as_tensor(sc["K"])
    c2w, sig, _ = chain_poses(uv, depth, usable, K, CameraInitConfig())
    gt = np.linalg.inv(sc["c2w"][0]) @ sc["c2w"]
    assert np.allclose(c2w.numpy(), gt, atol=1e-6)
    assert np.allclose(sig.numpy(), 1.0, atol=1e-8)


def test_fov_fallback_on_flat_and_monotonic_curves():
    # no motion at all: every fov explains the (identical) frames perfectly -> flat curve -> 45 deg
    rng = np.random.default_rng(0)
    uv = torch.as_tensor(rng.uniform(0, 100, (50, 1, 2))).repeat(1, 3, 1)
    depth = torch.as_tensor(rng.uniform(1, 3, (50, 1))).repeat(1, 3)
    usable = torch.ones(50, 3, dtype=torch.bool)
    fov, diag = search_fov(uv, depth, usable, 100, 80, CameraInitConfig())
    assert fov == 45.0 and diag["fov_fallback"]
    # true fov (110 deg) outside the 10-90 search range: the score falls monotonically to the end ->
    # 45 deg
    sc = make_scene(fov=110.0, T=16, n_static=300, seed=3)
    uv, depth, usable = _lifted(sc)
    fov, diag = search_fov(uv, depth, usable, sc["W"], sc["H"], CameraInitConfig())
    assert fov == 45.0 and diag["fov_fallback"]
    assert np.argmin(diag["fov_scores"]) == len(diag["fov_scores"]) - 1


def test_bundle_adjustment_progress_bar_changes_nothing(capsys):
    """progress= shows a bar over the BA steps (stderr) and gives the same cameras."""
    sc = make_scene(T=8, n_static=120, seed=3)
    cfg = CameraInitConfig(ba_steps=20, depth_correction_start=5, log_every=0)
    args = (sc["tracks"], sc["depth_prior"], None, sc["W"], sc["H"], cfg)
    quiet = initialize_cameras(*args)
    assert "bundle adjustment" not in capsys.readouterr().err
    shown = initialize_cameras(*args, progress="camera init: bundle adjustment")
    err = capsys.readouterr().err
    assert "camera init: bundle adjustment" in err and "/20 " in err
    assert torch.equal(quiet.c2w, shown.c2w) and torch.equal(quiet.K, shown.K)


@pytest.mark.parametrize("noisy", [False, True])
def test_initialize_cameras_synthetic(noisy):
    if noisy:
        sc = make_scene(
            T=20,
            n_static=450,
            seed=1,
            depth_drift=0.15,
            depth_noise=0.02,
            track_jitter=0.5,
            flow_noise=0.2,
        )
    else:
        sc = make_scene(T=20, n_static=450, seed=0)
    em = epipolar_error_maps(
        sc["flow"], list(range(sc["c2w"].shape[0])), EpipolarConfig(ransac_hypotheses=128)
    )
    masks = dynamic_masks(em, 1.0)
    cfg = CameraInitConfig(ba_steps=150, depth_correction_start=40, log_every=50)
    res = initialize_cameras(sc["tracks"], sc["depth_prior"], masks, sc["W"], sc["H"], cfg)
    rel_ate, ferr = _errors(res, sc)
    # gauge: the first camera is the identity and its depth scale 1
    assert torch.equal(res.c2w[0], torch.eye(4, dtype=torch.float64))
    assert float(res.depth_scale[0]) == 1.0
    # dynamic tracks are (almost all) excluded
    dyn = torch.as_tensor(sc["tracks"].dynamic)
    assert float(res.static_track_mask[dyn].float().mean()) < 0.1
    assert float(res.static_track_mask[~dyn].float().mean()) > 0.8
    if noisy:
        assert ferr < 0.04 and rel_ate < 0.02
        # depth scales undo the injected drift (relative to frame 0)
        ds = res.depth_scale.numpy() * sc["drift"] / sc["drift"][0]
        assert np.abs(ds - 1).max() < 0.05
    else:
        assert ferr < 0.02 and rel_ate < 0.01
        assert np.abs(res.depth_scale.numpy() - 1).max() < 0.02


def test_bench_on_written_clip(tmp_path):
    import importlib.util

    root = write_synthetic_clip(tmp_path / "room", T=16, n_static=300, seed=2)
    spec = importlib.util.spec_from_file_location(
        "camera_init_bench", Path(__file__).resolve().parents[2] / "bench/camera_init_bench.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    row = mod.run_clip(
        root,
        CameraInitConfig(ba_steps=100, depth_correction_start=25),
        EpipolarConfig(ransac_hypotheses=128),
    )
    assert row["focal_err_pct"] < 3.0
    assert row["ate_rel_pct"] < 2.0
    assert row["mask_iou"] > 0.6
    assert set(row) >= {"time_s", "ate", "rpe_trans", "rpe_rot_deg", "fov_deg"}
