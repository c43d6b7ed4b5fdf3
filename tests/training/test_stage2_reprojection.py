"""Where the stage-2 HDR photometric reprojection loss sends its gradient
(m4dgs.training.stage2.WorldStage, stage2.pr_query).

With the paper's choice ("stage1": both HDR images are stage-1 frames with stopped gradients) L_pr
can only move the cameras and the rendered depth, never the colours; with "render" (stage-2 render
at t) the colour MLP gets a gradient."""

import math

import pytest
import torch

from m4dgs.core.camera import K_from_fov
from m4dgs.training.config import preset


def _stage(clip_dir, pr_query: str):
    from m4dgs.clip import Clip
    from m4dgs.model.gaussians import WorldGaussians
    from m4dgs.training.data import load_training_data
    from m4dgs.training.stage1 import build_appearance
    from m4dgs.training.stage2 import WorldInit, WorldStage

    torch.manual_seed(0)
    d = load_training_data(Clip.open(clip_dir))
    cfg = preset("tiny")
    cfg.stage2.pr_query = pr_query
    cfg.stage2.pr_steps = None
    T = d.num_frames
    K = torch.as_tensor(K_from_fov(d.width, d.height, 60.0)).float()
    c2w = torch.eye(4).expand(T, 4, 4).clone()
    c2w[:, 0, 3] = torch.linspace(0, 0.3, T)  # sideways motion: parallax, so poses and depth matter
    depth_scale = torch.full((T,), 3.0 / float(d.depth[d.depth > 0].median()))
    # a wall of static Gaussians at depths 2.5 .. 3.5 covering the view
    ny, nx = 10, 16
    ys, xs = torch.meshgrid(
        torch.linspace(-1.2, 1.2, ny), torch.linspace(-2.0, 2.0, nx), indexing="ij"
    )
    zs = 3.0 + 0.5 * torch.sin(xs * 2.0)
    n = ny * nx
    F = cfg.model.feature_dim
    static = {
        "means": torch.stack([xs, ys, zs], -1).reshape(n, 3),
        "quats": torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        "scales": torch.full((n, 3), math.log(0.15)),
        "opacities": torch.full((n,), 3.0),
        "features": torch.randn(n, F),
    }
    knots = torch.tensor([0.0, float(T - 1)])
    dynamic = {
        "ctrl": torch.zeros(0, 2, 3),
        "rot": torch.zeros(0, 4, 4),
        "scales": torch.zeros(0, 3),
        "opacities": torch.zeros(0),
        "features": torch.zeros(0, F),
    }
    g = WorldGaussians(
        static, dynamic, knots, T, cfg.model.world_scale_activation, cfg.model.world_scale_max
    )
    color, tm, bg = build_appearance(cfg, 0.73, "cpu", pretrain=False)
    stage1_hdr = torch.rand(T, d.height, d.width, 3) + 0.1  # stands in for the stage-1 HDR video
    return WorldStage(d, cfg, WorldInit(g, color, tm, bg, K, c2w, depth_scale, None, stage1_hdr))


def _grads_of_pr(st):
    L = st.losses(0).terms
    assert "pr" in L and float(L["pr"].detach()) > 0
    params = {
        "color": list(st.color.parameters()),
        "features": [st.gauss.static["features"]],
        "means": [st.gauss.static["means"]],
        "camera": [st.rig.dw, st.rig.dt],
    }
    flat = [p for ps in params.values() for p in ps]
    gs = torch.autograd.grad(L["pr"], flat, allow_unused=True)
    out, k = {}, 0
    for name, ps in params.items():
        out[name] = sum(float(g.abs().sum()) if g is not None else 0.0 for g in gs[k : k + len(ps)])
        k += len(ps)
    return out


def test_pr_from_stage1_frames_moves_only_cameras_and_depth(tiny_clip_realistic):
    g = _grads_of_pr(_stage(tiny_clip_realistic, "stage1"))
    assert g["color"] == 0.0 and g["features"] == 0.0
    assert g["camera"] > 0.0 and g["means"] > 0.0


def test_pr_against_the_render_also_pulls_colours(tiny_clip_realistic):
    g = _grads_of_pr(_stage(tiny_clip_realistic, "render"))
    assert g["color"] > 0.0 and g["features"] > 0.0 and g["camera"] > 0.0


def test_pr_query_is_validated(tiny_clip_realistic):
    with pytest.raises(ValueError, match="pr_query"):
        _stage(tiny_clip_realistic, "video")


def test_bad_option_values_fail_before_training(tiny_clip_realistic, tmp_path):
    from m4dgs.training.pipeline import train

    for key, value in (("stage2.pr_query", "video"), ("masks.method", "optical")):
        run = tmp_path / key
        with pytest.raises(ValueError, match=key.split(".")[1]):
            train(tiny_clip_realistic, run, preset="tiny", overrides={key: value}, progress=False)
        assert not (run / "status.json").exists() and not (run / "model").exists()
