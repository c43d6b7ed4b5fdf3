"""Stage-2 removal of mistakenly densified dynamic Gaussians (WorldStage.remove_misplaced_dynamic,
appendix "Gaussian Densification"): only the Gaussians densified since the previous pass are tested
(stage2.dynamic_removal_scope), a pass never removes more than
stage2.dynamic_removal_max_fraction of the set, the counts go to the run log, and ablation (b)
(`no-occlusion`) leaves the removal's occlusion test on.

Independent answers: hand-built dynamic sets whose creation steps ("born") and dynamic masks (all
static / all dynamic) fix which Gaussians must go."""

import pytest
import torch

from m4dgs.core.camera import K_from_fov
from m4dgs.training.config import apply_overrides, preset
from m4dgs.training.variants import overrides_for


def _stage(clip_dir, n_dyn: int, masks_value: bool, **overrides):
    from m4dgs.clip import Clip
    from m4dgs.model.gaussians import WorldGaussians
    from m4dgs.training.data import load_training_data
    from m4dgs.training.stage1 import build_appearance
    from m4dgs.training.stage2 import WorldInit, WorldStage

    d = load_training_data(Clip.open(clip_dir))
    cfg = apply_overrides(preset("tiny"), {"stage2.near_camera_fraction": 0.0, **overrides})
    T = d.num_frames
    K = torch.as_tensor(K_from_fov(d.width, d.height, 60.0)).float()
    c2w = torch.eye(4).expand(T, 4, 4).clone()
    depth_scale = torch.full((T,), 3.0 / float(d.depth[d.depth > 0].median()))
    knots = torch.arange(0, T, 2, dtype=torch.float32)
    if knots[-1] != T - 1:
        knots = torch.cat([knots, torch.tensor([T - 1.0])])
    Kn = len(knots)
    ctrl = torch.zeros(n_dyn, Kn, 3)
    ctrl[:, :, 0] = torch.linspace(-0.3, 0.3, n_dyn)[:, None]
    ctrl[:, :, 2] = 3.0  # all in view, 3 in front of every camera
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
        "rot": torch.tensor([[1.0, 0, 0, 0]] + [[0.0, 0, 0, 0]] * 3).expand(n_dyn, 4, 4).clone(),
        "scales": torch.full((n_dyn, 3), -3.0),
        "opacities": torch.zeros(n_dyn),
        "features": torch.zeros(n_dyn, F),
    }
    g = WorldGaussians(
        static, dynamic, knots, T, cfg.model.world_scale_activation, cfg.model.world_scale_max
    )
    color, tm, bg = build_appearance(cfg, 0.73, "cpu", pretrain=False)
    masks = torch.full((T, d.height, d.width), masks_value, dtype=torch.bool)
    return WorldStage(d, cfg, WorldInit(g, color, tm, bg, K, c2w, depth_scale, masks))


def test_removal_tests_only_gaussians_densified_since_the_last_pass(tiny_clip_realistic):
    # 6 dynamic Gaussians, all static by the masks: the 4 initial ones (born -1) must stay
    st = _stage(tiny_clip_realistic, 6, False)
    st.state_dynamic["born"] = torch.tensor([-1, -1, -1, -1, 50, 90])
    c = st.remove_misplaced_dynamic(100)
    assert c == {
        "dynamic_removal_tested": 2,
        "dynamic_removal_removed": 2,
        "dynamic_removal_kept": 0,
    }
    assert st.gauss.num_dynamic == 4
    assert st.state_dynamic["born"].tolist() == [-1, -1, -1, -1]
    assert st.state_dynamic["last_removal"] == 100
    # a Gaussian densified before the previous pass is not tested again ("new")
    st.state_dynamic["born"] = torch.tensor([-1, -1, 80, 150])
    c = st.remove_misplaced_dynamic(200)
    assert c["dynamic_removal_tested"] == 1 and c["dynamic_removal_removed"] == 1
    assert st.state_dynamic["born"].tolist() == [-1, -1, 80]


def test_removal_keeps_densified_gaussians_in_dynamic_regions(tiny_clip_realistic):
    st = _stage(tiny_clip_realistic, 4, True)
    st.state_dynamic["born"] = torch.tensor([-1, -1, 10, 20])
    c = st.remove_misplaced_dynamic(100)
    assert c["dynamic_removal_tested"] == 2 and c["dynamic_removal_removed"] == 0
    assert c["dynamic_removal_kept"] == 2 and st.gauss.num_dynamic == 4


def test_removal_scope_all_is_the_previous_behaviour_and_is_capped(tiny_clip_realistic):
    st = _stage(
        tiny_clip_realistic,
        6,
        False,
        **{"stage2.dynamic_removal_scope": "all", "stage2.dynamic_removal_max_fraction": 0.5},
    )
    with pytest.warns(RuntimeWarning, match="identified 6 of 6 as static; removing only 3"):
        c = st.remove_misplaced_dynamic(100)
    assert c["dynamic_removal_tested"] == 6 and c["dynamic_removal_removed"] == 3
    assert c["dynamic_removal_capped"] == 6 and st.gauss.num_dynamic == 3
    # "densified": every densified Gaussian, re-tested at every pass
    st = _stage(tiny_clip_realistic, 4, False, **{"stage2.dynamic_removal_scope": "densified"})
    st.state_dynamic["born"] = torch.tensor([-1, -1, -1, 10])
    st.state_dynamic["last_removal"] = 50
    assert st.remove_misplaced_dynamic(100)["dynamic_removal_removed"] == 1


def test_no_occlusion_ablation_keeps_the_removal_occlusion_test(tiny_clip_realistic, monkeypatch):
    from m4dgs.training import v2w

    seen = []
    real = v2w.dynamic_counts

    def spy(*args, **kwargs):
        seen.append((args[2] is not None, kwargs["occlusion_handling"], kwargs["occlusion_tol"]))
        return real(*args, **kwargs)

    monkeypatch.setattr(v2w, "dynamic_counts", spy)
    ov = overrides_for("no-occlusion")
    assert ov == {"ablation.occlusion_handling": False}
    st = _stage(tiny_clip_realistic, 3, False, **ov, **{"v2w.occlusion_tol": 0.2})
    st.state_dynamic["born"] = torch.tensor([-1, 5, 5])
    # in both, two of the three read as static, above the removal's cap (half): it says so
    with pytest.warns(RuntimeWarning, match="removing only 1"):
        st.remove_misplaced_dynamic(100)
    # the extended ablation (the previous no-occlusion) switches the removal's test off too
    st = _stage(tiny_clip_realistic, 3, False, **{"ablation.occlusion_handling_removal": False})
    st.state_dynamic["born"] = torch.tensor([-1, 5, 5])
    with pytest.warns(RuntimeWarning, match="removing only 1"):
        st.remove_misplaced_dynamic(100)
    assert seen == [(True, True, 0.2), (False, False, 0.05)]


def test_camera_extent_is_the_3dgs_radius():
    from m4dgs.training.stage2 import camera_extent

    c2w = torch.eye(4).expand(3, 4, 4).clone()
    c2w[:, 0, 3] = torch.tensor([0.0, 1.0, 2.0])  # mean 1, largest distance 1
    assert abs(camera_extent(c2w) - 1.1) < 1e-9
    assert camera_extent(torch.eye(4).expand(3, 4, 4), fallback=3.0) == 3.0


def test_stage2_clone_split_boundary_uses_the_camera_extent(tiny_clip_realistic):
    st = _stage(tiny_clip_realistic, 2, False)
    # the fixture's cameras do not move: the extent falls back to the median world depth (3)
    assert (
        abs(st.strat_static.extent - 3.0) < 1e-3
        and st.strat_dynamic.extent == st.strat_static.extent
    )
    st = _stage(tiny_clip_realistic, 2, False, **{"stage2.clone_split_extent": "absolute"})
    assert st.strat_static.extent == 1.0 and st.strat_dynamic.extent == 1.0


def test_dynamic_gaussians_have_their_own_learning_rates(tiny_clip_realistic):
    ov = {
        "stage2.lr.dynamic_position_init": 1e-2,
        "stage2.lr.dynamic_position_final": 1e-3,
        "stage2.lr.dynamic_rotation": 7e-3,
    }
    st = _stage(tiny_clip_realistic, 2, False, **ov)
    assert st.opt_dynamic["rot"].param_groups[0]["lr"] == 7e-3
    assert st.opt_static["quats"].param_groups[0]["lr"] == st.cfg.stage2.lr.rotation
    lrs = dict((id(o), lr) for o, lr in st.position_lrs(st.cfg.stage2.iterations))
    assert abs(lrs[id(st.opt_dynamic["ctrl"])] - 1e-3 * st.extent) < 1e-12
    assert abs(lrs[id(st.opt_static["means"])] - 1.6e-6 * st.extent) < 1e-12


def test_paper_preset_uses_the_paper_epipolar_threshold_in_normalised_coordinates():
    from m4dgs.training.config import TrainConfig

    for cfg in (preset("paper"), TrainConfig()):
        assert (cfg.epipolar.units, cfg.epipolar.threshold) == ("ndc", 1e-5)
    for name in ("tiny", "small"):
        assert (preset(name).epipolar.units, preset(name).epipolar.threshold) == ("px", 1.0)
