"""The ground-truth comparison against the clip's own files (the generator's gt/ldr images), and
the clip viewer's image of a frame with each prior drawn over it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from m4dgs.clip import Clip
from m4dgs.viewer.cameras import named_cameras
from m4dgs.viewer.clipview import OVERLAYS, clip_frame, track_colour, track_stride
from m4dgs.viewer.frame import view_frame
from m4dgs.viewer.truth import comparison, error_map, has_truth, mean_abs_error, truth_ldr


def test_truth_at_a_test_camera_is_the_clips_ldr_file(viewer_model):
    clip = viewer_model.clip
    cams = named_cameras(viewer_model)
    test = next(c for c in cams if c.kind == "test")
    for lv in list(clip.meta.exposures.observed) + list(clip.meta.exposures.novel):
        gt = truth_ldr(clip, test, math.log2(lv))
        assert np.array_equal(gt, clip.load_gt_ldr(lv, test.g))
    view = next(c for c in cams if c.kind == "view")
    lv = clip.meta.exposures.observed[0]
    assert has_truth(clip, view)
    assert np.array_equal(
        truth_ldr(clip, view, math.log2(lv)), clip.load_view_ldr(view.view, lv, view.g)
    )


def test_comparison_places_render_truth_and_error_side_by_side(viewer_model):
    clip = viewer_model.clip
    train = named_cameras(viewer_model)[0]
    ev = math.log2(clip.meta.train_dt_of(train.g))
    r = view_frame(viewer_model, train.camera, train.g, ev, "ldr")
    gt = truth_ldr(clip, train, ev)
    img = comparison(r, gt)
    W = clip.width
    assert img.shape == (clip.height, 3 * W + 4, 3)
    assert np.array_equal(img[:, :W], r) and np.array_equal(img[:, W + 2 : 2 * W + 2], gt)
    assert np.array_equal(img[:, 2 * W + 4 :], error_map(r, gt))
    # the error map is blue where equal and reaches red at ERROR_RANGE codes
    same = error_map(gt, gt)
    assert (same[..., 2] > same[..., 0]).all()
    assert mean_abs_error(r, gt) == pytest.approx(np.abs(r.astype(float) - gt).mean())
    with pytest.raises(ValueError, match="differ"):
        comparison(r[:, 1:], gt)


def test_clip_frame_overlays(tiny_clip_oracle):
    clip = Clip.open(tiny_clip_oracle)
    g = clip.train_frames[1]
    H, W = clip.height, clip.width
    plain = clip_frame(clip, g, "none", truth=False)
    assert np.array_equal(plain, clip.load_ldr(g))
    imgs = {o: clip_frame(clip, g, o, truth=False) for o in OVERLAYS}
    for o in ("depth", "tracks", "flow"):
        assert imgs[o].shape == (H, W, 3) and not np.array_equal(imgs[o], plain), o
    # every visible prior track of frame g has a dot at its position
    ts = clip.load_tracks_prior()
    i = clip.train_frames.index(g)
    k = track_stride(ts.tracks.shape[0], clip)
    drawn = [n for n in range(0, ts.tracks.shape[0], k) if ts.visible[n, i]]
    assert k > 1 and drawn  # the dense oracle tracks are thinned on a 72x40 frame

    def colour(n):
        return tuple(int(v) for v in np.round(np.array(track_colour(n)) * 255))

    palette = {colour(n) for n in drawn}
    inside = [
        (n, int(np.floor(ts.tracks[n, i, 0])), int(np.floor(ts.tracks[n, i, 1])))
        for n in drawn
        if 0 <= ts.tracks[n, i, 0] < W and 0 <= ts.tracks[n, i, 1] < H
    ]
    assert inside
    # every drawn track's position is painted in a drawn track's colour (tails may cross it)
    assert all(tuple(int(v) for v in imgs["tracks"][y, x]) in palette for _, x, y in inside)
    top = inside[-1]  # the last track drawn is on top
    assert tuple(int(v) for v in imgs["tracks"][top[2], top[1]]) == colour(top[0])
    # and nothing else changed: every changed pixel holds a drawn track's colour
    changed = (imgs["tracks"] != plain).any(-1)
    assert {tuple(int(v) for v in px) for px in imgs["tracks"][changed]} <= palette
    # with the truth beside: [frame | gap | true LDR at the frame's own exposure]
    both = clip_frame(clip, g, "none", truth=True)
    assert both.shape == (H, 2 * W + 2, 3) and np.array_equal(both[:, :W], plain)
    gt = both[:, W + 2 :].astype(int)
    assert np.abs(gt - plain.astype(int)).mean() < 3  # oracle input = CRF(truth) in 8 bits
    # a test frame has no input: its truth alone
    t = clip.test_frames[0]
    assert clip_frame(clip, t, "tracks").shape == (H, W, 3)
    with pytest.raises(ValueError, match="unknown overlay"):
        clip_frame(clip, g, "nope")


def test_clip_viewer_serves_on_loopback(tiny_clip_oracle, free_port):
    pytest.importorskip("viser", reason="the viewer extra (viser) is not installed")
    import urllib.request

    from m4dgs.viewer.server import open_target

    v = open_target(tiny_clip_oracle, port=free_port)
    try:
        assert v.port == free_port and v.server.get_host() == "127.0.0.1"
        with urllib.request.urlopen(f"http://127.0.0.1:{free_port}/", timeout=10) as r:
            assert r.status == 200
        v.gui_overlay.value = "tracks"
        v.gui_frame.value = 3
        v.update()
        assert "00003" in v.gui_info.content and "test frame" in v.gui_info.content
    finally:
        v.stop()


@pytest.mark.parametrize("canvas", [(1000, 600), (400, 900), (72, 40), (50, 20)])
def test_letterbox_keeps_the_pixels_and_fits_the_window_shape(canvas):
    from m4dgs.viewer.clipview import LETTERBOX_GREY, letterbox

    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (40, 146, 3), dtype=np.uint8)
    out = letterbox(img, *canvas)
    H, W = out.shape[:2]
    assert abs(W / H - canvas[0] / canvas[1]) < 2.0 / min(H, W) + 1e-9  # the window's shape
    k = max(1, min(canvas[0] // 146, canvas[1] // 40))
    assert H >= 40 * k and W >= 146 * k
    y0, x0 = (H - 40 * k) // 2, (W - 146 * k) // 2
    inner = out[y0 : y0 + 40 * k, x0 : x0 + 146 * k]
    assert np.array_equal(inner[::k, ::k], img)  # whole-pixel enlargement, nothing resampled
    border = out.copy()
    border[y0 : y0 + 40 * k, x0 : x0 + 146 * k] = LETTERBOX_GREY
    assert (border == LETTERBOX_GREY).all()
