"""bench/v2w_lift.py: its pinhole projection against analytic pixels and against m4dgs' own camera
functions, and its report on a short tiny-preset run (the world Gaussians of model/v2w.pt
reprojected where the stage-1 video Gaussians were, up to the V2W spline fit)."""

from __future__ import annotations

import json

import numpy as np
import torch

from m4dgs.core.camera import invert_rigid, project_pinhole


def test_pinhole_pixels_analytic(load_bench):
    vl = load_bench("v2w_lift")
    K = np.array([[100.0, 0, 40], [0, 120.0, 30], [0, 0, 1]])
    c2w = np.stack([np.eye(4), np.eye(4)])
    c2w[1, :3, 3] = [1.0, 0, 0]  # the second camera 1 unit to the right
    p = np.array(
        [[[0.0, 0, 2], [0.0, 0, 2]], [[1.0, 0.6, 2], [0.0, 0, -1]]]
    )  # [2 points, 2 frames]
    uv = vl.pinhole_pixels(p, K, c2w)
    np.testing.assert_allclose(uv[0, 0], [40, 30])
    np.testing.assert_allclose(uv[0, 1], [40 - 100 / 2, 30])  # seen from x = 1
    np.testing.assert_allclose(uv[1, 0], [40 + 100 / 2, 30 + 120 * 0.3])
    assert np.isnan(uv[1, 1]).all()  # behind the camera


def test_pinhole_pixels_match_m4dgs_cameras(load_bench):
    vl = load_bench("v2w_lift")
    rng = np.random.default_rng(1)
    T = 5
    c2w = np.stack([np.eye(4)] * T)
    for t in range(T):
        a = 0.1 * t
        c2w[t, :3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
        c2w[t, :3, 3] = rng.normal(0, 0.2, 3)
    K = np.array([[200.0, 0, 64], [0, 200.0, 48], [0, 0, 1]])
    p = rng.normal(0, 0.5, (7, T, 3)) + [0, 0, 4]
    w2c = invert_rigid(torch.from_numpy(c2w))
    cam = torch.einsum("tij,ntj->nti", w2c[:, :3, :3], torch.from_numpy(p)) + w2c[None, :, :3, 3]
    ref = project_pinhole(cam, torch.from_numpy(K)).numpy()
    np.testing.assert_allclose(vl.pinhole_pixels(p, K, c2w), ref, rtol=1e-9, atol=1e-9)


def test_report_on_a_short_run(
    tiny_clip_realistic, short_run_realistic, tmp_path, load_bench, capsys
):
    vl = load_bench("v2w_lift")
    run = short_run_realistic
    rep = vl.lift_report(run, tiny_clip_realistic)
    assert 0 <= rep["followers"] <= rep["dynamic"]
    assert rep["dynamic"] > 0 and rep["dynamic_px"]["median"] >= 0
    assert rep["dynamic_px"]["q25"] <= rep["dynamic_px"]["median"] <= rep["dynamic_px"]["p90"]
    out = tmp_path / "lift.json"
    assert vl.main([str(run), str(tiny_clip_realistic), "--json", str(out)]) == 0
    assert "followers of the movers" in capsys.readouterr().out
    assert json.loads(out.read_text())["dynamic"] == rep["dynamic"]
