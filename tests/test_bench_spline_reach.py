"""bench/spline_reach.py: the least-squares fit of the trainer's position spline to point tracks.

Against answers known without the script: a straight path is followed exactly at every interval,
also across a stretch where the track is hidden; a path that is itself a spline with a control point
every 2 frames is followed exactly at N_s = 2 and not at N_s = 8; on a clip, the figures of a track
drawn here (speed, counts) come back."""

from __future__ import annotations

import json

import numpy as np
import torch

from m4dgs.core import spline
from m4dgs.core.io import write_npz


def _mid(xy):
    """[N, T, 2] -> positions halfway between consecutive frames, [N, T - 1, 2] (straight paths)."""
    return 0.5 * (xy[:, 1:] + xy[:, :-1])


def test_straight_paths_are_followed_at_every_interval(load_bench):
    sr = load_bench("spline_reach")
    t = np.arange(25, dtype=np.float64)
    xy = np.stack(
        [np.stack([10 + 3.0 * t, 40 - 1.5 * t], -1), np.stack([5 + 0 * t, 7 + 0.5 * t], -1)]
    )
    vis = np.ones((2, 25), bool)
    vis[1, 8:15] = False  # hidden for a while: its control points there are decided by no frame
    for every in (1, 2, 4, 8):
        fit, between = sr.track_residuals(xy, vis, _mid(xy), np.ones((2, 24), bool), every)
        assert np.all(fit < 1e-6), (every, fit)
        # the test frames next to the hidden stretch included (no least-norm pull towards pixel 0)
        assert np.all(between < 1e-3), (every, between)


def test_a_spline_path_is_followed_at_its_own_interval_only(load_bench):
    sr = load_bench("spline_reach")
    T = 33
    knots = spline.make_knots(T, 2, dtype=torch.float64)
    rng = np.random.default_rng(0)
    ctrl = torch.from_numpy(rng.uniform(0, 100, (1, knots.numel(), 2)))
    xy = spline.evaluate(ctrl, knots, torch.arange(T, dtype=torch.float64)).numpy()  # [1, T, 2]
    mid = spline.evaluate(ctrl, knots, torch.arange(T - 1, dtype=torch.float64) + 0.5).numpy()
    vis, tvis = np.ones((1, T), bool), np.ones((1, T - 1), bool)
    fit2, between2 = sr.track_residuals(xy, vis, mid, tvis, 2)
    assert fit2[0] < 1e-3 and between2[0] < 1e-3
    fit8, between8 = sr.track_residuals(xy, vis, mid, tvis, 8)
    assert fit8[0] > 5.0 and between8[0] > 5.0  # control points drawn 0-100 px apart every 2 frames


def test_report_on_a_clip(tmp_path, load_bench, capsys):
    smb = load_bench("small_mover_bench")
    sr = load_bench("spline_reach")
    clip = smb.make_disc_clip(tmp_path / "disc")  # 24 frames, the even ones for training
    G = json.loads((tmp_path / "disc" / "disc.json").read_text())["frames"]
    g = np.arange(G, dtype=np.float64)
    moving = np.stack([20 + 2.5 * g, 30 + 0 * g], -1)  # 5 px a training frame
    still = np.stack([100 + 0 * g, 50 + 0 * g], -1)
    write_npz(
        clip / "gt" / "tracks.npz",
        tracks=np.stack([moving, still]).astype(np.float32),
        visible=np.ones((2, G), bool),
        frames=np.arange(G, dtype=np.int64),
        dynamic=np.array([True, False]),
    )
    rep = sr.reach_report(clip, every=(2, 4))
    assert rep["train_frames"] == 12 and rep["moving_tracks"] == 1 and rep["fitted_tracks"] == 1
    assert abs(rep["speed_px_per_train_frame"] - 5.0) < 1e-4
    assert rep["every"]["4"]["fit_median_px"] < 1e-3
    assert sr.main([str(clip), "--every", "4", "--json", str(tmp_path / "r.json")]) == 0
    assert "1 of 1 moving tracks fitted, median speed 5.00 px" in capsys.readouterr().out
    assert (
        json.loads((tmp_path / "r.json").read_text())[0]["every"]["4"]["between_median_px"] < 1e-3
    )
