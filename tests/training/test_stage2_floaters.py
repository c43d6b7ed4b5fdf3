"""Near-camera floater removal of stage 2 (m4dgs.training.stage2.near_camera_gaussians,
WorldStage.remove_near_camera_dynamic).

Independent answers: hand-placed points in front of, behind and beside known cameras; a dynamic
Gaussian whose control point swoops to the camera at one knot."""

import torch

from m4dgs.core.camera import K_from_fov
from m4dgs.training.config import preset

W, H = 80, 60


def test_near_camera_gaussians_analytic_cases():
    from m4dgs.training.stage2 import near_camera_gaussians

    K = torch.as_tensor(K_from_fov(W, H, 60.0)).float()
    f = float(K[0, 0])
    eye = torch.eye(4).expand(2, 4, 4).clone()
    back = eye.clone()
    back[1, :3, :3] = torch.diag(torch.tensor([-1.0, 1.0, -1.0]))  # camera 1 looks down -z
    x_out = (W + 0.25 * W - K[0, 2]) / f * 0.5  # projects 0.25 W right of the frame at z = 0.5
    pts = torch.tensor(
        [
            [[0.0, 0.0, 0.5], [0.0, 0.0, 5.0]],  # near at sample 0
            [[0.0, 0.0, 5.0], [0.0, 0.0, 5.0]],  # far
            [[0.0, 0.0, -0.5], [0.0, 0.0, -5.0]],  # behind camera 0; far in front of camera 1
            [[10.0, 0.0, 0.5], [10.0, 0.0, 5.0]],  # near but far outside the image
            # near, just outside the frame: inside the margin
            [[float(x_out), 0.0, 0.5], [0.0, 0.0, 5.0]],
            [[0.0, 0.0, 5.0], [0.0, 0.0, -0.5]],  # near camera 1 (looking -z) at sample 1
        ]
    )
    near = near_camera_gaussians(pts, back, K, W, H, z_min=1.0)
    assert near.tolist() == [True, False, False, False, True, True]
    assert near_camera_gaussians(pts, back, K, W, H, z_min=1.0, margin=0.0).tolist()[4] is False


def test_world_stage_removes_only_the_near_camera_dynamic_gaussian(tiny_clip_realistic):
    from m4dgs.clip import Clip
    from m4dgs.model.gaussians import WorldGaussians
    from m4dgs.training.data import load_training_data
    from m4dgs.training.stage1 import build_appearance
    from m4dgs.training.stage2 import WorldInit, WorldStage

    d = load_training_data(Clip.open(tiny_clip_realistic))
    cfg = preset("tiny")
    T = d.num_frames
    K = torch.as_tensor(K_from_fov(d.width, d.height, 60.0)).float()
    c2w = torch.eye(4).expand(T, 4, 4).clone()
    c2w[:, 0, 3] = torch.linspace(0, 0.2, T)
    # median world depth 3
    depth_scale = torch.full((T,), 3.0 / float(d.depth[d.depth > 0].median()))
    knots = torch.arange(0, T, 2, dtype=torch.float32)
    if knots[-1] != T - 1:
        knots = torch.cat([knots, torch.tensor([T - 1.0])])
    Kn = len(knots)
    # dynamic 0: stays 3 in front; dynamic 1: swoops to z = 0.1 in front of the camera at its middle
    # knot only
    ctrl = torch.zeros(2, Kn, 3)
    ctrl[:, :, 2] = 3.0
    ctrl[1, Kn // 2, 2] = 0.1
    F = cfg.model.feature_dim
    static = {
        "means": torch.tensor([[0.0, 0.0, 3.0]]),
        "quats": torch.tensor([[1.0, 0, 0, 0]]),
        "scales": torch.full((1, 3), -3.0),
        "opacities": torch.zeros(1),
        "features": torch.zeros(1, F),
    }
    dynamic = {
        "ctrl": ctrl,
        "rot": torch.tensor([[1.0, 0, 0, 0]] + [[0.0, 0, 0, 0]] * 3).expand(2, 4, 4).clone(),
        "scales": torch.full((2, 3), -3.0),
        "opacities": torch.zeros(2),
        "features": torch.zeros(2, F),
    }
    g = WorldGaussians(
        static, dynamic, knots, T, cfg.model.world_scale_activation, cfg.model.world_scale_max
    )
    color, tm, bg = build_appearance(cfg, 0.73, "cpu", pretrain=False)
    st = WorldStage(d, cfg, WorldInit(g, color, tm, bg, K, c2w, depth_scale))
    assert abs(st.extent - 3.0) < 1e-3 and cfg.stage2.near_camera_fraction == 0.1
    assert st.remove_near_camera_dynamic() == 1
    assert (
        st.gauss.num_dynamic == 1 and float(st.gauss.dynamic["ctrl"].detach()[0, Kn // 2, 2]) == 3.0
    )
    # never empties the dynamic set / nothing left to remove
    assert st.remove_near_camera_dynamic() == 0
