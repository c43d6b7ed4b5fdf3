"""Tracks of bright blobs (m4dgs.priors.highlight_tracks) on videos drawn here, against the
movers' known positions; the initialisation keeps them under its cap; off, nothing changes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from m4dgs.model.gaussians import VideoInitConfig, init_video_gaussians
from m4dgs.priors.highlight_tracks import (
    Blob,
    brightest_blobs,
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
    from m4dgs.training.data import TrainingData, init_tracks

    video = _video([(20.0, 30.0, 5.0, 1.0, 5.0, 3.0)])
    prior = torch.rand(7, T, 2) * 50
    d = TrainingData(
        clip_name="x",
        frames=list(range(0, 2 * T, 2)),
        width=W,
        height=H,
        ldr=torch.from_numpy(video.astype(np.float32) / 255),
        log2_dt=torch.log2(torch.tensor(DTS)),
        depth=torch.ones(T, H, W),
        tracks=prior,
        track_vis=torch.ones(7, T, dtype=torch.bool),
        flow_pairs=[],
        flow=None,
        flow_valid=None,
        unit_exposure_value=1.0,
        num_levels=3,
    )
    tr, vi, always = init_tracks(d, VideoInitConfig(highlight_tracks=on, highlight_points=4))
    assert torch.equal(tr[:7], prior) and int((~always).sum()) == 7
    assert tr.shape[0] == (7 + 4 if on else 7) and int(always.sum()) == (4 if on else 0)


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
