"""Tracks of bright blobs (m4dgs.priors.highlight_tracks) on videos drawn here, against the
movers' known positions; the initialisation keeps them under its cap; where the chains take over the
motion priors (step 5) and where they hold the depth prior (step 6), against counts and medians
worked out by hand; off, nothing changes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from m4dgs.model.gaussians import VideoInitConfig, init_video_gaussians
from m4dgs.priors.highlight_tracks import (
    Blob,
    brightest_blobs,
    chain_centres,
    chain_depth,
    chain_motion,
    highlight_masks,
    highlight_tracks,
    link_blobs,
)

W, H, T = 96, 64, 12
DTS = [0.25, 2.0, 16.0] * (T // 3)


def _disc(cx, cy, r):
    y, x = np.mgrid[0:H, 0:W] + 0.5
    return np.hypot(x - cx, y - cy) <= r


def _video(movers, static_bright=None, seed=0):
    """LDR frames of a dim textured plane and bright discs, through a gamma-2.2 response at DTS.
    movers: list of (x0, y0, vx, vy, r, radiance) per disc; static_bright: (x, y, r, radiance)."""
    rng = np.random.default_rng(seed)
    plane = 0.02 + 0.04 * rng.random((H, W, 1)).repeat(3, -1)
    frames = []
    for t, dt in enumerate(DTS):
        hdr = plane.copy()
        if static_bright is not None:
            x, y, r, v = static_bright
            hdr[_disc(x, y, r)] = v
        for x0, y0, vx, vy, r, v in movers:
            hdr[_disc(x0 + vx * t, y0 + vy * t, r)] = v
        ldr = np.clip(hdr * dt, 0, 1) ** (1 / 2.2)
        frames.append(np.round(ldr * 255).astype(np.uint8))
    return np.stack(frames)


def _chains(tracks, vis, points):
    return [(tracks[k : k + points], vis[k : k + points]) for k in range(0, len(tracks), points)]


def test_a_bright_disc_is_tracked_across_exposures():
    # radiance 3: saturated at dt 2 and 16, code ~ 0.75^(1/2.2) at dt 0.25 (the brightest there)
    video = _video([(20.0, 30.0, 5.0, 1.0, 5.0, 3.0)])
    tracks, vis = highlight_tracks(video, DTS, points=8)
    chains = _chains(tracks, vis, 8)
    assert len(chains) == 1
    tr, vi = chains[0]
    seen = np.nonzero(vi[0])[0]
    assert len(seen) >= T - 2  # every frame, or nearly (a blob may merge at the longest level)
    centre = np.array([[20.0 + 5.0 * t, 30.0 + 1.0 * t] for t in range(T)])
    # the first track is the centroid: within a quarter pixel of the disc's centre
    err = np.abs(tr[0, seen] - centre[seen]).max()
    assert err < 0.25, err
    # every track moves with the disc and stays inside it
    assert np.allclose(np.diff(tr[:, seen], axis=1), np.diff(centre[seen], axis=0), atol=0.5)
    assert (np.hypot(*(tr[:, seen] - centre[seen]).transpose(2, 0, 1)) <= 5.0).all()


def test_highlight_masks_cover_a_small_mover_and_leave_a_still_lamp_out():
    # a disc of radius 2 (the size the flow-based masks miss), 4 px a frame, and a still lamp as
    # bright: the lamp's chain stands still, so only the mover is masked
    video = _video([(15.0, 20.0, 4.0, 1.5, 2.0, 3.0)], static_bright=(80.0, 50.0, 2.5, 3.0))
    # frame 5 loses the mover (drawn dim): a gap the mask fills by interpolation
    dim = _video([], static_bright=(80.0, 50.0, 2.5, 3.0))
    video[5] = dim[5]
    masks = highlight_masks(video, DTS, dilate_px=1.0)
    assert masks.shape == (T, H, W)
    for t in range(T):
        disc = _disc(15.0 + 4.0 * t, 20.0 + 1.5 * t, 2.0)
        assert masks[t][disc].all(), t  # every pixel of the mover, the gap frame included
        # and nothing far from it (radius + dilation + the blob's own anti-aliasing margin)
        far = ~_disc(15.0 + 4.0 * t, 20.0 + 1.5 * t, 5.0)
        assert not masks[t][far].any(), t
    assert not masks[:, _disc(80.0, 50.0, 3.0)].any()  # the still lamp
    # without movers there is nothing to mask
    assert not highlight_masks(dim, DTS).any()


def test_a_patch_bright_only_at_the_longest_exposure_gives_no_track():
    # radiance 0.1: white only at dt 16 (as white as the mover there); at dt 0.25 and 2 far below
    # the mover's code, so its chain holds blobs at one exposure level only
    video = _video([(20.0, 30.0, 5.0, 1.0, 5.0, 3.0)], static_bright=(75.0, 15.0, 6.0, 0.1))
    tracks, vis = highlight_tracks(video, DTS, points=4)
    chains = _chains(tracks, vis, 4)
    assert len(chains) == 1  # the mover only
    assert tracks[0, vis[0]][:, 0].max() < 80.0 and np.ptp(tracks[0, vis[0]][:, 0]) > 40.0


def test_two_movers_give_two_chains_that_do_not_swap():
    video = _video([(15.0, 15.0, 5.0, 0.0, 4.0, 3.0), (80.0, 50.0, -5.0, 0.0, 4.0, 3.0)])
    tracks, vis = highlight_tracks(video, DTS, points=1)
    assert tracks.shape[0] == 2
    for k in range(2):
        xs = tracks[k, vis[k], 0]
        steps = np.diff(xs) / np.diff(np.nonzero(vis[k])[0])
        assert np.allclose(steps, steps[0], atol=0.5) and abs(abs(steps[0]) - 5.0) < 0.5


def test_link_blobs_gates_by_distance_and_area():
    b = [[Blob(10.0, 10.0, 20)], [Blob(14.0, 10.0, 20)], [Blob(60.0, 10.0, 20)]]
    chains = link_blobs(b, diagonal=100.0, max_step=0.1, max_gap=1)
    assert sorted(len(c) for c in chains) == [1, 2]  # 46 px > 10 px a frame: a new chain
    b = [[Blob(10.0, 10.0, 20)], [Blob(12.0, 10.0, 200)]]
    assert sorted(len(c) for c in link_blobs(b, 100.0, area_ratio=3.0)) == [1, 1]


def test_brightest_blobs_size_limits():
    img = np.zeros((H, W, 3), np.uint8)
    img[10:12, 10:11] = 255  # 2 px: below min_area
    img[30:36, 40:46] = 255  # 36 px
    img[:, 80:] = 255  # a bright wall: 16 x 64 = 1,024 px > 2 % of the image
    blobs = brightest_blobs(img, min_area=3, max_area=0.02)
    assert [(b.x, b.y, b.area) for b in blobs] == [(43.0, 33.0, 36)]


def test_the_cap_keeps_the_highlight_tracks():
    n, k = 50, 6
    rng = np.random.default_rng(0)
    # still points: the spline fit reproduces them exactly
    start = rng.uniform(1, 60, (n + k, 1, 2)).astype(np.float32)
    tracks = torch.from_numpy(np.repeat(start, T, axis=1))
    vis = torch.ones(n + k, T, dtype=torch.bool)
    always = torch.zeros(n + k, dtype=torch.bool)
    always[n:] = True
    depth = torch.ones(T, H, W)
    cfg = VideoInitConfig(max_gaussians=10)
    g = init_video_gaussians(tracks, vis, depth, W, H, cfg, always=always)
    assert g.num_gaussians == 10
    # the last six Gaussians (kept in index order) are the highlight tracks, at their positions
    pos = g.positions(0.0)[-k:, :2]
    want = tracks[n:, 0] / torch.tensor([W, H]) * 2 - 1
    assert torch.allclose(pos, want, atol=1e-3)


@pytest.mark.parametrize("on", [False, True])
def test_init_tracks_adds_nothing_unless_asked(on):
    from m4dgs.training.data import init_tracks

    prior = torch.rand(7, T, 2) * 50
    d = _training_data(_video([(20.0, 30.0, 5.0, 1.0, 5.0, 3.0)]), prior)
    tr, vi, always = init_tracks(d, VideoInitConfig(highlight_tracks=on, highlight_points=4))
    assert torch.equal(tr[:7], prior) and int((~always).sum()) == 7
    assert tr.shape[0] == (7 + 4 if on else 7) and int(always.sum()) == (4 if on else 0)


def test_a_one_pixel_glint_is_tracked_only_with_the_smaller_min_area():
    """A glint (one pixel, radiance 3, 2 px a frame) is below the tracker's default 3-pixel blobs;
    `init.highlight_min_area=1` links it, and its tracks sit on it."""
    from m4dgs.training.data import init_tracks

    prior = torch.rand(7, T, 2) * 50
    d = _training_data(_video([(20.5, 30.5, 2.0, 0.0, 0.6, 3.0)]), prior)
    _, _, always = init_tracks(d, VideoInitConfig(highlight_tracks=True, highlight_points=4))
    assert int(always.sum()) == 0
    cfg = VideoInitConfig(highlight_tracks=True, highlight_points=4, highlight_min_area=1)
    tr, vi, always = init_tracks(d, cfg)
    assert int(always.sum()) == 4
    seen = np.nonzero(vi[-1].numpy())[0]
    assert len(seen) >= T // 2, seen
    centre = tr[-4:].mean(0).numpy()[seen]
    want = np.array([[20.5 + 2.0 * t, 30.5] for t in seen])
    assert np.abs(centre - want).max() < 0.5


def test_the_disc_clip_of_the_regression_test_is_tracked(load_bench):
    """The frames tests/training/test_small_mover.py trains on (bench/small_mover_bench.py, through
    the clip's hdrnerf response at benchgen's alternating exposures): one chain, on the disc."""
    from m4dgs.core.crf import clip_crf, tonemap_ldr

    smb = load_bench("small_mover_bench")
    hdr, _, centres = smb.disc_frames()
    train = list(range(0, hdr.shape[0], 2))
    dts = [[0.125, 2.0, 32.0][i % 3] for i in range(len(train))]
    scale = 1.3  # about the scale benchgen from-hdr chooses for these frames
    f = clip_crf("hdrnerf")
    ldr = np.stack([tonemap_ldr(hdr[g] * scale, dt, f) for g, dt in zip(train, dts)])
    tracks, vis = highlight_tracks(ldr, dts, points=16)
    assert tracks.shape[0] == 16
    seen = np.nonzero(vis[0])[0]
    assert len(seen) >= 9, seen
    err = np.abs(tracks[0, seen] - centres[train][seen]).max()
    assert err < 1.0, err


def _training_data(video, tracks, flow_pairs=(), flow_valid=None):
    from m4dgs.training.data import TrainingData

    n = tracks.shape[0]
    return TrainingData(
        clip_name="x",
        frames=list(range(0, 2 * T, 2)),
        width=W,
        height=H,
        ldr=torch.from_numpy(video.astype(np.float32) / 255),
        log2_dt=torch.log2(torch.tensor(DTS)),
        depth=torch.ones(T, H, W),
        tracks=tracks,
        track_vis=torch.ones(n, T, dtype=torch.bool),
        flow_pairs=list(flow_pairs),
        flow=None if flow_valid is None else torch.zeros(*flow_valid.shape, 2),
        flow_valid=flow_valid,
        unit_exposure_value=1.0,
        num_levels=3,
    )


def test_chain_centres_sit_on_the_disc_and_are_nan_where_the_chain_misses():
    video = _video([(20.0, 30.0, 5.0, 1.0, 5.0, 3.0)])
    tracks, vis = highlight_tracks(video, DTS, points=8)
    vis[:, 3] = False  # as if the chain had a gap at frame 3
    c = chain_centres(tracks, vis, 8)
    assert c.shape == (1, T, 2)
    assert np.isnan(c[0, 3]).all()
    seen = np.nonzero(vis[0])[0]
    centre = np.array([[20.0 + 5.0 * t, 30.0 + 1.0 * t] for t in range(T)])
    # the mean of a sunflower pattern of 8 points within 0.6 r of the centroid: well inside 0.5 px
    assert np.abs(c[0, seen] - centre[seen]).max() < 0.5


def test_chain_motion_drops_the_followers_and_clears_the_flow_around_the_chain():
    T2, Hs, Ws = 4, 40, 40
    centres = np.full((1, T2, 2), np.nan)
    centres[0, :3] = [[10.5, 20.5], [12.5, 20.5], [14.5, 20.5]]  # no blob at frame 3
    base = np.repeat(centres[0, :3].mean(0, keepdims=True), T2, 0)[None]
    tracks = np.concatenate(
        [
            np.nan_to_num(centres, nan=30.0) + [1.0, 0.0],  # follows at 1 px: dropped
            np.nan_to_num(centres, nan=30.0) + [0.0, 2.5],  # 2.5 px off: kept
            base + [20.0, 0.0],  # far: kept
            np.nan_to_num(centres, nan=30.0) + [0.0, 1.0],  # near on 3 frames, seen on 2: kept
        ]
    )
    vis = np.ones((4, T2), bool)
    vis[3, 0] = False
    pairs = [(0, 1), (1, 0), (3, 2)]
    fv = np.ones((3, Hs, Ws), bool)
    keep, out = chain_motion(tracks, vis, centres, pairs, fv)
    assert keep.tolist() == [False, True, True, True]
    assert fv.all()  # the input is left alone
    # pixel centres strictly within 3 px of a pixel centre: 5 columns of 5 (dx, dy in -2..2)
    assert (~out).sum(axis=(1, 2)).tolist() == [25, 25, 0]
    assert not out[0, 20, 10] and out[0, 20, 13] and not out[0, 20, 12]
    assert not out[1, 20, 12] and out[1, 20, 15]
    assert chain_motion(tracks, vis, centres, pairs, None)[1] is None


def test_stage1_data_lets_the_chain_carry_the_disc_and_changes_nothing_when_off():
    from m4dgs.training.data import init_tracks, stage1_data

    video = _video([(20.0, 30.0, 5.0, 1.0, 5.0, 3.0)])
    rng = np.random.default_rng(1)
    truth = np.array([[20.0 + 5.0 * t, 30.0 + 1.0 * t] for t in range(T)])
    on_disc = truth[None] + rng.normal(0, 0.4, (3, T, 2))  # three prior tracks on the disc
    # elsewhere (the disc runs along y = 30-41, x = 20-75)
    off_disc = rng.uniform([5, 50], [90, 60], (5, 1, 2)).repeat(T, 1)
    prior = torch.from_numpy(np.concatenate([off_disc, on_disc]).astype(np.float32))
    pairs = [(t, t + 1) for t in range(T - 1)]
    d = _training_data(video, prior, pairs, torch.ones(len(pairs), H, W, dtype=torch.bool))

    same, chain = stage1_data(d, VideoInitConfig(highlight_tracks=True, highlight_points=4))
    assert same is d and not chain.any()

    cfg = VideoInitConfig(highlight_motion=True, highlight_points=4)
    s1, chain = stage1_data(d, cfg)
    assert s1.tracks.shape[0] == 5 + 4 and chain.tolist() == [False] * 5 + [True] * 4
    assert torch.equal(s1.tracks[:5], prior[:5])  # the followers are gone, the rest kept in order
    seen = s1.track_vis[5].numpy()
    assert np.abs(s1.tracks[5].numpy()[seen] - truth[seen]).max() < 0.25  # the chain's centroid
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    for p, (i, _) in enumerate(pairs):
        cleared = ~s1.flow_valid[p].numpy()
        if seen[i]:
            # a disc of 3 px about the chain's centre, within half a pixel of the disc's
            r = np.hypot(xs - truth[i, 0], ys - truth[i, 1])
            assert cleared[r < 2.5].all() and not cleared[r > 3.5].any()
        else:
            assert not cleared.any()
    assert d.flow_valid.all()  # the clip's priors are left alone
    # the initialisation lifts the chain's tracks once, and keeps them under its cap
    tr, _, always = init_tracks(
        s1, VideoInitConfig(highlight_tracks=True, highlight_motion=True, highlight_points=4), chain
    )
    assert tr.shape[0] == 9 and torch.equal(always, chain)


def test_the_video_stage_trains_on_the_chains_priors():
    """Stage 1 (m4dgs.training.stage1.VideoStage) with `stage1.init.highlight_motion`: its track and
    flow losses read the chains' priors, and it lifts one Gaussian per track of them."""
    from m4dgs.training.config import apply_overrides, preset
    from m4dgs.training.stage1 import VideoStage

    video = _video([(20.0, 30.0, 5.0, 1.0, 5.0, 3.0)])
    truth = np.array([[20.0 + 5.0 * t, 30.0 + 1.0 * t] for t in range(T)])
    prior = np.concatenate(
        [truth[None] + 0.3, np.full((4, T, 2), 10.0) + np.arange(4)[:, None, None]]
    )
    pairs = [(t, t + 1) for t in range(T - 1)]
    d = _training_data(
        video,
        torch.from_numpy(prior.astype(np.float32)),
        pairs,
        torch.ones(len(pairs), H, W, dtype=torch.bool),
    )
    cfg = preset("tiny")
    cfg.width, cfg.height = W, H
    cfg.tonemap.pretrain_steps = 0
    on = VideoStage(d, apply_overrides(cfg, {"stage1.init.highlight_motion": True}))
    off = VideoStage(d, cfg)
    assert off.data is d and off.gauss.num_gaussians == 5
    assert on.data.tracks.shape[0] == 4 + 16 and on.gauss.num_gaussians == 4 + 16
    assert int((~on.data.flow_valid).sum()) > 0 and d.flow_valid.all()


def test_chain_depth_holds_the_prior_at_the_chains_median_in_a_3px_disc():
    Tn, Hs, Ws = 6, 24, 32
    depth = np.full((Tn, Hs, Ws), 4.0)
    centres = np.full((2, Tn, 2), np.nan)  # the second chain has no blob at all
    centres[0, :5] = [[10.5 + 2 * t, 12.5] for t in range(5)]  # no blob at frame 5
    # the 29 pixels whose centre is within 3 px of a pixel centre (boundary included), by hand:
    # dx = 0: dy -3..3 (7); |dx| = 1, 2: dy -2..2 (4 x 5); |dx| = 3: dy = 0 (2)
    offsets = [(dx, dy) for dx in range(-3, 4) for dy in range(-3, 4) if dx * dx + dy * dy <= 9]
    assert len(offsets) == 29
    mover = [2.0, 2.2, 6.0, 1.8, 2.3]  # the prior jumps at frame 2 (what lies behind the mover)
    for t, v in enumerate(mover):
        for dx, dy in offsets:
            depth[t, 12 + dy, 10 + 2 * t + dx] = v
    depth[0, 12, 10] = 100.0  # one outlier: frame 0's median is still 2.0
    depth[3, 12, 16] = 0.0  # an invalid pixel: left out of the median, and left invalid
    before = depth.copy()
    out = chain_depth(depth, centres)
    assert np.array_equal(depth, before)  # the input is left alone
    held = 2.2  # the median of the per-frame medians 2.0, 2.2, 6.0, 1.8, 2.3
    for t in range(5):
        ring = [(12 + dy, 10 + 2 * t + dx) for dx, dy in offsets]
        vals = np.array([out[t, y, x] for y, x in ring])
        if t == 3:
            assert out[3, 12, 16] == 0.0
            vals = vals[vals > 0]
            assert vals.size == 28
        assert np.allclose(vals, held)
        changed = out[t] != before[t]
        # frame 1 is at the median already; frame 3 has one invalid pixel
        assert changed.sum() == {1: 0, 3: 28}.get(t, 29) and not changed[12, 10 + 2 * t + 4]
        assert not changed[12 + 3, 10 + 2 * t + 2]  # dx = 2, dy = 3: 13 > 9, outside
    assert np.array_equal(out[5], before[5])  # the frame the chain misses
    assert np.array_equal(chain_depth(depth, centres[1:]), before)


def _jumping_depth():
    """The disc clip's training data, its depth prior 4.0 on the plane and 2.0 on the disc but 6.0
    at frames 2, 3 and 7 (a prior that jumps with what lies behind the mover), and the disc's
    centres [T, 2]."""
    video = _video([(20.0, 30.0, 5.0, 1.0, 5.0, 3.0)])
    truth = np.array([[20.0 + 5.0 * t, 30.0 + 1.0 * t] for t in range(T)])
    prior = torch.from_numpy(np.concatenate([truth[None], truth[None] + 20.0]).astype(np.float32))
    d = _training_data(video, prior)
    d.depth[:] = 4.0
    for t in range(T):
        d.depth[t][torch.from_numpy(_disc(*truth[t], 5.0))] = 6.0 if t in (2, 3, 7) else 2.0
    return d, truth


def test_the_depth_option_holds_stage_1s_and_stage_2s_prior_and_nothing_else():
    from m4dgs.training.data import depth_data, stage1_data

    d, truth = _jumping_depth()
    clip_depth = d.depth.clone()

    assert depth_data(d, VideoInitConfig(highlight_motion=True)) is d  # off: the clip's prior
    assert stage1_data(d, VideoInitConfig(highlight_tracks=True))[0] is d

    s1, chain = stage1_data(d, VideoInitConfig(highlight_depth=True, highlight_points=4))
    s2 = depth_data(d, VideoInitConfig(highlight_depth=True, highlight_points=4))
    assert torch.equal(d.depth, clip_depth)  # the clip's prior is left alone
    assert s1.tracks is d.tracks and not chain.any()  # the motion priors are the clip's
    assert torch.equal(s1.depth, s2.depth)
    for t in range(T):
        near = torch.from_numpy(_disc(*truth[t], 2.5))  # within the hold, whatever the centroid
        assert torch.all(s1.depth[t][near] == 2.0)
        far = torch.from_numpy(~_disc(*truth[t], 3.5))
        assert torch.equal(s1.depth[t][far], clip_depth[t][far])
    # with the motion option too: the same held prior, and the chain's tracks as before
    both, chain = stage1_data(
        d, VideoInitConfig(highlight_motion=True, highlight_depth=True, highlight_points=4)
    )
    assert torch.equal(both.depth, s1.depth) and chain.sum() == 4


def test_stage_2_trains_on_the_held_depth():
    """WorldStage (m4dgs.training.stage2) with `stage1.init.highlight_depth` reads the held prior
    (its depth term and scene extent), the clip's without it."""
    from m4dgs.core.camera import K_from_fov
    from m4dgs.model.gaussians import WorldGaussians
    from m4dgs.training.config import apply_overrides, preset
    from m4dgs.training.data import depth_data
    from m4dgs.training.stage1 import build_appearance
    from m4dgs.training.stage2 import WorldInit, WorldStage

    d, _ = _jumping_depth()
    cfg = preset("tiny")
    cfg.width, cfg.height = W, H
    F = cfg.model.feature_dim
    one = {"quats": torch.tensor([[1.0, 0, 0, 0]]), "scales": torch.full((1, 3), -3.0)}
    static = {**one, "means": torch.tensor([[0.0, 0, 3]]), "opacities": torch.zeros(1)}
    knots = torch.tensor([0.0, 4.0, 8.0, T - 1.0])
    dynamic = {
        "ctrl": torch.tensor([0.0, 0, 3]).expand(1, 4, 3).clone(),
        "rot": torch.tensor([[1.0, 0, 0, 0]] + [[0.0, 0, 0, 0]] * 3)[None],
        "scales": one["scales"],
        "opacities": torch.zeros(1),
    }
    static["features"] = dynamic["features"] = torch.zeros(1, F)

    def stage(c):
        g = WorldGaussians(static, dynamic, knots, T, c.model.world_scale_activation, 0.05)
        init = WorldInit(
            g,
            *build_appearance(c, 1.0, "cpu", pretrain=False),
            torch.as_tensor(K_from_fov(W, H, 60.0)).float(),
            torch.eye(4).expand(T, 4, 4).clone(),
            torch.ones(T),
        )
        return WorldStage(d, c, init)

    on = apply_overrides(cfg, {"stage1.init.highlight_depth": True})
    assert stage(cfg).data.depth is d.depth
    held = stage(on).data.depth
    assert torch.equal(held, depth_data(d, on.stage1.init).depth)
    assert not torch.equal(held, d.depth)
