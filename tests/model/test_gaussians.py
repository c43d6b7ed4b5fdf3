"""Gaussian containers and the video-Gaussian initialisation from tracks + depth."""

import numpy as np
import pytest
import torch

from m4dgs.core import camera, rotation, spline
from m4dgs.model import gaussians
from m4dgs.model.gaussians import ModelConfig, VideoGaussians, VideoInitConfig, WorldGaussians


def _scene(n=60, t_count=11, width=48, height=32, seed=0):
    """Tracks moving linearly in pixels, on a depth map that is linear in x (so bilinear sampling is
    exact)."""
    g = torch.Generator().manual_seed(seed)
    start = torch.rand(n, 2, generator=g) * torch.tensor([width - 8.0, height - 8.0]) + 4.0
    vel = (torch.rand(n, 2, generator=g) - 0.5) * 0.6
    times = torch.arange(t_count, dtype=torch.float32)
    tracks = start[:, None] + vel[:, None] * times[None, :, None]
    visible = torch.rand(n, t_count, generator=g) > 0.2
    visible[:, 0] = True
    # depth D_t(u, v) = 2 + 0.01 * t + 0.02 * (u - 0.5) + 0.03 * (v - 0.5): evaluated on
    # pixel-centre grid
    uc = torch.arange(width, dtype=torch.float32) + 0.5
    vc = torch.arange(height, dtype=torch.float32) + 0.5
    depth = (
        2.0
        + 0.01 * times[:, None, None]
        + 0.02 * (uc[None, None, :] - 0.5)
        + 0.03 * (vc[None, :, None] - 0.5)
    )
    return tracks, visible, depth, width, height


def test_sample_depth_is_exact_bilinear_at_centres_and_between():
    tracks, visible, depth, w, h = _scene()
    z = gaussians.sample_depth(depth, tracks, w, h)
    times = torch.arange(depth.shape[0], dtype=torch.float32)
    want = 2.0 + 0.01 * times[None] + 0.02 * (tracks[..., 0] - 0.5) + 0.03 * (tracks[..., 1] - 0.5)
    torch.testing.assert_close(z, want, atol=1e-5, rtol=0)
    # exactly a pixel centre (i + 0.5, j + 0.5) reads that pixel
    d = torch.arange(12.0).reshape(1, 3, 4)
    uv = torch.tensor([[[2.5, 1.5]]])
    assert gaussians.sample_depth(d, uv, 4, 3).item() == pytest.approx(d[0, 1, 2].item())


def test_init_reprojects_tracks_and_depth():
    tracks, visible, depth, w, h = _scene()
    cfg = VideoInitConfig(seed=1)
    vg = gaussians.init_video_gaussians(
        tracks, visible, depth, w, h, cfg, ModelConfig(control_every=4)
    )
    assert len(vg) == tracks.shape[0]
    assert vg.knots.tolist() == [0.0, 4.0, 8.0, 10.0]
    # project t = 0 positions back to pixels with the lead's camera helper (u = (x + 1) W / 2)
    p0 = vg.positions(0.0)
    uv = camera.ortho_to_pixel(p0[:, :2], w, h)
    torch.testing.assert_close(uv, tracks[:, 0], atol=1e-3, rtol=0)
    # every frame (linear motion: the fit is exact also across invisible frames); depth from the
    # prior
    p_all = vg.positions(torch.arange(11.0))
    torch.testing.assert_close(
        camera.ortho_to_pixel(p_all[..., :2], w, h), tracks, atol=1e-3, rtol=0
    )
    z_want = gaussians.sample_depth(depth, tracks, w, h)
    torch.testing.assert_close(p_all[..., 2], z_want, atol=1e-4, rtol=0)
    # attributes
    torch.testing.assert_close(vg.opacities(), torch.full((len(vg),), 0.5))
    q = vg.quats(3.5)
    torch.testing.assert_close(q, torch.tensor([1.0, 0, 0, 0]).expand(len(vg), 4))
    assert vg.features().shape == (len(vg), 36)
    assert (
        vg.scales().shape == (len(vg), 3) and (vg.scales() > 0).all() and (vg.scales() < 0.05).all()
    )


def test_init_scale_is_sqrt_mean_knn_sq_distance():
    # 4 tracks at pixel corners of a square; depth constant: video-space distances are known by hand
    w, h, t_count = 40, 40, 3
    uv = torch.tensor([[10.0, 10.0], [12.0, 10.0], [10.0, 12.0], [30.0, 30.0]])
    tracks = uv[:, None].expand(4, t_count, 2).clone()
    visible = torch.ones(4, t_count, dtype=torch.bool)
    depth = torch.full((t_count, h, w), 3.0)
    vg = gaussians.init_video_gaussians(
        tracks,
        visible,
        depth,
        w,
        h,
        VideoInitConfig(knn_k=2),
        ModelConfig(video_scale_activation="exp"),
    )
    pts = torch.cat([uv / 20.0 - 1.0, torch.full((4, 1), 3.0)], 1).numpy()
    d2 = ((pts[:, None] - pts[None]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    want = np.sqrt(np.sort(d2, 1)[:, :2].mean(1))
    np.testing.assert_allclose(vg.scales()[:, 0].detach().numpy(), want, rtol=1e-4)
    # sigmoid-bounded scales (authors): the isolated 4th point is clamped just below the maximum
    vs = gaussians.init_video_gaussians(
        tracks, visible, depth, w, h, VideoInitConfig(knn_k=2), ModelConfig(video_scale_max=1.0)
    )
    got = vs.scales()[:, 0].detach().numpy()
    np.testing.assert_allclose(got[:3], want[:3], rtol=1e-4)
    assert want[3] > 1.0 and 0.99 < got[3] < 1.0


def test_init_cap_subsample_and_invisible_tracks():
    tracks, visible, depth, w, h = _scene(n=80)
    visible[:5] = False  # never visible: dropped
    tracks[5:10, :, 0] = -50.0  # outside the image: dropped
    vg = gaussians.init_video_gaussians(
        tracks, visible, depth, w, h, VideoInitConfig(max_gaussians=30, seed=3)
    )
    assert len(vg) == 30
    vg_all = gaussians.init_video_gaussians(
        tracks, visible, depth, w, h, VideoInitConfig(max_gaussians=1000)
    )
    assert len(vg_all) == 70
    # deterministic for a seed
    vg2 = gaussians.init_video_gaussians(
        tracks, visible, depth, w, h, VideoInitConfig(max_gaussians=30, seed=3)
    )
    torch.testing.assert_close(vg.params["ctrl"], vg2.params["ctrl"])
    torch.testing.assert_close(vg.params["features"], vg2.params["features"])


def test_scale_activations_roundtrip():
    s = torch.tensor([1e-4, 0.01, 0.049])
    for kind in ("exp", "sigmoid"):
        raw = gaussians.scale_inverse(s, kind, 0.05)
        torch.testing.assert_close(
            gaussians.scale_activation(raw, kind, 0.05), s, rtol=1e-5, atol=0
        )
    with pytest.raises(ValueError):
        gaussians.scale_activation(s, "softplus")


def test_video_gaussians_accessors_and_state_roundtrip():
    g = torch.Generator().manual_seed(4)
    n, t_count = 7, 9
    knots = spline.make_knots(t_count, 4)
    ctrl = torch.randn(n, knots.numel(), 3, generator=g)
    coeffs = torch.randn(n, 4, 4, generator=g)
    vg = VideoGaussians(
        ctrl,
        coeffs,
        torch.zeros(n, 3),
        torch.zeros(n),
        torch.randn(n, 36, generator=g),
        knots,
        t_count,
    )
    torch.testing.assert_close(vg.positions(2.5), spline.evaluate(ctrl, knots, 2.5))
    # rotation at frame 6 of 9 -> normalised time 6/8, evaluated by hand
    tn = 6 / 8
    want = sum(coeffs[:, j] * tn**j for j in range(4))
    torch.testing.assert_close(vg.quats(6.0, normalize=False), want)
    torch.testing.assert_close(
        vg.quats(torch.tensor([6.0]))[:, 0], want / want.norm(dim=-1, keepdim=True)
    )
    torch.testing.assert_close(vg.scales(), torch.full((n, 3), 0.025))
    vg2 = VideoGaussians.from_state(vg.to_state())
    for k in vg.params:
        torch.testing.assert_close(vg2.params[k], vg.params[k])
    # gradients flow to the control points and coefficients
    (vg.positions(3.0).sum() + vg.quats(3.0).sum()).backward()
    assert vg.params["ctrl"].grad is not None and vg.params["rot"].grad is not None
    with pytest.raises(ValueError):
        VideoGaussians(
            ctrl, coeffs[:3], torch.zeros(n, 3), torch.zeros(n), torch.zeros(n, 36), knots, t_count
        )


def test_world_gaussians_union_and_info_split():
    g = torch.Generator().manual_seed(5)
    ns, nd, t_count = 4, 3, 9
    knots = spline.make_knots(t_count, 4)
    static = {
        "means": torch.randn(ns, 3, generator=g),
        "quats": torch.randn(ns, 4, generator=g),
        "scales": torch.randn(ns, 3, generator=g),
        "opacities": torch.randn(ns, generator=g),
        "features": torch.randn(ns, 36, generator=g),
    }
    dynamic = {
        "ctrl": torch.randn(nd, knots.numel(), 3, generator=g),
        "rot": rotation.init_rotation_coeffs(nd),
        "scales": torch.randn(nd, 3, generator=g),
        "opacities": torch.randn(nd, generator=g),
        "features": torch.randn(nd, 36, generator=g),
    }
    wg = WorldGaussians(static, dynamic, knots, t_count)
    assert len(wg) == 7 and wg.is_dynamic.tolist() == [False] * 4 + [True] * 3
    p = wg.positions(5.0)
    torch.testing.assert_close(p[:4], static["means"])
    torch.testing.assert_close(p[4:], spline.evaluate(dynamic["ctrl"], knots, 5.0))
    pt = wg.positions(torch.tensor([1.0, 5.0]))
    assert pt.shape == (7, 2, 3)
    torch.testing.assert_close(pt[:4, 1], static["means"])
    q = wg.quats(2.0)
    torch.testing.assert_close(q[:4], static["quats"] / static["quats"].norm(dim=-1, keepdim=True))
    torch.testing.assert_close(q[4:], torch.tensor([1.0, 0, 0, 0]).expand(3, 4))
    torch.testing.assert_close(
        wg.scales(), torch.exp(torch.cat([static["scales"], dynamic["scales"]]))
    )
    torch.testing.assert_close(
        wg.opacities(), torch.sigmoid(torch.cat([static["opacities"], dynamic["opacities"]]))
    )
    # render-info split for the two densification strategies
    grad = torch.arange(14.0).reshape(7, 2)
    radii = torch.arange(7)
    si, di = wg.split_render_info({"means2d_grad": grad, "radii": radii, "width": 10, "height": 8})
    torch.testing.assert_close(si["means2d_grad"], grad[:4])
    torch.testing.assert_close(di["radii"], radii[4:])
    assert si["width"] == 10 and di["height"] == 8
    wg2 = WorldGaussians.from_state(wg.to_state())
    torch.testing.assert_close(wg2.positions(3.0), wg.positions(3.0))


def test_knn_mean_sq_distance_matches_brute_force():
    """The initial-scale statistic: mean squared distance to the k nearest other points (the kNN
    itself is tested in tests/core/test_knn.py)."""
    g = torch.Generator().manual_seed(6)
    pts = torch.rand(300, 3, generator=g, dtype=torch.float64)
    pts[10] = pts[11]  # a duplicate: distance 0 to the other copy, never to itself
    full = ((pts[:, None] - pts[None]) ** 2).sum(-1)
    full.fill_diagonal_(float("inf"))
    want_d2, _ = full.topk(4, dim=1, largest=False)
    for backend in ("torch", "scipy"):
        got = gaussians.knn_mean_sq_distance(pts, 4, backend)
        torch.testing.assert_close(got, want_d2.mean(1))
    # k is clipped to N - 1; a single point gets 1
    two = torch.tensor([[0.0, 0.0, 0.0], [0.0, 3.0, 4.0]])
    torch.testing.assert_close(gaussians.knn_mean_sq_distance(two, 3), torch.tensor([25.0, 25.0]))
    torch.testing.assert_close(gaussians.knn_mean_sq_distance(two[:1], 3), torch.ones(1))
