"""Densification rules on hand-made cases, with the Adam state checked row by row."""

import math

import pytest
import torch
from torch import nn

from m4dgs.core import rotation, spline
from m4dgs.model import gaussians
from m4dgs.training.densify import DensifyConfig, GaussianLayout, Strategy

W, H = 100, 50


def _logit(p):
    return math.log(p / (1 - p))


def _params():
    """0: small (clone if high grad); 1, 3: large (split if high grad); 2: transparent (prune)."""
    s2 = math.sqrt(0.5)
    return {
        "means": nn.Parameter(torch.tensor([[0.0, 0, 1], [1.0, 2, 3], [5.0, 5, 5], [-1.0, -1, 2]])),
        "quats": nn.Parameter(
            torch.tensor([[1.0, 0, 0, 0], [s2, 0, 0, s2], [1.0, 0, 0, 0], [1.0, 0, 0, 0]])
        ),
        "scales": nn.Parameter(
            torch.log(torch.tensor([[0.005] * 3, [0.1, 0.001, 0.001], [0.005] * 3, [0.02] * 3]))
        ),
        "opacities": nn.Parameter(
            torch.tensor([_logit(0.5), _logit(0.6), _logit(0.001), _logit(0.7)])
        ),
        "features": nn.Parameter(torch.arange(4 * 5, dtype=torch.float32).reshape(4, 5)),
    }


def _adam(params):
    opt = torch.optim.Adam(
        [{"params": [p], "name": k} for k, p in params.items()], lr=1e-3, eps=1e-15
    )
    loss = sum(
        (p * torch.arange(1, p.numel() + 1, dtype=p.dtype).reshape(p.shape)).sum()
        for p in params.values()
    )
    loss.backward()
    opt.step()
    opt.zero_grad()
    return opt


def _render_info(params, grad_px):
    """A differentiable stand-in for the rasterizer: means2d depends on the means; the loss gives
    known gradients."""
    means2d = params["means"][:, :2] * 1.0
    info = {"means2d": means2d, "radii": torch.tensor([3, 4, 2, 5]), "width": W, "height": H}
    return info, (means2d * grad_px).sum()


def test_clone_split_prune_and_optimizer_alignment():
    params = _params()
    opt = _adam(params)
    old = {k: v.detach().clone() for k, v in params.items()}
    old_avg = {k: opt.state[params[k]]["exp_avg"].clone() for k in params}
    old_sq = {k: opt.state[params[k]]["exp_avg_sq"].clone() for k in params}
    cfg = DensifyConfig(start_iter=0, every=1, reset_every=10_000, stop_iter=100)
    strat = Strategy(cfg, GaussianLayout(), seed=0)
    state = strat.initialize_state()
    # pixel gradients: NDC norm = |g * (W/2, H/2)|: 1e-5 * 50 = 5e-4 > 2e-4 for 0 and 1; 1e-7 * 50
    # for 2 and 3
    grad_px = torch.tensor([[1e-5, 0.0], [0.0, 2e-5], [1e-7, 0.0], [1e-7, 0.0]])
    info, loss = _render_info(params, grad_px)
    strat.step_pre_backward(params, opt, state, 1, info)
    loss.backward()
    out = strat.step_post_backward(params, opt, state, 1, info)
    assert out == {"clone": 1, "split": 1, "prune": 1, "reset": 0}
    # rows: clone appends a copy of 0 -> [0,1,2,3,0']; split removes 1 and appends 2 samples ->
    # [0,2,3,0',1a,1b]; prune removes 2 -> [0,3,0',1a,1b]
    n = 5
    for k, p in params.items():
        assert p.shape[0] == n
        st = opt.state[p]
        assert st["exp_avg"].shape == p.shape and st["exp_avg_sq"].shape == p.shape
        # surviving originals keep their moments, new rows have zero moments
        torch.testing.assert_close(st["exp_avg"][0], old_avg[k][0])
        torch.testing.assert_close(st["exp_avg"][1], old_avg[k][3])
        torch.testing.assert_close(st["exp_avg_sq"][1], old_sq[k][3])
        assert (st["exp_avg"][2:] == 0).all() and (st["exp_avg_sq"][2:] == 0).all()
        # the optimizer holds exactly the new parameter objects
        assert any(p is q for g in opt.param_groups for q in g["params"])
    torch.testing.assert_close(params["means"][2], old["means"][0])  # clone: same position
    torch.testing.assert_close(params["scales"][2], old["scales"][0])
    torch.testing.assert_close(params["features"][1], old["features"][3])
    # split: scale / 1.6, other attributes copied, samples displaced along the rotated long axis
    # only
    torch.testing.assert_close(
        params["scales"][3:].exp(), (old["scales"][1].exp() / 1.6).expand(2, 3)
    )
    torch.testing.assert_close(params["features"][3:], old["features"][1].expand(2, 5))
    torch.testing.assert_close(params["opacities"][3:], old["opacities"][1].expand(2))
    off = params["means"][3:] - old["means"][1]
    # quaternion = 90 deg about z: local x (scale 0.1) maps to world y; world x, z offsets are at
    # the 0.001 scale
    assert off[:, 0].abs().max() < 0.006 and off[:, 2].abs().max() < 0.006
    assert off[:, 1].abs().max() > 0.01
    # statistics were reset and sized to the new count
    assert state["grad2d"].shape == (n,) and (state["grad2d"] == 0).all()
    # an optimizer step still works with the new parameters
    loss2 = sum(p.sum() for p in params.values())
    loss2.backward()
    opt.step()


def test_grad_threshold_uses_mean_over_visible_steps_and_schedule():
    params = _params()
    opt = _adam(params)
    cfg = DensifyConfig(start_iter=2, every=3, reset_every=10_000, stop_iter=100, prune_opacity=0.0)
    strat = Strategy(cfg)
    state = strat.initialize_state()
    old_scale3 = params["scales"][3].detach().exp()
    # Gaussian 0 visible twice with NDC norms 2.5e-4 and 0.5e-4 (mean 1.5e-4 < 2e-4) -> no growth;
    # Gaussian 3 visible once at 5e-4 and invisible once (radius 0: not counted) -> mean 5e-4 ->
    # split (scale 0.02)
    for step, (g0, g3, r3) in enumerate([(2.5e-4, 5e-4, 5), (0.5e-4, 1.0, 0)], start=2):
        grad = torch.zeros(4, 2)
        grad[0, 0] = g0 / (W / 2)
        grad[3, 1] = g3 / (H / 2)
        info = {"means2d_grad": grad, "radii": torch.tensor([1, 0, 0, r3]), "width": W, "height": H}
        out = strat.step_post_backward(params, opt, state, step, info)
        if step == 2:  # not after start_iter yet
            assert out["clone"] == 0 and state["count"].tolist() == [1, 0, 0, 1]
    assert out == {"clone": 0, "split": 1, "prune": 0, "reset": 0}
    assert params["means"].shape[0] == 5
    torch.testing.assert_close(params["scales"][3:].exp(), (old_scale3 / 1.6).expand(2, 3))


def test_cap_respected_and_highest_gradient_wins():
    params = _params()
    opt = _adam(params)
    cfg = DensifyConfig(
        start_iter=0, every=1, reset_every=10_000, stop_iter=100, prune_opacity=0.0, max_gaussians=5
    )
    strat = Strategy(cfg)
    state = strat.initialize_state()
    grad = torch.zeros(4, 2)
    grad[0, 0] = 2e-3  # clone candidate (small), higher gradient -> the only one within the cap
    grad[3, 0] = 1e-3  # split candidate (+1 Gaussian), lower gradient
    info = {"means2d_grad": grad, "radii": torch.ones(4), "width": W, "height": H}
    out = strat.step_post_backward(params, opt, state, 1, info)
    assert out["clone"] == 1 and out["split"] == 0 and params["means"].shape[0] == 5
    torch.testing.assert_close(params["means"][4], params["means"][0])
    out = strat.step_post_backward(
        params,
        opt,
        state,
        2,
        {**info, "means2d_grad": torch.cat([grad, grad[:1]]), "radii": torch.ones(5)},
    )
    assert out["clone"] == 0 and out["split"] == 0 and params["means"].shape[0] == 5


def test_opacity_reset_and_stop():
    params = _params()
    opt = _adam(params)
    cfg = DensifyConfig(start_iter=0, every=1000, reset_every=4, stop_iter=10)
    strat = Strategy(cfg)
    state = strat.initialize_state()
    info = {"means2d_grad": torch.zeros(4, 2), "radii": torch.ones(4), "width": W, "height": H}
    op_before = torch.sigmoid(params["opacities"].detach())
    out = strat.step_post_backward(params, opt, state, 4, info)
    assert out["reset"] == 1
    op = torch.sigmoid(params["opacities"])
    torch.testing.assert_close(op, torch.clamp(op_before, max=0.01), rtol=1e-5, atol=0)
    assert op_before[2] < 0.01 and (op[[0, 1, 3]] - 0.01).abs().max() < 1e-6
    assert (opt.state[params["opacities"]]["exp_avg"] == 0).all()
    assert opt.state[params["means"]]["exp_avg"].abs().sum() > 0  # other states untouched
    before = params["opacities"].detach().clone()
    params["opacities"].data.fill_(2.0)
    # past stop_iter: nothing
    assert strat.step_post_backward(params, opt, state, 12, info)["reset"] == 0
    assert (params["opacities"] == 2.0).all()
    assert before.shape == (4,)


def test_video_gaussians_split_moves_all_control_points_together():
    g = torch.Generator().manual_seed(0)
    n, t_count = 3, 9
    knots = spline.make_knots(t_count, 4)
    vg = gaussians.VideoGaussians(
        torch.randn(n, knots.numel(), 3, generator=g),
        rotation.init_rotation_coeffs(n),
        gaussians.scale_inverse(
            torch.tensor([[0.03] * 3, [0.002] * 3, [0.002] * 3]), "sigmoid", 0.05
        ),
        torch.zeros(n),
        torch.randn(n, 36, generator=g),
        knots,
        t_count,
    )
    old_ctrl = vg.params["ctrl"].detach().clone()
    opt = torch.optim.Adam([{"params": [p], "name": k} for k, p in vg.params.items()], lr=1e-3)
    strat = Strategy(
        DensifyConfig(start_iter=0, every=1, stop_iter=10, reset_every=1000), vg.layout(), seed=1
    )
    state = strat.initialize_state()
    grad = torch.tensor([[1e-3, 0.0], [1e-3, 0.0], [0.0, 0.0]])
    info = {"means2d_grad": grad, "radii": torch.ones(3), "width": W, "height": H}
    out = strat.step_post_backward(vg.params, opt, state, 1, info)
    assert out["clone"] == 1 and out["split"] == 1
    # rows: [1, 2, 1', 0a, 0b]
    assert len(vg) == 5 and vg.params["rot"].shape == (5, 4, 4)
    delta = vg.params["ctrl"][3:] - old_ctrl[0]  # [2, K, 3]
    # same offset at every control point
    torch.testing.assert_close(delta, delta[:, :1].expand_as(delta))
    assert delta.abs().max() > 0
    torch.testing.assert_close(vg.scales()[3:], torch.full((2, 3), 0.03 / 1.6), rtol=1e-4, atol=0)
    torch.testing.assert_close(vg.params["ctrl"][2], old_ctrl[1])
    for p in vg.params.values():
        assert opt.state.get(p) is None or opt.state[p]["exp_avg"].shape == p.shape


def test_sanity_check_messages():
    strat = Strategy()
    with pytest.raises(ValueError, match="lacks"):
        strat.check_sanity({"means": torch.zeros(2, 3)})
    p = _params()
    p["features"] = nn.Parameter(torch.zeros(3, 5))
    with pytest.raises(ValueError, match="disagree"):
        strat.check_sanity(p)


def test_remove_keeps_state_aligned():
    params = _params()
    opt = _adam(params)
    strat = Strategy(DensifyConfig(start_iter=0, every=1000, reset_every=1000, stop_iter=10))
    state = strat.initialize_state()
    info = {
        "means2d_grad": torch.tensor([[1.0, 0], [2.0, 0], [3.0, 0], [4.0, 0]]),
        "radii": torch.ones(4),
        "width": 2,
        "height": 2,
    }
    strat.step_post_backward(params, opt, state, 1, info)
    old_avg = opt.state[params["features"]]["exp_avg"].clone()
    assert strat.remove(params, opt, state, torch.tensor([False, True, False, True])) == 2
    assert state["grad2d"].tolist() == [1.0, 3.0] and state["count"].tolist() == [1.0, 1.0]
    torch.testing.assert_close(opt.state[params["features"]]["exp_avg"], old_avg[[0, 2]])
    assert params["means"].shape == (2, 3)


def test_born_records_the_creation_step_of_clones_and_split_samples():
    # the stage-2 removal tests only densified Gaussians: "born" must follow every row edit
    params = _params()
    opt = _adam(params)
    strat = Strategy(DensifyConfig(start_iter=0, every=1, reset_every=10_000, stop_iter=100))
    state = strat.initialize_state()
    grad_px = torch.tensor([[1e-5, 0.0], [0.0, 2e-5], [1e-7, 0.0], [1e-7, 0.0]])
    info, loss = _render_info(params, grad_px)
    strat.step_pre_backward(params, opt, state, 7, info)
    loss.backward()
    strat.step_post_backward(params, opt, state, 7, info)
    # rows [0, 3, 0', 1a, 1b] (see test_clone_split_prune_and_optimizer_alignment)
    assert state["born"].tolist() == [-1, -1, 7, 7, 7]
    strat.remove(params, opt, state, torch.tensor([False, True, False, True, False]))
    assert state["born"].tolist() == [-1, 7, 7]


@pytest.mark.parametrize("extent, expect", [(1.0, (1, 1)), (0.1, (0, 2)), (20.0, (2, 0))])
def test_clone_split_boundary_scales_with_the_extent(extent, expect):
    # largest scales 0.005 (row 0) and 0.1 (row 1); boundary 0.01 x extent (3DGS percent_dense)
    params = _params()
    opt = _adam(params)
    cfg = DensifyConfig(start_iter=0, every=1, reset_every=10_000, stop_iter=100)
    strat = Strategy(cfg, GaussianLayout(), extent=extent)
    state = strat.initialize_state()
    grad_px = torch.tensor([[1e-5, 0.0], [0.0, 2e-5], [1e-7, 0.0], [1e-7, 0.0]])
    info, loss = _render_info(params, grad_px)
    strat.step_pre_backward(params, opt, state, 1, info)
    loss.backward()
    out = strat.step_post_backward(params, opt, state, 1, info)
    assert (out["clone"], out["split"]) == expect


def test_an_empty_set_is_left_alone():
    """A set with no Gaussian (e.g. no dynamic Gaussian after V2W on a static scene) is skipped at
    every scheduled step instead of failing on a [-1, 0, 2] reshape."""
    params = {k: nn.Parameter(v.detach()[:0].clone()) for k, v in _params().items()}
    opt = torch.optim.Adam([{"params": [p], "name": k} for k, p in params.items()], lr=1e-3)
    strat = Strategy(DensifyConfig(start_iter=0, every=1, reset_every=2, stop_iter=10))
    state = strat.initialize_state()
    info = {"means2d_grad": torch.zeros(0, 2), "radii": torch.zeros(0), "width": W, "height": H}
    for it in range(1, 5):
        out = strat.step_post_backward(params, opt, state, it, info)
        assert out == {"clone": 0, "split": 0, "prune": 0, "reset": 0}
    assert all(p.shape[0] == 0 for p in params.values())


def test_clone_split_and_prune_keep_the_gain_rows_with_their_gaussians():
    """Video Gaussians with a gain over time (beyond the paper): after a clone, a split and a
    prune, and after a removal, every row of log2_gain (tagged with its Gaussian's features) and
    of its Adam moments sits with the rest of its Gaussian."""
    g = torch.Generator().manual_seed(0)
    n, t_count = 4, 9
    knots = spline.make_knots(t_count, 4)
    feats = torch.arange(n * 6, dtype=torch.float32).reshape(n, 6)
    vg = gaussians.VideoGaussians(
        torch.randn(n, knots.numel(), 3, generator=g),
        rotation.init_rotation_coeffs(n),
        gaussians.scale_inverse(
            torch.tensor([[0.03] * 3, [0.002] * 3, [0.002] * 3, [0.002] * 3]), "sigmoid", 0.05
        ),
        torch.tensor([0.0, 0.0, _logit(0.001), 0.0]),
        feats,
        knots,
        t_count,
        log2_gain=feats[:, :5].clone(),  # K = 5 knot values = the first 5 features
    )
    opt = _adam(vg.params)
    strat = Strategy(
        DensifyConfig(start_iter=0, every=1, stop_iter=10, reset_every=1000), vg.layout(), seed=1
    )
    state = strat.initialize_state()
    # 0: large, high gradient -> split; 1: small, high gradient -> clone; 2: transparent -> pruned
    grad = torch.tensor([[1e-3, 0.0], [1e-3, 0.0], [0.0, 0.0], [0.0, 0.0]])
    info = {"means2d_grad": grad, "radii": torch.ones(4), "width": W, "height": H}
    out = strat.step_post_backward(vg.params, opt, state, 1, info)
    assert (out["clone"], out["split"], out["prune"]) == (1, 1, 1)
    assert len(vg) == 5 and vg.params[gaussians.GAIN_KEY].shape == (5, 5)
    gain, f = vg.params[gaussians.GAIN_KEY].detach(), vg.params["features"].detach()
    torch.testing.assert_close(gain, f[:, :5])  # each gain row still with its Gaussian
    # rows [1, 3, 1', 0a, 0b] (split samples last; one Adam step moved every value by 1e-3)
    assert f[:, 0].round().tolist() == [6.0, 18.0, 6.0, 0.0, 0.0]
    ga = opt.state[vg.params[gaussians.GAIN_KEY]]
    for key in ("exp_avg", "exp_avg_sq"):
        assert ga[key].shape == (5, 5)
        assert (ga[key][2:] == 0).all() and (ga[key][:2] != 0).all()
    # the split samples evaluate the gain curve of their parent at any time
    curve = vg.log2_gain(3.3).detach()
    torch.testing.assert_close(curve[3], curve[4])
    # removal (the stage-2 pass over misplaced dynamic Gaussians) keeps the rows together too
    strat.remove(vg.params, opt, state, torch.tensor([True, False, False, True, False]))
    torch.testing.assert_close(
        vg.params[gaussians.GAIN_KEY].detach(), vg.params["features"].detach()[:, :5]
    )
    assert opt.state[vg.params[gaussians.GAIN_KEY]]["exp_avg"].shape == (3, 5)
