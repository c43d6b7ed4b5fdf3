"""bench/highlight_interp_bound.py on frames drawn here: a surface sliding 2 px a frame with a glint
that peaks at the test frame; the three stand-ins' peak ratios against the values worked out by
hand, and a point with no track near it is not carried."""

from __future__ import annotations

import numpy as np

H = W = 20


def _grid_tracks(dx):
    """Tracks at every pixel centre of frame a, moved by (dx, 0) at frame b."""
    y, x = np.mgrid[0:H, 0:W] + 0.5
    a = np.stack([x.ravel(), y.ravel()], axis=1)
    return a, a + np.array([dx, 0.0])


def test_the_stand_ins_read_the_neighbours_at_the_carried_surface_point(load_bench):
    hb = load_bench("highlight_interp_bound")
    test = np.full((H, W), 0.1)
    test[10, 10] = 8.0  # the glint's peak, at the test frame
    mask = np.zeros((H, W), bool)
    mask[10, 10] = True
    before, after = np.full((H, W), 0.1), np.full((H, W), 0.1)
    # the surface moves +2 px in x a frame: the glint's point is 2 px left before, 2 right after
    before[10, 8], after[10, 12] = 4.0, 2.0
    before[10, 10] = 0.5  # what a copy of the frame before shows at the glint's pixel
    pts = np.array([[10.5, 10.5]])
    nbs = []
    for lum, dx in ((before, -2.0), (after, 2.0)):
        ta, tb = _grid_tracks(dx)
        q = hb.carry_points(pts, ta, tb)
        assert np.allclose(q, pts + [dx, 0.0])
        nbs.append((lum, q))
    r = hb.frame_bound(test, mask, nbs)
    assert np.isclose(r["max"], 4.0 / 8.0)
    assert np.isclose(r["mean"], 3.0 / 8.0)
    assert np.isclose(r["same_pixel"], 0.5 / 8.0)


def test_a_point_far_from_every_track_is_not_carried(load_bench):
    hb = load_bench("highlight_interp_bound")
    ta = np.array([[1.5, 1.5], [2.5, 1.5]])
    q = hb.carry_points(np.array([[1.5, 2.5], [15.5, 15.5]]), ta, ta + 3.0, k=2, near_px=2.0)
    assert np.allclose(q[0], [4.5, 5.5]) and np.isnan(q[1]).all()
    none = np.zeros((0, 2))
    assert np.isnan(hb.carry_points(np.array([[1.0, 1.0]]), none, none)).all()
    # a stand-in reads 0 where its point is not carried
    lum = np.ones((H, W))
    r = hb.frame_bound(lum, lum > 0, [(lum, np.full((H * W, 2), np.nan))])
    assert r["max"] == 0.0 and r["same_pixel"] == 1.0
    assert np.isclose(hb.peak_geomean([0.5, 2.0]), 1.0)  # the scorer's mean over frames


def test_a_clip_without_ground_truth_is_named(load_bench, tmp_path, capsys):
    hb = load_bench("highlight_interp_bound")
    assert hb.main([str(tmp_path / "missing")]) == 2
    assert "missing" in capsys.readouterr().err
