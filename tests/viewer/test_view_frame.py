"""The viewer's images against what `m4dgs render` wrote for the same camera, time and exposure
(the trainer renders every training and test frame into the run folder), and its camera helpers
against the project's own quaternion code."""

from __future__ import annotations

import math

import numpy as np
import pytest

from m4dgs.clip import frame_name, level_name
from m4dgs.core.camera import quat_to_rotmat
from m4dgs.core.hdr import mu_law
from m4dgs.core.io import read_exr, read_png
from m4dgs.viewer.cameras import (
    ViewCamera,
    from_browser,
    matrix_to_quat,
    named_cameras,
    quat_to_matrix,
    to_browser,
)
from m4dgs.viewer.frame import MODES, view_frame


def test_quaternions_match_the_project_convention_and_round_trip():
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        R = quat_to_matrix(q)
        np.testing.assert_allclose(R, np.asarray(quat_to_rotmat(q)), atol=1e-6)
        q2 = matrix_to_quat(R)
        assert q2[0] >= 0
        np.testing.assert_allclose(np.abs(q2 @ q), 1.0, atol=1e-9)  # same rotation, up to sign


def test_browser_camera_round_trip_and_resize():
    c2w = np.eye(4)
    c2w[:3, :3] = quat_to_matrix([0.9, 0.1, -0.3, 0.2])
    c2w[:3, 3] = [0.5, -1.0, 2.0]
    K = np.array([[50.0, 0, 36.0], [0, 50.0, 20.0], [0, 0, 1]])
    cam = ViewCamera(K, c2w, 72, 40)
    wxyz, pos, fov = to_browser(cam)
    assert fov == pytest.approx(2 * math.atan(20 / 50))
    back = from_browser(wxyz, pos, fov, 72, 40)
    np.testing.assert_allclose(back.c2w, c2w, atol=1e-9)
    np.testing.assert_allclose(back.K, K, atol=1e-9)
    half = cam.resized(36, 20)
    # a pixel centre maps to the same ray: u = fx x + cx scales with the width
    np.testing.assert_allclose(half.K[:2], K[:2] / 2)
    assert (half.width, half.height) == (36, 20)


def test_ldr_equals_the_render_command_output(viewer_run, viewer_model):
    """A training camera at its frame and input exposure gives renders/train/ldr/<g>.png, a test
    camera at each level renders/test/ldr/<level>/<g>.png (within 1 code), and the HDR modes
    follow renders/*/hdr/<g>.exr."""
    model, clip = viewer_model, viewer_model.clip
    cams = {(c.kind, c.g): c for c in named_cameras(model)}
    for g, dt in list(zip(clip.train_frames, clip.train_dt))[:3]:
        img = view_frame(model, cams["train", g].camera, g, math.log2(dt), "ldr")
        ref = read_png(viewer_run / "renders" / "train" / "ldr" / frame_name(g, "png"))
        assert img.shape == ref.shape == (clip.height, clip.width, 3) and img.dtype == np.uint8
        assert np.abs(img.astype(int) - ref.astype(int)).max() <= 1
        # and the exposure matters: two stops brighter is not the same picture
        brighter = view_frame(model, cams["train", g].camera, g, math.log2(dt) + 2, "ldr")
        assert brighter.astype(float).mean() > img.astype(float).mean() + 5
    g = clip.test_frames[0]
    for lv in list(clip.meta.exposures.observed) + list(clip.meta.exposures.novel):
        img = view_frame(model, cams["test", g].camera, g, math.log2(lv), "ldr")
        ref = read_png(
            viewer_run / "renders" / "test" / "ldr" / level_name(lv) / frame_name(g, "png")
        )
        assert np.abs(img.astype(int) - ref.astype(int)).max() <= 1
    hdr = read_exr(viewer_run / "renders" / "test" / "hdr" / frame_name(g, "exr")).astype(
        np.float64
    )
    mu = view_frame(model, cams["test", g].camera, g, 1.0, "hdr-mulaw")
    ref = np.round(mu_law(hdr * 2.0) * 255)
    assert np.abs(mu.astype(int) - ref).max() <= 1


def test_every_mode_gives_an_image_of_the_camera_size(viewer_model):
    model = viewer_model
    cam = named_cameras(model)[0].camera.resized(48, 30)
    imgs = {m: view_frame(model, cam, 1.5, 0.0, m) for m in MODES}
    for m, img in imgs.items():
        assert img.shape == (30, 48, 3) and img.dtype == np.uint8, m
        assert img.max() > 0, f"{m}: black image"
    # the modes are different pictures
    assert not np.array_equal(imgs["ldr"], imgs["hdr-mulaw"])
    assert not np.array_equal(imgs["depth"], imgs["hdr-false"])
    # the split mode marks dynamic Gaussians orange (red > blue) and static ones blue
    dyn = model.gauss.num_dynamic > 0
    split = imgs["dynamic"].astype(int)
    assert ((split[..., 0] - split[..., 2]) > 40).any() == dyn
    with pytest.raises(ValueError, match="unknown view mode"):
        view_frame(model, cam, 0.0, 0.0, "nope")


def test_held_out_views_are_named_cameras_at_test_frames(viewer_run, viewer_model):
    """A view camera renders what `m4dgs render` wrote under renders/views/<view>/."""
    clip = viewer_model.clip
    views = [c for c in named_cameras(viewer_model) if c.kind == "view"]
    assert clip.view_names() and len(views) == len(clip.view_names()) * len(clip.test_frames)
    c = views[0]
    lv = clip.meta.exposures.observed[0]
    img = view_frame(viewer_model, c.camera, c.g, math.log2(lv), "ldr")
    ref = read_png(
        viewer_run / "renders" / "views" / c.view / "ldr" / level_name(lv) / frame_name(c.g, "png")
    )
    assert np.abs(img.astype(int) - ref.astype(int)).max() <= 1


def test_a_gain_over_time_colours_the_centres_and_the_render(viewer_model):
    """Beyond the paper: a model whose Gaussians carry a gain of c stops at every knot shows its
    centres as the model without it shows them c stops brighter (the tone mapper reads log2 H +
    ev), and its LDR render differs from the plain one."""
    import copy

    import torch

    from m4dgs.model.gaussians import WorldGaussians

    c = 1.5
    state = viewer_model.gauss.to_state()
    for part, key in (("static", "means"), ("dynamic", "ctrl")):
        state[part]["log2_gain"] = torch.full((state[part][key].shape[0], 4), c)
    relit = copy.copy(viewer_model)
    relit.gauss = WorldGaussians.from_state(state)
    cam = named_cameras(viewer_model)[0].camera.resized(48, 30)
    got = view_frame(relit, cam, 1.5, -2.0, "centres").astype(int)
    want = view_frame(viewer_model, cam, 1.5, -2.0 + c, "centres").astype(int)
    assert np.abs(got - want).max() <= 1 and got.max() > 0
    assert not np.array_equal(got, view_frame(viewer_model, cam, 1.5, -2.0, "centres"))
    a = view_frame(relit, cam, 1.5, -2.0, "ldr").astype(int)
    b = view_frame(viewer_model, cam, 1.5, -2.0, "ldr").astype(int)
    assert np.abs(a - b).max() > 10
