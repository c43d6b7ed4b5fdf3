"""The viewer's controls without a browser: play advances whole frames at the chosen rate and
wraps, Previous / Next walk the named cameras and move the time to theirs, the ground-truth panel
follows the selection and the exposure, the 3D centres follow the time."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("viser", reason="the viewer extra (viser) is not installed")


@pytest.fixture
def viewer(viewer_model, free_port):
    from m4dgs.viewer.server import Viewer

    v = Viewer(viewer_model, port=free_port)
    yield v
    v.stop()


def test_play_steps_whole_frames_and_wraps(viewer):
    G = viewer.clip.meta.num_frames
    viewer.gui_time.value = G - 2.5
    viewer.gui_fps.value = 20.0
    seen = []
    viewer._toggle_play()
    assert viewer.gui_play.label == "Pause"
    end = time.time() + 5
    while time.time() < end and len(set(seen)) < 3:
        seen.append(float(viewer.gui_time.value))
        time.sleep(0.01)
    viewer._toggle_play()
    assert viewer.gui_play.label == "Play"
    steps = list(dict.fromkeys(seen))
    # from G - 2.5: the next whole frame G - 2, then G - 1, then back to 0
    assert steps[:3] == [G - 2.5, G - 2.0, G - 1.0] or steps[1:4] == [G - 2.0, G - 1.0, 0.0]
    t = float(viewer.gui_time.value)
    time.sleep(0.3)
    assert float(viewer.gui_time.value) == t  # paused


def test_next_and_previous_walk_the_cameras(viewer):
    cams = viewer.cameras
    assert viewer.selected is cams[0]
    viewer._step_camera(1, None)
    assert viewer.selected is cams[1] and viewer.gui_camera.value == cams[1].label
    assert float(viewer.gui_time.value) == cams[1].g
    viewer._step_camera(-1, None)
    viewer._step_camera(-1, None)  # wraps to the last (a held-out view of the tiny clip)
    assert viewer.selected is cams[-1] and cams[-1].kind == "view"
    assert float(viewer.gui_time.value) == cams[-1].g


def test_truth_panel_follows_selection_and_exposure(viewer):
    assert viewer.gui_compare is not None
    viewer.gui_compare.value = True
    text0 = viewer.gui_truth_text.content
    assert viewer.selected.label in text0 and "mean |error|" in text0
    viewer.gui_ev.value = float(viewer.gui_ev.value) + 2.0
    assert viewer.gui_truth_text.content != text0 and "EV" in viewer.gui_truth_text.content
    img, err = viewer.truth_image()
    W = viewer.clip.width
    assert img.shape == (viewer.clip.height, 3 * W + 4, 3) and err >= 0


def test_centres_follow_the_time(viewer, viewer_model):
    viewer.gui_centres.value = True
    p0 = np.array(viewer._centres.points)
    assert p0.shape == (viewer_model.num_gaussians, 3)
    viewer.gui_time.value = float(viewer.clip.meta.num_frames - 1)
    p1 = np.array(viewer._centres.points)
    want = viewer_model.gauss.positions(viewer_model.time_of(viewer.gui_time.value))
    # viser keeps the points in float16
    np.testing.assert_allclose(p1, want.detach().cpu().numpy(), rtol=2e-3, atol=1e-3)
    if viewer_model.gauss.num_dynamic:
        assert not np.allclose(p0, p1)
    viewer.gui_centres.value = False
    assert viewer._centres is None


def test_centres_take_the_colour_at_the_time(viewer_model, free_port):
    """Beyond the paper: with a gain over time the centres' colours follow the time too (a gain
    from -3 to +3 stops over the frames, the model's own colours at each time)."""
    import copy

    import torch

    from m4dgs.model.gaussians import WorldGaussians
    from m4dgs.model.render import gaussian_colors
    from m4dgs.viewer.server import Viewer

    state = viewer_model.gauss.to_state()
    for part, key in (("static", "means"), ("dynamic", "ctrl")):
        n = state[part][key].shape[0]
        state[part]["log2_gain"] = torch.tensor([-3.0, 3.0]).expand(n, 2).clone()
    relit = copy.copy(viewer_model)
    relit.gauss = WorldGaussians.from_state(state)
    v = Viewer(relit, port=free_port)
    try:
        v.gui_centres.value = True
        cols = {}
        for g in (0.0, float(v.clip.meta.num_frames - 1)):
            v.gui_time.value = g
            cols[g] = np.array(v._centres.colors).astype(int)
            with torch.no_grad():
                t = relit.time_of(g)
                hdr = gaussian_colors(relit.gauss, relit.color, t)
                ev = torch.tensor(float(v.gui_ev.value))
                want = np.round(relit.tm(hdr, ev).clamp(0, 1).numpy() * 255).astype(int)
            assert np.abs(cols[g] - want).max() <= 1, g
        first, last = cols.values()
        assert last.mean() > first.mean() + 20
    finally:
        v.stop()
