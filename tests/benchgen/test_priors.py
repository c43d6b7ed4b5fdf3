"""Prior degradation (benchgen.priors): oracle exactness, determinism, and error statistics against
the documented bands (docs/priors.md), measured with independent numpy code on small synthetic
scenes with known geometry."""

import dataclasses
import math

import numpy as np
import pytest

from benchgen.priors import (
    HARSH,
    ORACLE,
    PROFILES,
    REALISTIC,
    PriorProfile,
    degrade_depth,
    degrade_flow,
    degrade_tracks,
    flow_pairs,
    get_profile,
    make_rng,
    priors_metadata,
    select_track_indices,
)
from m4dgs.clip import TrackSet

T, H, W = 16, 72, 96
SQ = 24  # square side (px)


def _scene():
    """Slanted background plane (depth 4..8), sky rows (depth 0) at the top, a square at depth 2
    moving right by 2 px/frame, an emitter patch on the background, a glossy strip on the square.
    Tracks: static background grid (occluded inside the square) + points on the square (dynamic)."""
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    depth = np.zeros((T, H, W))
    emit = np.zeros((T, H, W), bool)
    gloss = np.zeros((T, H, W), bool)
    corners = []
    for t in range(T):
        x0, y0 = 10 + 2 * t, 30
        insq = (xs >= x0) & (xs < x0 + SQ) & (ys >= y0) & (ys < y0 + SQ)
        d = 4.0 + 4.0 * (H - ys) / H
        d[ys < 8] = 0.0
        d[insq] = 2.0
        depth[t] = d
        emit[t] = (xs >= 76) & (xs < 86) & (ys >= 14) & (ys < 24)
        gloss[t] = insq & (xs < x0 + 8)
        corners.append((x0, y0))
    gx, gy = np.meshgrid(np.arange(1, W, 3) + 0.5, np.arange(9, H, 3) + 0.5)
    bg = np.stack([gx.ravel(), gy.ravel()], -1)
    fx, fy = np.meshgrid(np.arange(1, SQ, 2) + 0.5, np.arange(1, SQ, 2) + 0.5)
    fg = np.stack([fx.ravel(), fy.ravel()], -1)
    N = len(bg) + len(fg)
    tracks = np.zeros((N, T, 2))
    vis = np.zeros((N, T), bool)
    for t, (x0, y0) in enumerate(corners):
        tracks[: len(bg), t] = bg
        inside = (bg[:, 0] >= x0) & (bg[:, 0] < x0 + SQ) & (bg[:, 1] >= y0) & (bg[:, 1] < y0 + SQ)
        vis[: len(bg), t] = ~inside
        tracks[len(bg) :, t] = fg + [x0, y0]
        vis[len(bg) :, t] = True
    dyn = np.zeros(N, bool)
    dyn[len(bg) :] = True
    ts = TrackSet(
        tracks=tracks.astype(np.float32), visible=vis, frames=np.arange(0, 2 * T, 2), dynamic=dyn
    )
    return depth.astype(np.float32), emit, gloss, ts


def _flow_scene(shift=6):
    """F_{a->b}: background pans (1, 0.5) px, square [30, 54)^2 moves (shift, 0); background pixels
    of a covered by b's square are invalid. ldr_a: left half saturated; ldr_b: textured mid grey."""
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    flow = np.zeros((H, W, 2))
    flow[..., 0], flow[..., 1] = 1.0, 0.5
    insq = (xs >= 30) & (xs < 54) & (ys >= 30) & (ys < 54)
    flow[insq] = [shift, 0.0]
    xb, yb = xs + flow[..., 0], ys + flow[..., 1]
    covered = (xb >= 30 + shift) & (xb < 54 + shift) & (yb >= 30) & (yb < 54) & ~insq
    valid = ~covered & (xb < W) & (yb < H)
    rng = np.random.default_rng(5)
    ldr_b = np.clip(128 + 40 * rng.standard_normal((H, W, 3)), 3, 250).astype(np.uint8)
    ldr_a = ldr_b.copy()
    ldr_a[:, : W // 2] = 255
    return flow.astype(np.float32), valid, ldr_a, ldr_b, insq


# --------------------------------------------------------------------------------------------------
# profiles
def test_profiles_registry_and_metadata():
    assert list(PROFILES) == [
        "oracle",
        "realistic",
        "harsh",
        "realistic-exact-depth",
        "realistic-exact-motion",
    ]
    # the lists of names the CLI and the suite files accept
    from benchgen.cli import make as make_cmd
    from eval.records.suite import PRIOR_PROFILES

    assert PRIOR_PROFILES == tuple(PROFILES)
    from benchgen.cli import BUILTIN_PRIORS

    assert BUILTIN_PRIORS == tuple(PROFILES)
    param = next(p for p in make_cmd.params if p.name == "priors").type
    assert [param.convert(n, None, None) for n in PROFILES] == list(PROFILES)
    assert get_profile() is REALISTIC
    with pytest.raises(KeyError):
        get_profile("perfect")
    assert ORACLE.depth_is_identity and ORACLE.tracks_is_identity and ORACLE.flow_is_identity
    for p in (REALISTIC, HARSH):
        assert not (p.depth_is_identity or p.tracks_is_identity or p.flow_is_identity)
    md = priors_metadata(REALISTIC, 3)
    assert md["profile"] == "realistic" and md["seed"] == 3
    assert set(md["params"]) == {f.name for f in dataclasses.fields(PriorProfile)}
    import json

    json.dumps(md, allow_nan=False)  # clip.json-safe


# --------------------------------------------------------------------------------------------------
# oracle / seeds
def test_oracle_equals_ground_truth_bytes():
    depth, emit, gloss, ts = _scene()
    d = degrade_depth(depth, emit, gloss, ORACLE, None)
    assert d.dtype == np.float32 and d.tobytes() == depth.tobytes()
    tr = degrade_tracks(ts, depth, W, H, ORACLE, None)
    assert (
        tr.tracks.tobytes() == ts.tracks.tobytes() and tr.visible.tobytes() == ts.visible.tobytes()
    )
    assert np.array_equal(tr.frames, ts.frames) and tr.points3d is None and tr.dynamic is None
    flow, valid, la, lb, _ = _flow_scene()
    f, v = degrade_flow(flow, valid, la, lb, 3.0, ORACLE, None)
    assert f.tobytes() == flow.tobytes() and v.tobytes() == valid.tobytes()


def test_partly_exact_profiles_keep_the_other_priors_byte_identical():
    """realistic-exact-depth: the depth is the ground truth, the tracks and flow are the realistic
    profile's bytes (same seed); realistic-exact-motion: the other way round."""
    depth, emit, gloss, ts = _scene()
    flow, valid, la, lb, _ = _flow_scene()

    def run(profile):
        d = degrade_depth(depth, emit, gloss, profile, make_rng(4, "depth"))
        t = degrade_tracks(ts, depth, W, H, profile, make_rng(4, "tracks"))
        f, v = degrade_flow(flow, valid, la, lb, 2.0, profile, make_rng(4, "flow", 0, 2))
        return d.tobytes(), t.tracks.tobytes(), t.visible.tobytes(), f.tobytes(), v.tobytes()

    gt = (depth.tobytes(), ts.tracks.tobytes(), ts.visible.tobytes())
    gt += (flow.astype(np.float32).tobytes(), valid.tobytes())
    real = run(REALISTIC)
    exact_depth = run(PROFILES["realistic-exact-depth"])
    exact_motion = run(PROFILES["realistic-exact-motion"])
    assert exact_depth[0] == gt[0] != real[0]
    assert exact_depth[1:] == real[1:]
    assert exact_motion[0] == real[0]
    assert exact_motion[1:] == gt[1:] and real[1] != gt[1] and real[3] != gt[3]
    for name, exact in (
        ("realistic-exact-depth", ("depth",)),
        ("realistic-exact-motion", ("tracks", "flow")),
    ):
        p = PROFILES[name]
        for fam in ("depth", "tracks", "flow"):
            assert getattr(p, f"{fam}_is_identity") == (fam in exact), (name, fam)


@pytest.mark.parametrize("profile", [REALISTIC, HARSH], ids=lambda p: p.name)
def test_same_seed_identical_different_seed_differs(profile):
    depth, emit, gloss, ts = _scene()
    flow, valid, la, lb, _ = _flow_scene()

    def run(seed):
        d = degrade_depth(depth, emit, gloss, profile, make_rng(seed, "depth"))
        t = degrade_tracks(ts, depth, W, H, profile, make_rng(seed, "tracks"))
        f, v = degrade_flow(flow, valid, la, lb, 0.0, profile, make_rng(seed, "flow", 0, 6))
        return d.tobytes(), t.tracks.tobytes(), t.visible.tobytes(), f.tobytes(), v.tobytes()

    a, b, c = run(1), run(1), run(2)
    assert a == b
    assert a[0] != c[0] and a[1] != c[1] and a[3] != c[3]


def test_make_rng_keys_independent():
    x = make_rng(0, "depth").random(4)
    assert np.array_equal(x, make_rng(0, "depth").random(4))
    assert not np.array_equal(x, make_rng(0, "tracks").random(4))
    assert not np.array_equal(
        make_rng(0, "flow", 0, 6).random(4), make_rng(0, "flow", 6, 0).random(4)
    )


# --------------------------------------------------------------------------------------------------
# depth
def _absrel_median_scaled(pred, gt, mask):
    s = np.median(gt[mask]) / np.median(pred[mask])
    return float(np.mean(np.abs(s * pred[mask] - gt[mask]) / gt[mask]))


@pytest.mark.parametrize(
    "profile,band", [(REALISTIC, (0.03, 0.12)), (HARSH, (0.08, 0.25))], ids=["realistic", "harsh"]
)
def test_depth_scale_and_absrel_band(profile, band):
    depth, emit, gloss, _ = _scene()
    surf = depth > 0
    for seed in range(4):
        out = degrade_depth(depth, emit, gloss, profile, make_rng(seed, "depth"))
        assert out.shape == depth.shape and out.dtype == np.float32
        assert np.isfinite(out).all() and (out > 0).all()
        # unknown global scale, clearly != 1 (|log2| >= the profile's lower bound minus drift/noise
        # slack)
        ratio = np.median(out[surf]) / np.median(depth[surf])
        assert abs(math.log2(ratio)) >= profile.depth_scale_stops[0] - 0.2
        absrel = _absrel_median_scaled(out, depth, surf)
        assert band[0] <= absrel <= band[1], absrel
    # sky filled with a value farther than every surface of its frame (checked without edge blur,
    # which smears it)
    out = degrade_depth(
        depth,
        emit,
        gloss,
        dataclasses.replace(profile, depth_edge_blur_px=0.0),
        make_rng(0, "depth"),
    )
    for t in (0, T - 1):
        assert np.median(out[t][~surf[t]]) > out[t][surf[t]].max()


def test_depth_drift_is_slow_and_errors_sit_on_edges_and_emitters():
    depth, emit, gloss, _ = _scene()
    surf = depth > 0
    out = degrade_depth(depth, emit, gloss, REALISTIC, make_rng(0, "depth")).astype(np.float64)
    # per-frame scale (median ratio on the plain background) drifts, but slowly
    plain = surf & ~emit & ~gloss
    plain[:, 30 - 8 : 54 + 8, :] = False  # away from the square's rows
    logs = np.array([np.log(np.median(out[t][plain[t]] / depth[t][plain[t]])) for t in range(T)])
    steps = np.abs(np.diff(logs))
    assert steps.max() < 0.05 and np.ptp(logs) > 1e-3
    # relative error after per-frame scaling: edges and emitters worse than the plain background
    rel = np.zeros_like(out)
    for t in range(T):
        rel[t] = np.abs(out[t] * math.exp(-logs[t]) - depth[t]) / np.where(surf[t], depth[t], 1.0)
    edge = np.zeros_like(surf)
    for t in range(T):  # the square's left/right borders, +-1 px
        x0 = 10 + 2 * t
        for xe in (x0, x0 + SQ):
            edge[t, 32:52, xe - 1 : xe + 1] = True
    assert rel[edge].mean() > 3 * rel[plain].mean()
    assert rel[emit].mean() > 3 * rel[plain].mean()
    assert rel[gloss].mean() > 2 * rel[plain].mean()


# --------------------------------------------------------------------------------------------------
# tracks
def test_track_selection_grid_plus_dynamic():
    _, _, _, ts = _scene()
    prof = dataclasses.replace(REALISTIC, track_num_uniform=48, track_num_dynamic=20)
    idx = select_track_indices(ts, W, H, prof, make_rng(0, "sel"))
    # the grid is round(sqrt(48 * 96 / 72)) = 8 x 48 / 8 = 6 cells of 12 x 12 px
    q = np.argmax(ts.visible, axis=1)
    pos = ts.tracks[np.arange(len(q)), q]
    cells = {(int(p[0] // 12), int(p[1] // 12)) for p in pos[ts.visible.any(1)]}
    n_dyn_extra = 20
    assert len(idx) == len(cells) + n_dyn_extra
    assert ts.dynamic[idx].sum() >= n_dyn_extra
    assert np.all(np.diff(idx) > 0)


def test_track_jitter_and_drift_statistics():
    _, _, _, ts = _scene()
    zero = dict(
        track_vis_flip_prob=0.0,
        track_edge_flip_prob=0.0,
        track_dropout_rate=0.0,
        track_num_uniform=None,
        track_num_dynamic=0,
    )
    # jitter only: per-axis std of the error on non-query frames equals sigma
    pj = dataclasses.replace(REALISTIC, track_drift_px=0.0, **zero)
    out = degrade_tracks(ts, None, W, H, pj, make_rng(0, "tracks"))
    err = out.tracks.astype(np.float64) - ts.tracks
    q = np.argmax(ts.visible, axis=1)
    nonq = np.arange(T)[None, :] != q[:, None]
    assert np.abs(err[~nonq]).max() == 0.0  # the query point is exact
    assert err[nonq].std() == pytest.approx(pj.track_jitter_px, rel=0.05)
    # drift only: variance grows linearly with the frame offset from the query frame (visible
    # points, q = 0)
    pd = dataclasses.replace(REALISTIC, track_jitter_px=0.0, track_occluded_drift_mult=1.0, **zero)
    out = degrade_tracks(ts, None, W, H, pd, make_rng(1, "tracks"))
    err = out.tracks.astype(np.float64) - ts.tracks
    sel = q == 0
    for k in (4, 12):
        assert err[sel, k].var() == pytest.approx(k * pd.track_drift_px**2, rel=0.2)
    # realistic: mean error within the documented band
    out = degrade_tracks(
        ts,
        None,
        W,
        H,
        dataclasses.replace(
            REALISTIC, **{k: v for k, v in zero.items() if k.startswith("track_num")}
        ),
        make_rng(2, "tracks"),
    )
    e = np.linalg.norm(out.tracks.astype(np.float64) - ts.tracks, axis=-1)
    assert 0.4 <= e.mean() <= 1.5


def test_track_visibility_mistakes_only_near_changes_and_dropouts():
    depth, _, _, ts = _scene()
    pv = dataclasses.replace(
        ORACLE,
        name="vis",
        track_vis_window=2,
        track_vis_flip_prob=0.5,
        track_num_uniform=None,
        track_num_dynamic=0,
    )
    out = degrade_tracks(ts, None, W, H, pv, make_rng(0, "tracks"))
    diff = out.visible != ts.visible
    assert diff.any()
    vis = ts.visible
    for n, t in zip(*np.nonzero(diff)):
        changes = [c for c in range(1, T) if vis[n, c] != vis[n, c - 1]]
        assert any(c - 2 <= t <= c + 1 for c in changes)
    # drop-outs: the fraction of tracks still reported visible k frames after the query decays like
    # (1 - r)^k
    r = 0.05
    pdrop = dataclasses.replace(
        ORACLE, name="drop", track_dropout_rate=r, track_num_uniform=None, track_num_dynamic=0
    )
    big = TrackSet(
        tracks=np.repeat(ts.tracks[-1:], 4000, 0),
        visible=np.ones((4000, T), bool),
        frames=ts.frames,
    )
    out = degrade_tracks(big, None, W, H, pdrop, make_rng(0, "tracks"))
    for k in (5, 12):
        assert out.visible[:, k].mean() == pytest.approx((1 - r) ** k, abs=0.03)
    lost = ~out.visible
    assert np.all(lost[:, :-1] <= lost[:, 1:])  # once lost, never visible again
    # near depth edges (realistic) the visibility of static background points also flips sometimes
    pe = dataclasses.replace(
        pv, track_vis_flip_prob=0.0, track_edge_px=2.0, track_edge_flip_prob=0.5
    )
    out = degrade_tracks(ts, depth, W, H, pe, make_rng(0, "tracks"))
    assert (out.visible != ts.visible).any()


# --------------------------------------------------------------------------------------------------
# flow
def test_flow_noisier_where_saturated_and_with_exposure_gap():
    flow, valid, la, lb, insq = _flow_scene()
    f, v = degrade_flow(flow, valid, la, lb, 0.0, REALISTIC, make_rng(0, "flow"))
    assert f.dtype == np.float32 and v.dtype == bool
    assert not (v & ~valid).any()  # valid is a subset of the ground-truth visibility
    epe = np.linalg.norm(f.astype(np.float64) - flow, axis=-1)
    band = np.zeros((H, W), bool)
    band[24:60, 24:66] = True  # around the square (motion boundaries)
    sat = np.zeros((H, W), bool)
    sat[:, : W // 2 - 6] = True
    ok = np.zeros((H, W), bool)
    ok[:, W // 2 + 6 :] = True
    e_sat, e_ok = epe[sat & ~band].mean(), epe[ok & ~band].mean()
    assert e_sat > 2.5 * e_ok
    assert 0.2 <= e_ok <= 0.8  # realistic band in well-exposed regions
    assert v[ok & ~band].mean() > 0.9 and v[sat & ~band].mean() < v[ok & ~band].mean()
    # motion-boundary band worse than the well-exposed interior
    edge = np.zeros((H, W), bool)
    edge[32:52, 52:56] = True  # right border of the square, inside the well-exposed half
    assert epe[edge].mean() > 2 * e_ok
    # exposure gap: error grows with EV difference
    f4, v4 = degrade_flow(flow, valid, la, lb, 4.0, REALISTIC, make_rng(0, "flow"))
    e4 = np.linalg.norm(f4.astype(np.float64) - flow, axis=-1)[ok & ~band].mean()
    assert e4 == pytest.approx(e_ok * (1 + 4 * REALISTIC.flow_ev_gain), rel=0.02)
    assert v4[ok & ~band].mean() < v[ok & ~band].mean()


def test_flow_pairs_alternating_three_levels():
    frames = list(range(0, 18, 2))  # 9 training frames
    dts = [0.125, 2.0, 32.0] * 3
    pairs = flow_pairs(frames, dts, 3)
    expected = []
    for a, b in [(0, 6), (2, 8), (4, 10), (6, 12), (8, 14), (10, 16)]:
        expected += [(a, b), (b, a)]
    assert pairs == expected
    for a, b in pairs:
        assert dts[frames.index(a)] == dts[frames.index(b)]
    # random values: paired anyway unless same level is required
    rv = [0.3, 1.0, 7.0, 0.2, 5.0]
    assert flow_pairs([0, 2, 4, 6, 8], rv, 3) == [(0, 6), (6, 0), (2, 8), (8, 2)]
    assert flow_pairs([0, 2, 4, 6, 8], rv, 3, require_same_level=True) == []
    assert flow_pairs([0, 2, 4, 6], [0.5, 8.0] * 2, 2) == [(0, 4), (4, 0), (2, 6), (6, 2)]


def test_nonfinite_ground_truth_gives_finite_priors():
    depth, _, _, ts = _scene()
    tr = ts.tracks.copy()
    vis = ts.visible.copy()
    tr[0, 3:6] = np.nan  # e.g. behind the camera: invisible, no projection
    vis[0, 3:6] = False
    tr[1, :] = np.nan
    vis[1, :] = False
    gt = TrackSet(tracks=tr, visible=vis, frames=ts.frames, dynamic=ts.dynamic)
    out = degrade_tracks(
        gt,
        depth,
        W,
        H,
        dataclasses.replace(REALISTIC, track_num_uniform=None, track_num_dynamic=0),
        make_rng(0, "tracks"),
    )
    assert np.isfinite(out.tracks).all()
    assert not out.visible[1].any()
    # held from the last finite frame
    np.testing.assert_allclose(out.tracks[0, 4], ts.tracks[0, 2], atol=10.0)
    flow, valid, la, lb, _ = _flow_scene()
    flow = flow.copy()
    flow[:5] = np.nan
    f, v = degrade_flow(flow, valid, la, lb, 0.0, REALISTIC, make_rng(0, "flow"))
    assert np.isfinite(f).all() and not v[:5].any()
