"""The brightness gain over time (beyond the paper, ModelConfig.appearance_knots): its curve against
hand computations and finite differences, the containers with and without it, and renders with it
against the rasterizer fed colours scaled by hand (values and gradients)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from m4dgs.core import rotation, spline
from m4dgs.core.camera import K_from_fov
from m4dgs.model.background import Background
from m4dgs.model.color import ColorMLP, view_directions
from m4dgs.model.gaussians import (
    GAIN_KEY,
    ModelConfig,
    VideoGaussians,
    VideoInitConfig,
    WorldGaussians,
    evaluate_log2_gain,
    gain_knots,
    gain_second_differences,
    init_video_gaussians,
)
from m4dgs.model.render import gaussian_colors, render_gaussians
from m4dgs.raster import render


def _hand_curve(values, num_frames: int, t: float) -> float:
    """One Gaussian's log2 gain at time t written out: knots spread evenly over 0..T-1,
    Catmull-Rom tangents (one-sided at the ends), Hermite basis, times clamped to the knots."""
    v = [float(x) for x in values]
    k = len(v)
    if k == 1:
        return v[0]
    h = (num_frames - 1) / (k - 1)
    tk = [i * h for i in range(k)]
    t = min(max(t, 0.0), tk[-1])
    slope = [(v[i + 1] - v[i]) / h for i in range(k - 1)]
    m = [slope[0]] + [0.5 * (slope[i - 1] + slope[i]) for i in range(1, k - 1)] + [slope[-1]]
    i = min(int(t // h), k - 2)
    s = (t - tk[i]) / h
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * v[i] + h10 * h * m[i] + h01 * v[i + 1] + h11 * h * m[i + 1]


def test_knots_spread_evenly_over_the_training_frames():
    assert gain_knots(9, 3).tolist() == [0.0, 4.0, 8.0]
    torch.testing.assert_close(gain_knots(50, 8), torch.arange(8.0) * 7.0)
    assert gain_knots(10, 1).tolist() == [0.0]
    assert gain_knots(1, 3).tolist() == [0.0, 0.5, 1.0]  # one frame: distinct knots all the same
    with pytest.raises(ValueError):
        gain_knots(10, 0)


def test_curve_against_hand_computed_values():
    # three knots at frames 0, 4, 8 (T = 9) with values 0, 1, 3 stops: tangents 0.25, 0.375, 0.5
    # a stop a frame; at t = 2 (s = 1/2 of [0, 4]): 0.125 * 4 * 0.25 + 0.5 * 1 - 0.125 * 4 * 0.375
    # = 0.4375; at t = 6: 0.5 + 0.1875 + 1.5 - 0.25 = 1.9375
    values = torch.tensor([[0.0, 1.0, 3.0]], dtype=torch.float64)
    knots = gain_knots(9, 3, dtype=torch.float64)
    cases = {0.0: 0.0, 2.0: 0.4375, 4.0: 1.0, 6.0: 1.9375, 8.0: 3.0, -1.0: 0.0, 11.5: 3.0}
    for t, want in cases.items():
        assert evaluate_log2_gain(values, knots, t).item() == pytest.approx(want, abs=1e-12), t
    # two knots: a straight line; one knot: a constant
    two = torch.tensor([[1.0, -1.0]], dtype=torch.float64)
    assert evaluate_log2_gain(two, gain_knots(6, 2, dtype=torch.float64), 2.5).item() == (
        pytest.approx(0.0, abs=1e-12)
    )
    one = torch.tensor([[0.7]], dtype=torch.float64)
    assert evaluate_log2_gain(one, gain_knots(6, 1, dtype=torch.float64), 3.2).item() == 0.7
    # random curves at fractional times against the written-out formula; shapes
    g = torch.Generator().manual_seed(0)
    values = torch.randn(4, 6, generator=g, dtype=torch.float64)
    knots = gain_knots(23, 6, dtype=torch.float64)
    times = [0.0, 0.5, 3.3, 4.4, 10.0, 13.75, 21.9, 22.0]
    got = evaluate_log2_gain(values, knots, times)
    assert got.shape == (4, len(times), 1)
    want = [[_hand_curve(v, 23, t) for t in times] for v in values.tolist()]
    np.testing.assert_allclose(got[..., 0].numpy(), want, atol=1e-12)
    assert evaluate_log2_gain(values, knots, 3.3).shape == (4, 1)


def test_curve_gradient_matches_finite_differences():
    g = torch.Generator().manual_seed(1)
    values = torch.randn(3, 5, generator=g, dtype=torch.float64, requires_grad=True)
    knots = gain_knots(17, 5, dtype=torch.float64)
    times = [0.0, 1.3, 7.5, 12.25, 16.0]
    assert torch.autograd.gradcheck(lambda v: evaluate_log2_gain(v, knots, times), (values,))
    # the colour factor 2 ** g too
    assert torch.autograd.gradcheck(
        lambda v: torch.exp2(evaluate_log2_gain(v, knots, 5.6)), (values,)
    )
    # and the curvature penalty's differences are the plain second differences
    d2 = gain_second_differences(values.detach())
    v = values.detach()
    torch.testing.assert_close(d2[:, 1], v[:, 3] - 2 * v[:, 2] + v[:, 1])
    assert gain_second_differences(v[:, :2]).shape == (3, 0)


def _video(n=6, t_count=9, gain=None, seed=4):
    g = torch.Generator().manual_seed(seed)
    knots = spline.make_knots(t_count, 4)
    return VideoGaussians(
        torch.randn(n, knots.numel(), 3, generator=g),
        torch.randn(n, 4, 4, generator=g),
        torch.zeros(n, 3),
        torch.zeros(n),
        torch.randn(n, 36, generator=g),
        knots,
        t_count,
        log2_gain=gain,
    )


def _world(ns=4, nd=3, t_count=9, gain_k=0, seed=5):
    g = torch.Generator().manual_seed(seed)
    knots = spline.make_knots(t_count, 4)
    static = {
        "means": torch.cat([torch.randn(ns, 2, generator=g) * 0.5, torch.full((ns, 1), 3.0)], 1),
        "quats": torch.randn(ns, 4, generator=g),
        "scales": torch.full((ns, 3), math.log(0.3)),
        "opacities": torch.full((ns,), 1.0),
        "features": torch.randn(ns, 36, generator=g),
    }
    ctrl = torch.randn(nd, knots.numel(), 3, generator=g) * 0.3
    ctrl[..., 2] += 3.5
    dynamic = {
        "ctrl": ctrl,
        "rot": rotation.init_rotation_coeffs(nd),
        "scales": torch.full((nd, 3), math.log(0.25)),
        "opacities": torch.full((nd,), 1.0),
        "features": torch.randn(nd, 36, generator=g),
    }
    if gain_k:
        static[GAIN_KEY] = torch.randn(ns, gain_k, generator=g)
        dynamic[GAIN_KEY] = torch.randn(nd, gain_k, generator=g)
    return WorldGaussians(static, dynamic, knots, t_count, "exp", 1.0)


def test_without_the_option_the_containers_hold_the_paper_parameters():
    vg = _video()
    assert set(vg.params) == {"ctrl", "rot", "scales", "opacities", "features"}
    assert set(vg.state_dict()) == {f"params.{k}" for k in vg.params} | {"knots"}
    assert set(vg.to_state()["params"]) == set(vg.params)
    assert vg.log2_gain(2.0) is None and vg.gain_values() is None and vg.appearance_knots == 0
    wg = _world()
    assert set(wg.static) == {"means", "quats", "scales", "opacities", "features"}
    assert set(wg.dynamic) == {"ctrl", "rot", "scales", "opacities", "features"}
    assert set(wg.state_dict()) == (
        {f"static.{k}" for k in wg.static} | {f"dynamic.{k}" for k in wg.dynamic} | {"knots"}
    )
    assert wg.log2_gain(2.0) is None and wg.appearance_knots == 0
    # the colour is the colour MLP's, the same tensor operations
    mlp = ColorMLP()
    torch.testing.assert_close(gaussian_colors(wg, mlp, 2.0), mlp(wg.features()), rtol=0, atol=0)
    # the video-Gaussian initialisation: no gain by default, zeros with one, the rest the same
    n_tracks, t_count = 12, 9
    tracks = torch.rand(n_tracks, t_count, 2, generator=torch.Generator().manual_seed(0)) * 20
    vis = torch.ones(n_tracks, t_count, dtype=torch.bool)
    depth = torch.full((t_count, 24, 24), 2.0)
    a = init_video_gaussians(tracks, vis, depth, 24, 24, VideoInitConfig(), ModelConfig())
    b = init_video_gaussians(
        tracks, vis, depth, 24, 24, VideoInitConfig(), ModelConfig(appearance_knots=3)
    )
    assert GAIN_KEY not in a.params and b.params[GAIN_KEY].shape == (n_tracks, 3)
    assert not b.params[GAIN_KEY].any()
    for k in a.params:
        assert torch.equal(a.params[k], b.params[k]), k


def test_containers_with_a_gain_evaluate_save_and_load_it():
    g = torch.Generator().manual_seed(2)
    gain = torch.randn(6, 4, generator=g)
    vg = _video(gain=gain)
    assert vg.appearance_knots == 4 and vg.params[GAIN_KEY].shape == (6, 4)
    want = [[_hand_curve(v, 9, t) for t in (0.0, 2.5, 8.0)] for v in gain.tolist()]
    np.testing.assert_allclose(vg.log2_gain([0.0, 2.5, 8.0])[..., 0].detach(), want, atol=1e-5)
    # the knots follow from T and K: not in the saved state, rebuilt on load
    assert "gain_knots" not in vg.state_dict()
    back = VideoGaussians.from_state(vg.to_state())
    assert torch.equal(back.log2_gain(3.7), vg.log2_gain(3.7))
    wg = _world(gain_k=5)
    assert wg.appearance_knots == 5
    u = wg.log2_gain(6.25)
    assert u.shape == (7, 1)
    sv, dv = wg.static[GAIN_KEY].detach(), wg.dynamic[GAIN_KEY].detach()
    want = [_hand_curve(v, 9, 6.25) for v in torch.cat([sv, dv]).tolist()]
    np.testing.assert_allclose(u[:, 0].detach(), want, atol=1e-5)
    assert wg.log2_gain(torch.tensor([1.0, 2.0])).shape == (7, 2, 1)
    back = WorldGaussians.from_state(wg.to_state())
    assert torch.equal(back.log2_gain(6.25), u.detach())
    # both sets or neither, one number of knots
    s = {k: v.detach() for k, v in wg.static.items()}
    d = {k: v.detach() for k, v in wg.dynamic.items()}
    with pytest.raises(ValueError, match="static set only"):
        WorldGaussians(s, {k: v for k, v in d.items() if k != GAIN_KEY}, wg.knots, 9)
    with pytest.raises(ValueError, match="knots"):
        WorldGaussians(s, {**d, GAIN_KEY: torch.zeros(3, 2)}, wg.knots, 9)
    with pytest.raises(ValueError, match="log2_gain"):
        _video(gain=torch.zeros(5, 4))


@pytest.mark.parametrize("camera_model", ["pinhole", "ortho"])
def test_render_with_a_gain_equals_colours_scaled_by_hand(camera_model):
    """render_gaussians with a gain equals the rasterizer fed colour(features) * 2 ** g(t), g from
    the written-out curve; gradients w.r.t. the knot values and the features agree too."""
    torch.manual_seed(0)
    t, t_count, k_gain = 5.3, 9, 4
    wg = _world(t_count=t_count, gain_k=k_gain)
    mlp, bg = ColorMLP(), Background(True)
    W, H = 40, 28
    if camera_model == "pinhole":
        K = torch.as_tensor(K_from_fov(W, H, 60.0), dtype=torch.float32)
        view = torch.eye(4)  # c2w: the camera a little to the left of and behind the origin
        view[:3, 3] = torch.tensor([-0.2, 0.1, -0.5])
        w2c = torch.linalg.inv(view)
    else:
        K = torch.tensor([[W / 2, 0, W / 2], [0, H / 2, H / 2], [0, 0, 1.0]])
        view = w2c = torch.eye(4)
    weight = torch.rand(H, W, 3, generator=torch.Generator().manual_seed(3))
    out = render_gaussians(wg, mlp, bg, t, view, K, W, H, camera_model, "torch")
    params = [wg.static[GAIN_KEY], wg.dynamic[GAIN_KEY], wg.static["features"]]
    got = torch.autograd.grad((out.hdr * weight).sum(), params)
    # by hand: the curve's weights on each knot at t from the written-out formula
    basis = torch.tensor(
        [_hand_curve([float(i == j) for j in range(k_gain)], t_count, t) for i in range(k_gain)]
    )
    values = torch.cat([wg.static[GAIN_KEY], wg.dynamic[GAIN_KEY]])
    # the (view-dependent) MLP sees the directions from the camera centre in pinhole renders only
    dirs = view_directions(wg.positions(t), view[:3, 3]) if camera_model == "pinhole" else None
    colours = mlp(wg.features(), dirs) * 2.0 ** (values @ basis)[:, None]
    ref = render(
        wg.positions(t), wg.quats(t), wg.scales(), wg.opacities(), colours, w2c, K, W, H,
        camera_model=camera_model, backend="torch", background=bg(),
    )  # fmt: skip
    torch.testing.assert_close(out.hdr, ref.features, rtol=1e-5, atol=1e-6)
    want = torch.autograd.grad((ref.features * weight).sum(), params)
    for a, b in zip(got, want):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6)
    assert float(got[0].abs().sum()) > 0 and float(got[1].abs().sum()) > 0
    # and it is not the render without the gain
    with torch.no_grad():
        plain = render(
            wg.positions(t), wg.quats(t), wg.scales(), wg.opacities(),
            mlp(wg.features(), dirs), w2c, K, W, H,
            camera_model=camera_model, backend="torch", background=bg(),
        )  # fmt: skip
    assert float((plain.features - out.hdr.detach()).abs().max()) > 1e-3
