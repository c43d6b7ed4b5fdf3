"""The loss assembly of both stages (m4dgs.training.objective through VideoStage / WorldStage) on
small synthetic training data, no clip and no renderer of the benchmark.

For one iteration: which terms are present under each config weight and ablation switch; each
term's value against an independent recomputation from the m4dgs.losses functions on the same
render (the frames drawn from a copy of the stage's generator, in the documented order); and which
parameters each term's gradient reaches."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from m4dgs.core import camera as cam
from m4dgs.core import rotation as rot
from m4dgs.core import spline
from m4dgs.core.camera import K_from_fov
from m4dgs.core.knn import knn
from m4dgs.core.warp import backward_warp
from m4dgs.losses.geometry import depth_loss, flow_from_destination_map, flow_loss, track_loss
from m4dgs.losses.motion import acceleration_loss, velocity_loss
from m4dgs.losses.photometric import rgb_loss, unit_exposure_loss
from m4dgs.losses.temporal import (
    flow_in_bounds,
    hdr_reprojection_loss,
    tlr_loss,
    tlr_valid_mask,
)
from m4dgs.model.gaussians import GAIN_KEY, WorldGaussians
from m4dgs.training import objective
from m4dgs.training.config import apply_overrides, preset
from m4dgs.training.data import TrainingData
from m4dgs.training.stage1 import VideoStage, build_appearance
from m4dgs.training.stage2 import WorldInit, WorldStage

T, W, H, N_TRACKS = 6, 32, 24, 40
BACKEND = "torch"  # the dense reference rasterizer: no compiled extension needed


def synthetic_data(seed: int = 0) -> TrainingData:
    """Random LDR frames, a slanted depth prior, tracks drifting right, flows F_{i -> i +- 2}."""
    g = torch.Generator().manual_seed(seed)
    ys, xs = torch.meshgrid(torch.arange(H) + 0.5, torch.arange(W) + 0.5, indexing="ij")
    depth = (2.0 + xs / W)[None].repeat(T, 1, 1) + 0.05 * torch.rand(T, H, W, generator=g)
    start = torch.rand(N_TRACKS, 1, 2, generator=g) * torch.tensor([W - 8.0, H - 2.0]) + 1.0
    tracks = start + torch.arange(T, dtype=torch.float32)[None, :, None] * torch.tensor([1.0, 0.0])
    vis = torch.ones(N_TRACKS, T, dtype=torch.bool)
    vis[::5, 0] = False  # some tracks unseen at frame 0
    pairs = [(i, j) for i in range(T) for j in (i - 2, i + 2) if 0 <= j < T]
    flow = torch.zeros(len(pairs), H, W, 2)
    for p, (i, j) in enumerate(pairs):
        flow[p, ..., 0] = float(j - i)
    return TrainingData(
        clip_name="synthetic",
        frames=list(range(0, 2 * T, 2)),
        width=W,
        height=H,
        ldr=torch.rand(T, H, W, 3, generator=g),
        log2_dt=torch.tensor([-1.0, 1.0] * (T // 2)),
        depth=depth,
        tracks=tracks,
        track_vis=vis,
        flow_pairs=pairs,
        flow=flow,
        flow_valid=torch.ones(len(pairs), H, W, dtype=torch.bool),
        unit_exposure_value=0.73,
        num_levels=2,
    )


def tiny_config(**overrides):
    cfg = preset("tiny")
    cfg.width, cfg.height = W, H
    cfg.tonemap.pretrain_steps = 0
    return apply_overrides(cfg, overrides) if overrides else cfg


def replay_sample(stage, it: int) -> dict:
    """The iteration's frames drawn from a copy of the stage's generator in the documented order:
    i; a flow-vs-track coin when frame i has prior flows; j; and, when the moving set has more
    than arap_k Gaussians, the motion subset and the ARAP time t2."""
    rng = np.random.default_rng()
    rng.bit_generator.state = stage.rng.bit_generator.state
    d, lc = stage.data, stage.loss_cfg
    i = int(rng.integers(T))
    targets = d.flow_targets(i)
    use_flow = bool(targets) and rng.random() < lc.flow_prob
    j = int(rng.choice(targets)) if use_flow else int(rng.choice([k for k in range(T) if k != i]))
    out = {"i": i, "j": j, "use_flow": use_flow}
    n = stage.trajectories().count
    if stage.motion and n > lc.arap_k:
        out["sub"] = torch.from_numpy(rng.choice(n, size=min(n, 4096), replace=False))
        if lc.lambda_arap > 0:
            out["t2"] = float(rng.integers(T))
    return out


def reseed_for_arap(stage, it: int) -> None:
    """Reseed the stage's generator until the iteration's ARAP times differ (t2 != i), so that the
    ARAP term has a gradient."""
    for seed in range(100):
        stage.rng = np.random.default_rng(seed)
        draw = replay_sample(stage, it)
        if draw.get("t2", draw["i"]) != draw["i"]:
            return
    raise AssertionError("no seed with t2 != i")


def grads(value: torch.Tensor, params: dict) -> dict:
    """{name: sum |d value / d p|} over each named group of parameters (0 where unused)."""
    flat = [p for ps in params.values() for p in ps]
    gs = torch.autograd.grad(value, flat, retain_graph=True, allow_unused=True)
    out, k = {}, 0
    for name, ps in params.items():
        out[name] = sum(float(g.abs().sum()) for g in gs[k : k + len(ps)] if g is not None)
        k += len(ps)
    return out


# --------------------------------------------------------------------------------------------------
# stage 1
# --------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def data():
    return synthetic_data()


def video_stage(data, **overrides) -> VideoStage:
    torch.manual_seed(0)
    return VideoStage(data, tiny_config(**overrides), "cpu", BACKEND)


def test_stage1_terms_follow_weights_and_ablations(data):
    late = 10_000  # past the TLR start
    st = video_stage(data)
    assert list(st.losses(late).terms) == ["rgb", "ue", "dep", "track", "arap", "vel", "acc", "tlr"]
    assert "tlr" not in video_stage(data).losses(st.tlr_start_step() - 1).terms
    cases = {
        "ablation.depth_loss": (False, {"dep"}),
        "ablation.track_loss": (False, {"track"}),
        "ablation.tlr": (False, {"tlr"}),
        "stage1.loss.lambda_dep": (0.0, {"dep"}),
        "stage1.loss.lambda_track": (0.0, {"track"}),
        "stage1.loss.lambda_tlr": (0.0, {"tlr"}),
        "stage1.loss.lambda_arap": (0.0, {"arap"}),
    }
    for key, (value, gone) in cases.items():
        names = set(video_stage(data, **{key: value}).losses(late).terms)
        assert names == {"rgb", "ue", "dep", "track", "arap", "vel", "acc", "tlr"} - gone, key
    names = video_stage(
        data, **{"stage1.loss.lambda_vel": 0.0, "stage1.loss.lambda_acc": 0.0}
    ).losses(late)
    assert not {"vel", "acc"} & set(names.terms)
    extra = video_stage(
        data,
        **{
            "stage1.loss.lambda_opacity": 1.0,
            "stage1.loss.lambda_scale_std": 1.0,
            "stage1.loss.lambda_flat": 1.0,
            "tonemap.lambda_monotonic": 1.0,
        },
    ).losses(late)
    assert list(extra.terms)[-4:] == ["mono", "opacity", "scale_std", "flat"]
    # stage 2's own term is not a stage-1 term, and the weights follow the config
    w = video_stage(data, **{"stage1.loss.lambda_dep": 0.25}).weights()
    assert "pr" not in w and w["dep"] == 0.25 and w["ue"] == 10.0


@pytest.mark.parametrize("arap", [0.01, 0.0])  # the neighbours from ARAP's sets, or alone
def test_relative_smoothness_recomputed(data, arap):
    """`loss.smooth_relative` (beyond the paper): the velocity and acceleration terms on each
    sampled Gaussian's window positions less the mean of its arap_k nearest neighbours' (found at
    the query frame), recomputed here by indexing; with ARAP off the generator draws as before."""
    over = {"stage1.loss.smooth_relative": True, "stage1.loss.lambda_arap": arap}
    st = video_stage(data, **over)
    it = 10_000
    draw = replay_sample(st, it)
    i, sub = draw["i"], draw["sub"]
    L = st.losses(it).terms
    assert ("arap" in L) == (arap > 0)
    with torch.no_grad():
        ctrl, coeff, knots = st.gauss.params["ctrl"], st.gauss.params["rot"], st.gauss.knots
        nb = knn(spline.evaluate(ctrl, knots, float(i)), st.loss_cfg.arap_k)[0][sub]  # [n, k]
        times = torch.arange(max(0, i - 2), min(T, i + 3), dtype=torch.float32)
        pos = spline.evaluate(ctrl, knots, times).transpose(0, 1)  # [W, N, 3]
        rel = pos[:, sub] - pos[:, nb].mean(dim=2)
        q = rot.poly_evaluate(coeff[sub], rot.normalize_time(times, T), normalize=True)
        for name, f in (("vel", velocity_loss), ("acc", acceleration_loss)):
            want = f(rel, q.transpose(0, 1))
            torch.testing.assert_close(L[name], want, rtol=1e-5, atol=1e-6)
            assert not torch.allclose(want, f(pos[:, sub], q.transpose(0, 1)))


@pytest.mark.parametrize("flow_prob", [1.0, 0.0])  # flow supervision / track supervision
def test_stage1_term_values_recomputed(data, flow_prob):
    st = video_stage(data, **{"stage1.loss.flow_prob": flow_prob})
    it = 10_000
    draw = replay_sample(st, it)
    i, j = draw["i"], draw["j"]
    assert draw["use_flow"] == (flow_prob == 1.0 and bool(data.flow_targets(i)))
    out = st.losses(it)
    L = out.terms
    nbrs = [k for k in (i - 1, i + 1) if 0 <= k < T]
    with torch.no_grad():
        r = st.render(float(i), [float(j)] + [float(k) for k in nbrs])
        lc = st.loss_cfg
        eq = lambda name, v: torch.testing.assert_close(L[name], v, rtol=1e-6, atol=1e-7)  # noqa: E731
        eq("rgb", rgb_loss(st.tm(r.hdr, data.log2_dt[i]), data.ldr[i], lambda_d=0.2))
        eq("ue", unit_exposure_loss(st.tm.unit_exposure_value(), 0.73))
        eq("dep", depth_loss(r.depth, data.depth[i], valid=r.alpha > 0.5))
        if draw["use_flow"]:
            p = data.flow_pairs.index((i, j))
            pred, v = flow_from_destination_map(r.dest[0], alpha=r.alpha)
            eq("track", flow_loss(pred, data.flow[p], v, norm="l1"))
        else:
            vis = data.track_vis[:, i] & data.track_vis[:, j]
            src, dst = data.tracks[vis, i], data.tracks[vis, j]
            eq("track", track_loss(r.dest[0], src, dst, alpha=r.alpha, norm="l1"))
        ctrl, coeff, knots = st.gauss.params["ctrl"], st.gauss.params["rot"], st.gauss.knots
        sub = draw["sub"]
        p_t = spline.evaluate(ctrl, knots, float(i))
        p_2 = spline.evaluate(ctrl, knots, draw["t2"])
        nb = knn(p_t, lc.arap_k)[0][sub]
        d_t = (p_t[sub][:, None] - p_t[nb]).norm(dim=-1)
        d_2 = (p_2[sub][:, None] - p_2[nb]).norm(dim=-1)
        eq("arap", ((d_t - d_2) ** 2).mean())
        times = torch.arange(max(0, i - 2), min(T, i + 3), dtype=torch.float32)
        pos = spline.evaluate(ctrl[sub], knots, times).transpose(0, 1)
        q = rot.poly_evaluate(coeff[sub], rot.normalize_time(times, T), normalize=True)
        eq("vel", velocity_loss(pos, q.transpose(0, 1)))
        eq("acc", acceleration_loss(pos, q.transpose(0, 1)))
        terms = []
        for n_idx, k in enumerate(nbrs):
            rn = st.render(float(k))
            dm = r.dest[1 + n_idx]
            flow, fv = flow_from_destination_map(dm, alpha=r.alpha)
            z = (dm / r.alpha.clamp_min(1e-6)[..., None])[..., 2]
            valid = fv & tlr_valid_mask(flow, rn.depth, z, ratio=1.1)
            terms.append(tlr_loss(r.hdr, rn.hdr, flow, valid))
        eq("tlr", torch.stack(terms).mean())
    # the render metadata of the query frame comes back with the terms
    assert out.meta.means2d.shape[-2] == st.gauss.num_gaussians
    total = objective.total_loss(L, st.weights())
    manual = sum(st.weights()[k] * float(v.detach()) for k, v in L.items())
    assert float(total.detach()) == pytest.approx(manual, rel=1e-6)


def test_stage1_gradients_reach_the_intended_parameters(data):
    st = video_stage(data, **{"stage1.loss.flow_prob": 0.0})
    g = st.gauss.params
    with torch.no_grad():  # rotating Gaussians (at identity rotations the angles have no slope)
        g["rot"][:, 1:].normal_(0.0, 0.1, generator=torch.Generator().manual_seed(2))
    reseed_for_arap(st, 10_000)
    L = st.losses(10_000).terms
    params = {
        "ctrl": [g["ctrl"]],
        "rot": [g["rot"]],
        "scales": [g["scales"]],
        "opacities": [g["opacities"]],
        "features": [g["features"]],
        "color": list(st.color.parameters()),
        "tonemap": list(st.tm.parameters()),
        "background": list(st.bg.parameters()),
    }
    reach = {
        name: {k for k, v in grads(value, params).items() if v > 0} for name, value in L.items()
    }
    everything = set(params)
    assert reach["rgb"] == everything
    assert reach["ue"] == {"tonemap"}
    # geometry terms never touch appearance
    for name in ("dep", "track"):
        assert reach[name] and not reach[name] & {"features", "color", "tonemap", "background"}
    assert reach["arap"] == {"ctrl"}
    assert reach["vel"] == {"ctrl", "rot"} and reach["acc"] == {"ctrl", "rot"}
    # TLR compares HDR renders: no tone mapper; neighbours and flows are detached
    assert "tonemap" not in reach["tlr"] and {"color", "features"} <= reach["tlr"]


def test_tlr_neighbour_gradient_option(data):
    """loss.tlr_neighbour_grad: off (default), the TLR gradient is that of the term with the
    neighbour renders held constant; on, the neighbour renders' own gradient is added. Both against
    the term rebuilt by hand; the two gradients differ."""
    it, got = 10_000, {}
    for flag in (False, True):
        st = video_stage(
            data, **{"stage1.loss.flow_prob": 0.0, "stage1.loss.tlr_neighbour_grad": flag}
        )
        draw = replay_sample(st, it)
        i, j = draw["i"], draw["j"]
        feats = st.gauss.params["features"]
        g_auto = torch.autograd.grad(st.losses(it).terms["tlr"], feats)[0]
        nbrs = [k for k in (i - 1, i + 1) if 0 <= k < T]
        r = st.render(float(i), [float(j)] + [float(k) for k in nbrs])
        terms = []
        for n_idx, k in enumerate(nbrs):
            rn = st.render(float(k))
            dm, alpha = r.dest[1 + n_idx].detach(), r.alpha.detach()
            flow, fv = flow_from_destination_map(dm, alpha=alpha)
            z = (dm / alpha.clamp_min(1e-6)[..., None])[..., 2]
            valid = fv & tlr_valid_mask(flow, rn.depth.detach(), z, ratio=1.1)
            nb = rn.hdr if flag else rn.hdr.detach()
            terms.append(tlr_loss(r.hdr, nb, flow, valid, detach_neighbour=False))
        g_hand = torch.autograd.grad(torch.stack(terms).mean(), feats)[0]
        torch.testing.assert_close(g_auto, g_hand, rtol=1e-5, atol=1e-9)
        got[flag] = g_auto
    assert float((got[True] - got[False]).abs().max()) > 1e-3 * float(got[False].abs().max())


def _tlr_by_hand(st, it, floor_frac=0.0, shoulder=None):
    """The stage's TLR term at step `it` rebuilt from its renders: the neighbours i +- 1, the
    rendered flow and the depth-order test, |H_w - H| / (H_w + H + floor) with floor = floor_frac x
    the query render's median, over the pixels whose tone-mapped render lies under `shoulder` in
    every channel (None: all). Returns (the term, the fraction of pixels kept)."""
    draw = replay_sample(st, it)
    i, j = draw["i"], draw["j"]
    nbrs = [k for k in (i - 1, i + 1) if 0 <= k < T]
    with torch.no_grad():
        r = st.render(float(i), [float(j)] + [float(k) for k in nbrs])
        floor = floor_frac * float(r.hdr.median())
        keep = torch.ones(r.hdr.shape[:2], dtype=torch.bool)
        if shoulder is not None:
            keep = (st.tm(r.hdr, st.log2_dt[i]) < shoulder).all(-1)
        terms = []
        for n_idx, k in enumerate(nbrs):
            rn = st.render(float(k))
            dm, alpha = r.dest[1 + n_idx], r.alpha
            flow, fv = flow_from_destination_map(dm, alpha=alpha)
            z = (dm / alpha.clamp_min(1e-6)[..., None])[..., 2]
            valid = fv & tlr_valid_mask(flow, rn.depth, z, ratio=1.1) & keep
            warped = backward_warp(rn.hdr, flow)
            err = (warped - r.hdr).abs() / (warped + r.hdr + 1e-10 + floor)
            m = (valid & flow_in_bounds(flow))[..., None].float()
            terms.append((err * m).sum() / (m.sum() * 3))
    return float(torch.stack(terms).mean()), float(keep.float().mean())


def test_tlr_denominator_floor_option(data):
    """loss.tlr_den_floor: the stage's TLR term is the term rebuilt by hand with the floor
    fraction x the query render's median in every neighbour's denominator; 0 is the paper's."""
    it = 10_000
    for frac in (0.0, 0.05):
        st = video_stage(data, **{"stage1.loss.flow_prob": 0.0, "stage1.loss.tlr_den_floor": frac})
        want, _ = _tlr_by_hand(st, it, floor_frac=frac)
        got = st.losses(it).terms["tlr"]
        assert float(got.detach()) == pytest.approx(want, rel=1e-5)


def test_tlr_shoulder_option(data):
    """loss.tlr_shoulder: the stage's TLR term is the term rebuilt by hand over the pixels whose
    tone-mapped render at the query frame's exposure lies under the shoulder in every channel; the
    shoulder is put at the render's median so that about half the pixels leave the term, and None
    (the paper's) keeps them all."""
    it = 10_000
    st = video_stage(data, **{"stage1.loss.flow_prob": 0.0})
    i = replay_sample(st, it)["i"]
    with torch.no_grad():
        ldr = st.tm(st.render(float(i)).hdr, st.log2_dt[i])
    shoulder = float(ldr.amax(-1).median())
    kept = []
    for value in (None, shoulder):
        st = video_stage(data, **{"stage1.loss.flow_prob": 0.0, "stage1.loss.tlr_shoulder": value})
        want, frac = _tlr_by_hand(st, it, shoulder=value)
        kept.append(frac)
        got = st.losses(it).terms["tlr"]
        assert float(got.detach()) == pytest.approx(want, rel=1e-5)
    assert kept[0] == 1.0 and 0.2 < kept[1] < 0.8


def test_shoulder_keep():
    """Under the shoulder in every channel, without gradient; None keeps no mask."""
    ldr = torch.tensor(
        [[[0.1, 0.2, 0.3], [0.1, 0.99, 0.3]], [[0.98, 0.5, 0.5], [0.97, 0.97, 0.97]]]
    )
    ldr.requires_grad_(True)
    keep = objective.shoulder_keep(ldr, 0.98)
    assert keep.tolist() == [[True, False], [False, True]] and not keep.requires_grad
    assert objective.shoulder_keep(ldr, None) is None


def test_stage1_step_densifies_through_the_strategy_and_records(data):
    st = video_stage(data)
    rec = st.step(0)
    assert {"rgb", "total", "num_gaussians"} <= set(rec)
    assert st.dstate["count"] is not None  # the strategy saw this step's means2d gradient
    assert float(st.dstate["count"].sum()) > 0


# --------------------------------------------------------------------------------------------------
# stage 2
# --------------------------------------------------------------------------------------------------
def world_stage(data, n_static: int = 24, n_dynamic: int = 12, **overrides) -> WorldStage:
    torch.manual_seed(1)
    cfg = tiny_config(**overrides)
    K = torch.as_tensor(K_from_fov(W, H, 60.0)).float()
    c2w = torch.eye(4).expand(T, 4, 4).clone()
    c2w[:, 0, 3] = torch.linspace(0, 0.3, T)
    depth_scale = torch.full((T,), 1.5)
    F = cfg.model.feature_dim
    xy = (torch.rand(n_static, 2) - 0.5) * torch.tensor([2.5, 1.8])
    static = {
        "means": torch.cat([xy, 3.0 + torch.rand(n_static, 1)], -1),
        "quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(n_static, 1),
        "scales": torch.full((n_static, 3), math.log(0.2)),
        "opacities": torch.full((n_static,), 2.0),
        "features": torch.randn(n_static, F),
    }
    knots = torch.tensor([0.0, 2.0, 4.0, float(T - 1)])
    ctrl = torch.cat([(torch.rand(n_dynamic, 1, 2) - 0.5), torch.full((n_dynamic, 1, 1), 2.5)], -1)
    ctrl = ctrl + torch.linspace(0, 0.3, len(knots))[None, :, None] * torch.rand(n_dynamic, 1, 3)
    coeff = torch.zeros(n_dynamic, 4, 4)
    coeff[:, 0, 0] = 1.0
    coeff[:, 1, 1] = 0.1 * torch.rand(n_dynamic)
    dynamic = {
        "ctrl": ctrl,
        "rot": coeff,
        "scales": torch.full((n_dynamic, 3), math.log(0.15)),
        "opacities": torch.full((n_dynamic,), 2.0),
        "features": torch.randn(n_dynamic, F),
    }
    k = cfg.model.appearance_knots
    if k:  # a gain over time (beyond the paper): random curves, from their own generator
        gen = torch.Generator().manual_seed(7)
        static[GAIN_KEY] = 0.5 * torch.randn(n_static, k, generator=gen)
        dynamic[GAIN_KEY] = 0.5 * torch.randn(n_dynamic, k, generator=gen)
    g = WorldGaussians(static, dynamic, knots, T, "exp", 1.0)
    color, tm, bg = build_appearance(cfg, 0.73, "cpu", pretrain=False)
    stage1_hdr = torch.rand(T, H, W, 3) + 0.1
    masks = torch.zeros(T, H, W, dtype=torch.bool)
    masks[:, :4] = True
    init = WorldInit(g, color, tm, bg, K, c2w, depth_scale, masks, stage1_hdr)
    return WorldStage(data, cfg, init, "cpu", BACKEND)


FULL2 = ["rgb", "ue", "dep", "track", "arap", "vel", "acc", "tlr", "pr"]


def test_stage2_terms_follow_weights_ablations_and_method(data):
    late = 10_000
    st = world_stage(data)
    assert list(st.losses(late).terms) == FULL2
    assert list(st.losses(0).terms) == [n for n in FULL2 if n != "tlr"]
    assert "pr" not in world_stage(data, **{"stage2.pr_steps": 5}).losses(5).terms
    assert "pr" in world_stage(data, **{"stage2.pr_steps": 5}).losses(4).terms
    assert "pr" not in world_stage(data, **{"ablation.reproj_loss": False}).losses(late).terms
    assert "pr" not in world_stage(data, **{"stage2.lambda_pr": 0.0}).losses(late).terms
    assert "pr" not in world_stage(data, **{"stage2.optimize_cameras": False}).losses(late).terms
    assert "dep" not in world_stage(data, **{"stage2.loss.lambda_dep": 0.0}).losses(late).terms
    # too few dynamic Gaussians for ARAP: no motion regularisers (and no draws for them)
    few = world_stage(data, n_dynamic=3).losses(late).terms
    assert not {"arap", "vel", "acc"} & set(few) and "track" in few
    # the static baseline: no motion, fixed cameras
    static = world_stage(data, method="static-hdr").losses(late).terms
    assert list(static) == ["rgb", "ue", "dep"]
    # the LDR reprojection baseline replaces L_pr by its LDR term (also named "pr")
    ldr = world_stage(data, method="ldr-reproj").losses(late).terms
    assert "pr" in ldr
    assert world_stage(data).weights()["pr"] == 1.0


@pytest.mark.parametrize("flow_prob", [1.0, 0.0])
def test_stage2_term_values_recomputed(data, flow_prob):
    st = world_stage(data, **{"stage2.loss.flow_prob": flow_prob})
    it = 10_000
    draw = replay_sample(st, it)
    i, j = draw["i"], draw["j"]
    assert draw["use_flow"] == (flow_prob == 1.0)
    out = st.losses(it)
    L = out.terms
    nbrs = [k for k in (i - 1, i + 1) if 0 <= k < T]
    ext = st.extent
    assert ext == pytest.approx(1.5 * float(data.depth.median()), rel=1e-6)
    eq = lambda name, v: torch.testing.assert_close(L[name], v, rtol=1e-5, atol=1e-7)  # noqa: E731
    with torch.no_grad():
        c2w = st.rig.c2w()
        w2c = cam.invert_rigid(c2w)
        K = st.rig.K
        dests = [float(j)] + [float(k) for k in nbrs]
        r = st.render_at(float(i), c2w[i], dest_times=dests)
        eq("rgb", rgb_loss(st.tm(r.hdr, data.log2_dt[i]), data.ldr[i], lambda_d=0.2))
        eq("ue", unit_exposure_loss(st.tm.unit_exposure_value(), 0.73))
        prior = data.depth[i] * 1.5
        eq("dep", depth_loss(r.depth, prior, valid=r.alpha > 0.5) / ext)
        if draw["use_flow"]:
            p = data.flow_pairs.index((i, j))
            pred, v = flow_from_destination_map(r.dest[0], K=K, w2c_dst=w2c[j], alpha=r.alpha)
            eq("track", flow_loss(pred, data.flow[p], v, norm="l1"))
        else:
            vis = data.track_vis[:, i] & data.track_vis[:, j]
            src, dst = data.tracks[vis, i], data.tracks[vis, j]
            expect = track_loss(r.dest[0], src, dst, K=K, w2c_dst=w2c[j], alpha=r.alpha)
            eq("track", expect)
        ctrl, coeff, knots = st.gauss.dynamic["ctrl"], st.gauss.dynamic["rot"], st.gauss.knots
        sub = draw["sub"]
        p_t = spline.evaluate(ctrl, knots, float(i))
        p_2 = spline.evaluate(ctrl, knots, draw["t2"])
        nb = knn(p_t, 5)[0][sub]
        d_t = (p_t[sub][:, None] - p_t[nb]).norm(dim=-1)
        d_2 = (p_2[sub][:, None] - p_2[nb]).norm(dim=-1)
        eq("arap", ((d_t - d_2) ** 2).mean() / ext**2)
        times = torch.arange(max(0, i - 2), min(T, i + 3), dtype=torch.float32)
        pos = spline.evaluate(ctrl[sub], knots, times).transpose(0, 1) / ext
        q = rot.poly_evaluate(coeff[sub], rot.normalize_time(times, T), normalize=True)
        eq("vel", velocity_loss(pos, q.transpose(0, 1)))
        eq("acc", acceleration_loss(pos, q.transpose(0, 1)))
        terms = []
        for n_idx, k in enumerate(nbrs):
            rn = st.render_at(float(k), c2w[k])
            dm = r.dest[1 + n_idx]
            flow, fv = flow_from_destination_map(dm, K=K, w2c_dst=w2c[k], alpha=r.alpha)
            z = cam.transform_points(w2c[k], dm / r.alpha.clamp_min(1e-6)[..., None])[..., 2]
            valid = fv & tlr_valid_mask(flow, rn.depth, z, ratio=1.1)
            terms.append(tlr_loss(r.hdr, rn.hdr, flow, valid))
        eq("tlr", torch.stack(terms).mean())
        refs = [i + o for off in (1, 2) for o in (-off, off) if 0 <= i + o < T]
        hdr1 = st.stage1_hdr
        pr = [
            hdr_reprojection_loss(hdr1[i], hdr1[k], r.depth, K, c2w[i], c2w[k], st.dynamic_masks[i])
            for k in refs
        ]
        eq("pr", torch.stack(pr).mean())
    assert out.meta.means2d.shape[-2] == st.gauss.num_gaussians


def test_stage2_gradients_reach_the_intended_parameters(data):
    st = world_stage(data, **{"stage2.loss.flow_prob": 1.0})
    reseed_for_arap(st, 10_000)
    L = st.losses(10_000).terms
    gs, gd = st.gauss.static, st.gauss.dynamic
    params = {
        "static_means": [gs["means"]],
        "static_features": [gs["features"]],
        "ctrl": [gd["ctrl"]],
        "rot": [gd["rot"]],
        "color": list(st.color.parameters()),
        "tonemap": list(st.tm.parameters()),
        "camera": [st.rig.dw, st.rig.dt],
    }
    reach = {
        name: {k for k, v in grads(value, params).items() if v > 0} for name, value in L.items()
    }
    assert {"color", "tonemap", "camera", "static_features"} <= reach["rgb"]
    assert reach["ue"] == {"tonemap"}
    for name in ("dep", "track"):
        assert "camera" in reach[name] and not reach[name] & {"color", "tonemap", "static_features"}
    assert reach["arap"] == {"ctrl"}
    assert reach["vel"] == {"ctrl", "rot"} and reach["acc"] == {"ctrl", "rot"}
    assert "tonemap" not in reach["tlr"] and "color" in reach["tlr"]
    # L_pr from two stage-1 frames: cameras and rendered depth only, never colours
    assert "camera" in reach["pr"] and not reach["pr"] & {"color", "tonemap", "static_features"}


def test_stage2_step_uses_both_strategies(data):
    st = world_stage(data)
    rec = st.step(0)
    assert {"rgb", "total", "num_gaussians", "num_dynamic"} <= set(rec)
    for state, n in ((st.state_static, 24), (st.state_dynamic, 12)):
        assert state["count"] is not None and state["count"].shape == (n,)


def test_smooth_window_frames():
    """Half width w: frames i - w .. i + w cut at the clip's ends; -1: every frame (paper)."""
    assert objective.smooth_window(3, 10, 2) == (1, 6)
    assert objective.smooth_window(0, 10, 2) == (0, 3)
    assert objective.smooth_window(9, 10, 1) == (8, 10)
    assert objective.smooth_window(4, 10, -1) == (0, 10)


def test_paper_form_of_the_smoothness_terms(data):
    """smooth_half_width = -1 and motion_subset = 0: velocity / acceleration summed over every frame
    and averaged over every moving Gaussian (the paper's form), recomputed independently."""
    st = video_stage(data, **{"stage1.loss.smooth_half_width": -1, "stage1.loss.motion_subset": 0})
    L = st.losses(10_000).terms
    ctrl, coeff, knots = st.gauss.params["ctrl"], st.gauss.params["rot"], st.gauss.knots
    times = torch.arange(T, dtype=torch.float32)
    with torch.no_grad():
        pos = spline.evaluate_reference(ctrl, knots, times).transpose(0, 1)  # [T, N, 3]
        q = rot.poly_evaluate(coeff, rot.normalize_time(times, T), normalize=True).transpose(0, 1)
        # the Gaussians' order does not matter for a mean over all of them
        torch.testing.assert_close(L["vel"], velocity_loss(pos, q), rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(L["acc"], acceleration_loss(pos, q), rtol=1e-5, atol=1e-6)


def test_view_dependent_colour_option_reaches_the_stages(data):
    assert not video_stage(data).color.view_dependent
    st = video_stage(data, **{"tonemap.color_view_dependent": True})
    assert st.color.view_dependent
    # stage 1 renders through the orthographic camera: the direction weights get no gradient
    L = st.losses(10_000)
    g = torch.autograd.grad(L.terms["rgb"], st.color.fc1.weight)[0]
    assert g[:, -3:].abs().max() == 0 and g[:, :-3].abs().max() > 0
    # stage 2 renders through pinhole cameras: they do
    ws = world_stage(data, **{"tonemap.color_view_dependent": True})
    assert ws.color.view_dependent
    g = torch.autograd.grad(ws.losses(10).terms["rgb"], ws.color.fc1.weight)[0]
    assert g[:, -3:].abs().max() > 0
    # the reflected direction (beyond the paper) reaches both stages' MLPs, and stage 2's sees it
    kw = {"tonemap.color_view_dependent": True, "tonemap.color_direction": "reflected"}
    ws = world_stage(data, **kw)
    assert ws.color.direction == video_stage(data, **kw).color.direction == "reflected"
    g = torch.autograd.grad(ws.losses(10).terms["rgb"], ws.color.fc1.weight)[0]
    assert g[:, -3:].abs().max() > 0
    # with the specular lobe (beyond the paper) its head learns in stage 2 only
    kw["tonemap.color_specular"] = True
    st = video_stage(data, **kw)
    g = torch.autograd.grad(st.losses(10_000).terms["rgb"], st.color.spec.weight, allow_unused=True)
    assert g[0] is None or g[0].abs().max() == 0
    ws = world_stage(data, **kw)
    g = torch.autograd.grad(ws.losses(10).terms["rgb"], ws.color.spec.weight)[0]
    assert g.abs().max() > 0


def test_a_non_finite_loss_stops_training_naming_stage_step_and_term(data):
    from m4dgs.core.errors import NonFiniteError

    st = video_stage(data)
    st.step(0)
    with torch.no_grad():
        st.gauss.params["features"].fill_(float("nan"))  # every colour NaN -> rgb loss NaN
    before = {k: v.detach().clone() for k, v in st.gauss.params.items() if k != "features"}
    with pytest.raises(NonFiniteError, match=r"stage1: step 1: non-finite loss \(rgb=nan"):
        st.step(1)
    # it stops before any optimiser step: the other parameters have not moved
    for k, v in before.items():
        assert torch.equal(st.gauss.params[k].detach(), v), k


def test_a_non_finite_parameter_stops_training_naming_it(data):
    from m4dgs.core.errors import NonFiniteError

    st = video_stage(data)
    st.check_parameters(0)  # finite: nothing
    with torch.no_grad():
        st.gauss.params["ctrl"][3, 0, 0] = float("inf")
    with pytest.raises(NonFiniteError, match=r"stage1: step 7: parameter n_ctrl holds NaN"):
        st.check_parameters(7)
    ws = world_stage(data)
    with torch.no_grad():
        ws.rig.dt[2, 1] = float("nan")
    with pytest.raises(NonFiniteError, match=r"stage2: step 0: parameter rig\.dt holds NaN"):
        ws.check_parameters(0)


def test_an_overflowing_hdr_render_stops_training_naming_stage_and_step(data):
    """An HDR value beyond float32's range (here every colour 2^200) reaching the tone mapper's
    table stops the step with the stage and step named, not an out-of-range table index."""
    from m4dgs.core.errors import NonFiniteError

    # a table of 64 nodes: the tiny frames (32 x 24 x 3 values) take the table path
    st = video_stage(data, **{"tonemap.lut_size": 64})
    st.step(0)
    with torch.no_grad():
        st.color.fc2.bias.fill_(200.0)  # finite parameters, 2^200 overflows float32
    with pytest.raises(NonFiniteError, match=r"stage1: step 1: the tone mapper's input .* spans"):
        st.step(1)


def test_blank_and_saturated_frames_are_found():
    from m4dgs.core.errors import InputError
    from m4dgs.training.data import blank_frames, check_frame_content

    rng = np.random.default_rng(0)
    ldr = rng.integers(0, 256, size=(4, 20, 30, 3), dtype=np.uint8)
    ldr[1] = 0
    ldr[1, 0, :5] = 200  # 5 of 600 pixels lit: still blank (> 98 % black)
    ldr[3] = 255
    assert blank_frames(ldr) == ([1], [3])
    with pytest.warns(
        RuntimeWarning, match=r"2 of 4 training frames are blank .*black: \[12\]; saturated: \[16\]"
    ):
        check_frame_content(ldr, [10, 12, 14, 16], "clip/input/ldr")
    with pytest.raises(InputError, match="4 of 4 training frames .* nothing to train on"):
        check_frame_content(np.zeros_like(ldr), [10, 12, 14, 16], "clip/input/ldr")


def test_too_few_training_frames_or_an_unseen_level_is_refused():
    from m4dgs.core.errors import InputError
    from m4dgs.training.data import check_enough_frames

    check_enough_frames([0.125, 2.0, 32.0], [0.125, 2.0, 32.0], "clip.json")  # fine
    with pytest.raises(InputError, match=r"clip.json: split.train has 2 training frames; .* 3"):
        check_enough_frames([0.125, 2.0], [0.125, 2.0], "clip.json")
    with pytest.raises(InputError, match=r"exposures.observed lists \[32.0\], which no training"):
        check_enough_frames([0.125, 2.0, 0.125, 2.0], [0.125, 2.0, 32.0], "clip.json")
    # random-values: the exposures lie between the levels by design
    check_enough_frames([0.2, 1.7, 9.0, 0.4], [0.125, 2.0, 32.0], "clip.json", "random-values")


# device reads of a training step: on CUDA each one (float(t), bool(t), int(t), .item(), .tolist(),
# nonzero) waits for the GPU, so the CPU cannot queue the next kernels meanwhile
_READS = ("__float__", "__bool__", "__int__", "__index__", "item", "tolist", "nonzero")
# not counted: the spline's column narrowing (CPU tensors only) and the rasterizers (their reads are
# the backend's own: gsplat's on CUDA, which the GPU profile of bench/step_bench.py counts)
_NOT_COUNTED = ("core/spline.py", "raster/")


def _count_device_reads(fn):
    """(result, {call site: reads}) of fn(), counting the reads on paths that also run on CUDA."""
    import traceback
    from collections import Counter

    sites: Counter = Counter()
    saved = {n: getattr(torch.Tensor, n) for n in _READS}
    saved_nz = torch.nonzero

    def site():
        frames = [f for f in traceback.extract_stack()[:-2] if "/m4dgs/" in f.filename]
        return f"{frames[-1].filename.split('/m4dgs/')[-1]}:{frames[-1].lineno}" if frames else ""

    def wrap(orig):
        def f(*a, **k):
            s = site()
            if s and not s.startswith(_NOT_COUNTED):
                sites[s] += 1
            return orig(*a, **k)

        return f

    try:
        for n, orig in saved.items():
            setattr(torch.Tensor, n, wrap(orig))
        torch.nonzero = wrap(saved_nz)
        out = fn()
    finally:
        for n, orig in saved.items():
            setattr(torch.Tensor, n, orig)
        torch.nonzero = saved_nz
    return out, sites


def test_a_training_step_reads_the_device_a_few_times(data):
    """A stage-1 and a stage-2 step (TLR on, no densification this step) read values from the
    device at most 4 times: the logged losses in one read, the tone mapper's input range in one,
    and a validity test or two. Each read waits for the GPU on CUDA; the logged losses alone were
    9 reads (counted here with the Tensor methods wrapped; _NOT_COUNTED says what is left out)."""
    for make, it in ((video_stage, 2_500), (world_stage, 2_000)):
        st = make(data)
        assert it >= st.tlr_start_step()
        st.step(it)  # first step: lazy set-up outside the count
        rec, sites = _count_device_reads(lambda st=st, it=it: st.step(it + 1))
        assert "total" in rec and "tlr" in rec, rec
        assert sum(sites.values()) <= 4, dict(sites)
        assert all(n == 1 for n in sites.values()), dict(sites)


def test_the_tone_mapper_table_reads_its_input_range_once():
    """ToneMapper.curve_lut spans its table over the input's range with one read from the device
    (the min and max together), and gives the table's values: against the exact curve."""
    from m4dgs.model.tonemap import ToneMapper

    tm = ToneMapper(hidden=16, generator=torch.Generator().manual_seed(0))
    z = torch.linspace(-3.0, 2.0, 300).reshape(100, 3)
    out, sites = _count_device_reads(lambda: tm.curve_lut(z))
    assert list(sites.values()) == [1] and next(iter(sites)).startswith("model/tonemap.py:"), sites
    torch.testing.assert_close(out, tm.curve(z), rtol=0, atol=1e-4)


@pytest.mark.parametrize("bad", [float("inf"), float("-inf"), float("nan")])
def test_the_tone_mapper_table_refuses_non_finite_input(bad):
    """A NaN or infinite input would give a NaN table position, cast to an out-of-range index:
    the table path raises NonFiniteError instead; finite inputs are unaffected (test above)."""
    from m4dgs.core.errors import NonFiniteError
    from m4dgs.model.tonemap import ToneMapper

    tm = ToneMapper(hidden=16, generator=torch.Generator().manual_seed(0))
    z = torch.linspace(-3.0, 2.0, 300).reshape(100, 3)
    z[17, 1] = bad
    with pytest.raises(NonFiniteError, match="tone mapper's input"):
        tm.curve_lut(z)


# --------------------------------------------------------------------------------------------------
# the brightness gain over time (beyond the paper: model.appearance_knots)
# --------------------------------------------------------------------------------------------------
PAPER_SPLINE = {"ctrl", "rot", "scales", "opacities", "features"}
PAPER_STATIC = {"means", "quats", "scales", "opacities", "features"}


def test_without_the_gain_the_stages_optimise_and_save_the_paper_parameters(data):
    st = video_stage(data)
    assert st.cfg.model.appearance_knots == 0
    sd = st.state_dict()
    assert set(sd["optimizers"]) == PAPER_SPLINE | {"color", "tonemap", "background"}
    assert set(sd["gaussians"]["params"]) == PAPER_SPLINE
    assert "gain_smooth" not in st.losses(10_000).terms
    ws = world_stage(data)
    sd = ws.state_dict()
    assert set(sd["opt_static"]) == PAPER_STATIC and set(sd["opt_dynamic"]) == PAPER_SPLINE
    assert set(sd["gaussians"]["static"]) == PAPER_STATIC
    assert set(sd["gaussians"]["dynamic"]) == PAPER_SPLINE
    assert list(ws.losses(10_000).terms) == FULL2


def test_the_gain_is_optimised_regularised_and_saved_in_both_stages(data):
    k = 4
    st = video_stage(data, **{"model.appearance_knots": k})
    gain = st.gauss.params[GAIN_KEY]
    assert gain.shape == (st.gauss.num_gaussians, k) and not gain.any()  # zeros at the start
    with torch.no_grad():
        gain.normal_(0.0, 0.5, generator=torch.Generator().manual_seed(3))
    L = st.losses(10_000).terms
    assert list(L) == ["rgb", "ue", "dep", "track", "arap", "vel", "acc", "tlr", "gain_smooth"]
    v = gain.detach().double()
    d2 = v[:, 2:] - 2 * v[:, 1:-1] + v[:, :-2]
    assert float(L["gain_smooth"].detach()) == pytest.approx(float((d2**2).mean()), rel=1e-6)
    assert st.weights()["gain_smooth"] == 0.1
    # the photometric terms reach the gain, the geometry terms do not
    assert float(torch.autograd.grad(L["rgb"], gain, retain_graph=True)[0].abs().sum()) > 0
    assert float(torch.autograd.grad(L["tlr"], gain, retain_graph=True)[0].abs().sum()) > 0
    g_dep = torch.autograd.grad(L["dep"], gain, retain_graph=True, allow_unused=True)[0]
    assert g_dep is None or not g_dep.any()
    # its own Adam at lr.gain; a step moves it; weight 0 drops the term
    assert st.optimizers[GAIN_KEY].param_groups[0]["lr"] == 1e-2
    before = gain.detach().clone()
    st.step(10_000)
    assert not torch.equal(st.gauss.params[GAIN_KEY].detach(), before)
    off = video_stage(data, **{"model.appearance_knots": k, "stage1.loss.lambda_gain_smooth": 0})
    assert "gain_smooth" not in off.losses(10_000).terms
    # a checkpoint holds the gain and its optimiser state, and loads back
    sd = st.state_dict()
    assert GAIN_KEY in sd["gaussians"]["params"] and GAIN_KEY in sd["optimizers"]
    st2 = video_stage(data, **{"model.appearance_knots": k})
    st2.load_state_dict(sd)
    assert torch.equal(st2.gauss.params[GAIN_KEY], st.gauss.params[GAIN_KEY])
    s_a, s_b = st.optimizers[GAIN_KEY].state_dict(), st2.optimizers[GAIN_KEY].state_dict()
    assert torch.equal(s_a["state"][0]["exp_avg"], s_b["state"][0]["exp_avg"])
    # stage 2: both sets, one term over the union, the static and dynamic optimisers
    ws = world_stage(data, **{"model.appearance_knots": k})
    L = ws.losses(10_000).terms
    assert list(L) == FULL2 + ["gain_smooth"]
    v = ws.gauss.gain_values().detach().double()
    d2 = v[:, 2:] - 2 * v[:, 1:-1] + v[:, :-2]
    assert float(L["gain_smooth"].detach()) == pytest.approx(float((d2**2).mean()), rel=1e-6)
    gs, gd = ws.gauss.static[GAIN_KEY], ws.gauss.dynamic[GAIN_KEY]
    g_s, g_d = torch.autograd.grad(L["rgb"], [gs, gd], retain_graph=True)
    assert float(g_s.abs().sum()) > 0 and float(g_d.abs().sum()) > 0
    assert GAIN_KEY in ws.opt_static and GAIN_KEY in ws.opt_dynamic
    ws.step(0)
    sd = ws.state_dict()
    assert GAIN_KEY in sd["opt_static"] and GAIN_KEY in sd["opt_dynamic"]
    assert GAIN_KEY in sd["gaussians"]["static"] and GAIN_KEY in sd["gaussians"]["dynamic"]
    ws2 = world_stage(data, **{"model.appearance_knots": k})
    ws2.load_state_dict(sd)
    assert torch.equal(ws2.gauss.gain_values(), ws.gauss.gain_values())


def test_the_dynamic_sets_gain_can_have_its_own_rate(data):
    """stage2.lr.dynamic_gain (beyond the paper) sets the rate of the dynamic set's gain knots only;
    unset, both sets step at lr.gain. Adam's first step moves every parameter with a gradient by
    its rate (m / sqrt(v) = sign(g) after the bias correction), so the knots' largest move is
    each set's rate."""
    ws = world_stage(data, **{"model.appearance_knots": 4})
    assert ws.opt_static[GAIN_KEY].param_groups[0]["lr"] == 1e-2
    assert ws.opt_dynamic[GAIN_KEY].param_groups[0]["lr"] == 1e-2
    ws = world_stage(data, **{"model.appearance_knots": 4, "stage2.lr.dynamic_gain": 0.1})
    assert ws.opt_static[GAIN_KEY].param_groups[0]["lr"] == 1e-2
    assert ws.opt_dynamic[GAIN_KEY].param_groups[0]["lr"] == 0.1
    s0 = ws.gauss.static[GAIN_KEY].detach().clone()
    d0 = ws.gauss.dynamic[GAIN_KEY].detach().clone()
    ws.step(0)
    ds = (ws.gauss.static[GAIN_KEY].detach() - s0).abs()
    dd = (ws.gauss.dynamic[GAIN_KEY].detach() - d0).abs()
    assert float(ds.max()) == pytest.approx(1e-2, rel=1e-3)
    assert float(dd.max()) == pytest.approx(0.1, rel=1e-3)


def test_gaussians_of_another_gain_setting_are_refused(data):
    ws = world_stage(data, **{"model.appearance_knots": 4})
    with pytest.raises(ValueError, match=r"stage 2: .* 4 knots, .*model\.appearance_knots = 0"):
        world_stage(data)._setup(ws.gauss, ws.color, ws.tm, ws.bg)
    st = video_stage(data)  # no gain
    cfg = tiny_config(**{"model.appearance_knots": 3})
    with pytest.raises(ValueError, match="stage 1: the Gaussians carry a gain with 0 knots"):
        VideoStage(data, cfg, "cpu", BACKEND, init=False)._setup(st.gauss, st.color, st.tm, st.bg)


def test_flat_term_is_smallest_over_largest_scale():
    """loss.lambda_flat's term (beyond the paper): a disc 0, a ball 1, a mean over Gaussians; its
    gradient against a central finite difference, and a step down it flattens every Gaussian."""
    from m4dgs.training.objective import flat_term

    class _G:
        def __init__(self, s):
            self.s = s

        def scales(self):
            return self.s

    s = torch.tensor([[1.0, 2.0, 4.0], [3.0, 3.0, 3.0], [0.0, 1.0, 2.0]], dtype=torch.float64)
    name, v = flat_term(_G(s))
    assert name == "flat"
    torch.testing.assert_close(v, torch.tensor((0.25 + 1.0 + 0.0) / 3, dtype=torch.float64))
    x = torch.tensor([[0.5, 0.9, 1.7], [1.1, 0.4, 0.6]], dtype=torch.float64, requires_grad=True)
    flat_term(_G(x))[1].backward()
    num = torch.zeros_like(x)
    with torch.no_grad():
        for i in range(2):
            for j in range(3):
                e = torch.zeros_like(x)
                e[i, j] = 1e-6
                num[i, j] = (flat_term(_G(x + e))[1] - flat_term(_G(x - e))[1]) / 2e-6
    torch.testing.assert_close(x.grad, num, rtol=1e-6, atol=1e-9)
    with torch.no_grad():
        y = x - 0.1 * x.grad
        ratio = lambda a: a.min(-1).values / a.max(-1).values  # noqa: E731
        assert (ratio(y) < ratio(x)).all()
