"""Config defaults (against the paper's numbers), presets, YAML round trip, unknown keys and
overrides."""

import dataclasses

import pytest
import yaml

from m4dgs.training import config, phases
from m4dgs.training.config import TrainConfig, apply_overrides, from_dict, preset, to_dict


def test_paper_defaults():
    cfg = preset("paper")
    s1, s2 = cfg.stage1, cfg.stage2
    # appendix "Implementation Details"
    assert (cfg.width, cfg.height) == (864, 480)
    assert (s1.iterations, s2.iterations) == (4000, 11000)
    for lc in (s1.loss, s2.loss):  # one list of weights for both stages
        assert (lc.lambda_rgb, lc.lambda_ue, lc.lambda_dep, lc.lambda_track) == (
            1.0,
            10.0,
            1.0,
            0.01,
        )
        assert (lc.lambda_arap, lc.lambda_vel, lc.lambda_acc, lc.lambda_tlr) == (0.01, 10, 10, 0.1)
        assert lc.lambda_dssim == 0.2 and lc.arap_k == 5
    assert s2.lambda_pr == 1.0 and s1.loss is not s2.loss
    assert (s1.densify.stop_iter, s1.densify.every, s1.densify.reset_every) == (3000, 200, 1000)
    assert (
        s2.densify_static.stop_iter,
        s2.densify_static.every,
        s2.densify_static.reset_every,
    ) == (8000, 400, 2000)
    assert (s2.densify_dynamic.every, s2.densify_dynamic.reset_every, s2.dynamic_removal_every) == (
        200,
        2000,
        2000,
    )
    d = s1.densify
    assert (d.grad_threshold, d.clone_split_scale, d.split_scale_factor) == (2e-4, 0.01, 1.6)
    assert (d.prune_opacity, d.reset_opacity_value, d.max_gaussians) == (0.005, 0.01, 150_000)
    lr = s1.lr
    assert (lr.position_init, lr.position_final, lr.rotation, lr.scale) == (
        1.6e-4,
        1.6e-6,
        1e-3,
        5e-3,
    )
    assert (lr.opacity, lr.features, lr.mlp, lr.adam_eps, lr.camera_rotation) == (
        5e-2,
        2.5e-3,
        5e-4,
        1e-15,
        3e-5,
    )
    assert cfg.model.control_every == 4 and cfg.model.feature_dim == 36
    assert cfg.v2w.dynamic_ratio == 0.1 and cfg.v2w.scale_refit_steps == 1000
    assert s2.pr_offsets == (1, 2)
    assert all(dataclasses.asdict(cfg.ablation).values())
    assert cfg.exposure.unit_exposure_value is None


def test_presets_are_smaller_and_consistent():
    tiny, small = preset("tiny"), preset("small")
    assert (small.width, small.height) == (216, 120)
    assert tiny.stage1.iterations + tiny.stage2.iterations <= 600
    assert small.stage1.iterations + small.stage2.iterations < 15_000  # paper: 4K + 11K
    for cfg in (tiny, small):
        for d in (cfg.stage1.densify, cfg.stage2.densify_static, cfg.stage2.densify_dynamic):
            assert 0 < d.start_iter < d.stop_iter and d.every >= 1
        assert cfg.stage1.densify.stop_iter < cfg.stage1.iterations
        assert cfg.stage2.densify_dynamic.stop_iter < cfg.stage2.iterations
    # the paper preset is the paper's appendix; small uses the authors' synthetic TLR weight and
    # reprojection window
    assert preset("paper").stage2.loss.lambda_tlr == 0.1 and preset("paper").stage2.pr_steps is None
    assert small.stage1.loss.lambda_tlr == small.stage2.loss.lambda_tlr == 0.01
    assert small.stage1.loss.lambda_dep == 0.01 and preset("paper").stage1.loss.lambda_dep == 1.0
    assert 0 < small.stage2.pr_steps < small.stage2.iterations
    with pytest.raises(ValueError, match="unknown preset"):
        preset("huge")


@pytest.mark.parametrize("name", ["tiny", "small", "paper"])
def test_yaml_round_trip(name, tmp_path):
    cfg = preset(name)
    cfg = apply_overrides(cfg, {"stage2.pr_offsets": [1, 2, 3], "exposure.perturb_ev": 0.25})
    path = tmp_path / "config.yaml"
    config.save_yaml(cfg, path)
    text = path.read_text()
    data = yaml.safe_load(text)
    assert data["stage1"]["loss"]["lambda_tlr"] == cfg.stage1.loss.lambda_tlr
    assert data["stage2"]["pr_offsets"] == [1, 2, 3]
    assert data["stage2"]["pr_steps"] == cfg.stage2.pr_steps
    back = config.load_yaml(path)
    assert back == cfg
    assert isinstance(back.stage2.pr_offsets, tuple)
    # from a dict without the preset key: plain dataclass defaults + the given values
    d = to_dict(cfg)
    d.pop("preset")
    assert from_dict(TrainConfig, d) == dataclasses.replace(cfg, preset="paper")


def test_unknown_key_errors_name_the_path():
    d = to_dict(preset("tiny"))
    d["stage1"]["loss"]["lamda_tlr"] = 0.0
    with pytest.raises(KeyError, match=r"stage1\.loss\.lamda_tlr"):
        from_dict(TrainConfig, d)
    with pytest.raises(KeyError, match=r"stage2\.densify_static\.evry"):
        from_dict(TrainConfig, {"stage2": {"densify_static": {"evry": 3}}})
    with pytest.raises(KeyError, match="bogus"):
        from_dict(TrainConfig, {"bogus": 1})
    with pytest.raises(KeyError, match=r"stage1\.nope"):
        apply_overrides(preset("tiny"), {"stage1.nope": 1})
    with pytest.raises(KeyError, match=r"stagex"):
        apply_overrides(preset("tiny"), {"stagex.loss.lambda_tlr": 1})
    with pytest.raises(TypeError, match=r"ablation\.tlr"):
        apply_overrides(preset("tiny"), {"ablation.tlr": 3})
    with pytest.raises(TypeError, match=r"stage1\.iterations"):
        from_dict(TrainConfig, {"stage1": {"iterations": 1.5}})


def test_apply_overrides_variants():
    base = preset("paper")
    v = apply_overrides(
        base,
        {
            "stage1.loss.lambda_tlr": 0,
            "stage2.loss.lambda_tlr": "0",  # CLI strings are parsed
            "ablation.tlr": "false",
            "model.control_every": 8,
            "stage2.pr_steps": 3000,
            "stage1.densify": {"every": 100},
        },
    )
    assert v.stage1.loss.lambda_tlr == 0.0 and isinstance(v.stage1.loss.lambda_tlr, float)
    assert v.stage2.loss.lambda_tlr == 0.0 and v.ablation.tlr is False
    assert v.model.control_every == 8 and v.stage2.pr_steps == 3000
    assert v.stage1.densify.every == 100 and v.stage1.densify.stop_iter == 3000
    # the original is untouched
    assert (
        base.stage1.loss.lambda_tlr == 0.1
        and base.model.control_every == 4
        and base.stage1.densify.every == 200
    )
    # Optional fields accept null
    assert apply_overrides(v, {"stage2.pr_steps": None}).stage2.pr_steps is None
    # a dict with a preset key applies the rest on top of that preset
    t = from_dict(TrainConfig, {"preset": "tiny", "stage1": {"loss": {"lambda_vel": 1.0}}})
    assert (
        t.width == 64
        and t.stage1.loss.lambda_vel == 1.0
        and t.stage1.iterations == preset("tiny").stage1.iterations
    )


def test_position_lr_schedule_and_tlr_start():
    lr = preset("paper").stage1.lr
    assert lr.position_lr(0, 4000) == pytest.approx(1.6e-4)
    assert lr.position_lr(4000, 4000) == pytest.approx(1.6e-6)
    # log-linear: geometric mean
    assert lr.position_lr(2000, 4000) == pytest.approx((1.6e-4 * 1.6e-6) ** 0.5)
    assert lr.position_lr(9999, 4000) == pytest.approx(1.6e-6)
    cfg = preset("paper")
    assert cfg.stage1.tlr_start_step() == 3000 and cfg.stage2.tlr_start_step() == 8000
    assert apply_overrides(cfg, {"stage1.loss.tlr_start": 10}).stage1.tlr_start_step() == 10


def test_old_loss_keys_map_to_the_loss_section_with_a_warning():
    base = preset("tiny")
    with pytest.warns(FutureWarning, match=r"'stage1\.lambda_dep' is deprecated.*stage1\.loss"):
        v = apply_overrides(base, {"stage1.lambda_dep": "0.5"})
    assert v.stage1.loss.lambda_dep == 0.5 and v.stage2.loss.lambda_dep == 1.0
    # nested mappings and YAML-style dicts too
    with pytest.warns(FutureWarning, match=r"stage2\.tlr_start"):
        v = apply_overrides(base, {"stage2": {"tlr_start": 7}})
    assert v.stage2.loss.tlr_start == 7 and v.stage2.tlr_start_step() == 7
    with pytest.warns(FutureWarning, match=r"stage1\.lambda_vel"):
        t = from_dict(TrainConfig, {"preset": "tiny", "stage1": {"lambda_vel": 2.0}})
    assert t.stage1.loss.lambda_vel == 2.0
    with pytest.warns(FutureWarning, match=r"stage2\.arap_k"):
        t = from_dict(TrainConfig, {"stage2": {"arap_k": 3}})
    assert t.stage2.loss.arap_k == 3 and t.stage1.loss.arap_k == 5
    # a key that nothing read is ignored with a warning
    with pytest.warns(FutureWarning, match=r"'stage1\.track_clamp_px' was removed"):
        assert apply_overrides(base, {"stage1.track_clamp_px": 50}) == base
    for key in ("stage2.lr.camera_focal", "v2w.fov_clamp", "exposure.num_exposures"):
        with pytest.warns(FutureWarning, match="removed"):
            assert apply_overrides(base, {key: 1}) == base


def test_renamed_smooth_window_keeps_the_same_frames():
    base = preset("tiny")
    assert base.stage1.loss.smooth_half_width == 2  # i - 2 .. i + 2 (authors' code)
    with pytest.warns(FutureWarning, match=r"'stage1\.loss\.smooth_window' is now .*= 2"):
        v = apply_overrides(base, {"stage1.loss.smooth_window": 1})
    assert v.stage1.loss.smooth_half_width == 2 and v == base
    with pytest.warns(FutureWarning, match=r"smooth_half_width' = 4"):
        v = apply_overrides(base, {"stage2.smooth_window": 3})
    assert v.stage2.loss.smooth_half_width == 4
    assert (
        apply_overrides(base, {"stage2.loss.smooth_half_width": -1}).stage2.loss.smooth_half_width
        == -1
    )


def test_an_old_config_dict_upgrades_to_the_same_config():
    old = to_dict(preset("small"))
    for stage in ("stage1", "stage2"):
        loss = old[stage].pop("loss")
        # the former smooth_window w meant the frames i - w - 1 .. i + w + 1
        loss["smooth_window"] = loss.pop("smooth_half_width") - 1
        old[stage].update(loss)
        old[stage]["track_clamp_px"] = 100.0
        old[stage]["lr"]["camera_focal"] = 0.0
    old["v2w"]["fov_clamp"] = 1.3
    old["exposure"]["num_exposures"] = None
    assert config.upgrade_dict(old, warn=False) == to_dict(preset("small"))
    with pytest.warns(FutureWarning):
        assert from_dict(TrainConfig, old) == preset("small")
    current = to_dict(preset("tiny"))
    assert config.upgrade_dict(current) == current


GAIN_FIELDS = {  # the fields of the gain over time (beyond the paper) and their defaults
    "model.appearance_knots": 0,
    "stage1.lr.gain": 1e-2,
    "stage2.lr.gain": 1e-2,
    "stage1.loss.lambda_gain_smooth": 0.1,
    "stage2.loss.lambda_gain_smooth": 0.1,
}


@pytest.mark.parametrize("name", ["tiny", "small", "paper"])
def test_a_config_from_before_the_gain_option_is_the_same_config(name):
    """A config written before the gain over time existed (its five fields absent) loads to the
    configuration with the option off, equal to the preset's; the option is off in every preset."""
    cfg = preset(name)
    flat = dict(phases.leaves(to_dict(cfg)))
    assert {k: flat[k] for k in GAIN_FIELDS} == GAIN_FIELDS
    old = to_dict(cfg)
    del old["model"]["appearance_knots"]
    for stage in ("stage1", "stage2"):
        del old[stage]["lr"]["gain"]
        del old[stage]["loss"]["lambda_gain_smooth"]
    assert from_dict(TrainConfig, old) == cfg
    old.pop("preset")
    assert from_dict(TrainConfig, old).model == cfg.model
    # the fields belong to stage 1 onwards: what shares camera initialisation still does
    assert {phases.phase_of(k) for k in GAIN_FIELDS} == {"stage1", "stage2"}


@pytest.mark.parametrize(
    "key, value",
    [
        ("method", "mono4dgs-hdr"),
        ("preset", "huge"),
        ("raster_backend", "cuda"),
        ("stage2.pr_query", "video"),
        ("stage2.ldr_reproj_pairs", "adjacent"),
        ("v2w.resample", "cubic"),
        ("tonemap.pretrain_crf", "not-a-curve"),
        ("masks.method", "optical"),
        ("masks.combine", "median"),
        ("epipolar.error", "algebraic"),
        ("epipolar.ransac_method", "ransac"),
        ("camera_init.robust", "l2"),
        ("model.rotation_init", "random"),
        ("model.world_scale_activation", "softplus"),
    ],
)
def test_typed_choices_are_rejected_naming_key_and_values(key, value):
    with pytest.raises(ValueError, match=rf"'{key}' must be one of .*got '{value}'"):
        apply_overrides(preset("tiny"), {key: value})
    section, _, last = key.rpartition(".")
    data = {last: value} if not section else {section: {last: value}}
    with pytest.raises(ValueError, match=key.replace(".", r"\.")):
        from_dict(TrainConfig, data)
    with pytest.raises(ValueError, match="must be one of"):
        config.from_yaml(yaml.safe_dump(data))


def test_validate_catches_values_set_directly():
    cfg = preset("tiny")
    cfg.stage2.pr_query = "video"
    with pytest.raises(ValueError, match=r"stage2\.pr_query"):
        config.validate(cfg)
    cfg = preset("tiny")
    cfg.masks.method = "optical"
    with pytest.raises(ValueError, match=r"masks\.method"):
        config.validate(cfg)
    with pytest.raises(ValueError, match="'method' must be one of"):
        TrainConfig(method="bogus")
    # every allowed value passes
    for m in ("mono4dgs", "static-hdr", "world-only", "ldr-reproj"):
        config.validate(apply_overrides(preset("tiny"), {"method": m}))


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("stage1.iterations", -5, r">= 0 \(a number of iterations\)"),
        ("stage1.iterations", 0, r">= 1 \(0 only without stage 1\)"),
        ("stage2.iterations", 0, ">= 1"),
        ("stage1.loss.lambda_dep", float("nan"), "a finite number"),
        ("stage2.loss.lambda_tlr", -0.1, r">= 0 \(a loss weight; 0 turns the term off\)"),
        ("stage1.lr.position_init", 0.0, r"> 0 \(a learning rate\)"),
        ("stage2.lr.camera_rotation", float("inf"), "a finite number"),
        ("stage1.loss.flow_prob", 1.5, r"a probability in \[0, 1\]"),
        ("tonemap.pretrain_steps", -1, r">= 0 \(a number of iterations\)"),
        ("width", 0, r">= 1 \(pixels\)"),
        ("checkpoint_every", 0, ">= 1"),
        (
            "stage2.loss.tlr_den_floor",
            -0.01,
            r">= 0 \(a fraction of the render's median HDR value\)",
        ),
        (
            "stage1.loss.tlr_shoulder",
            1.5,
            r"an LDR value in \(0, 1\] \(None = TLR on every pixel\)",
        ),
        (
            "stage2.loss.tlr_shoulder",
            0.0,
            r"an LDR value in \(0, 1\] \(None = TLR on every pixel\)",
        ),
        ("model.appearance_knots", -1, r">= 0 \(0 = no gain over time, the paper's colour\)"),
        ("stage1.lr.gain", 0.0, r"> 0 \(a learning rate\)"),
        ("stage2.lr.dynamic_gain", 0.0, r"> 0 \(a learning rate\)"),
        ("stage1.init.highlight_min_area", 0, r">= 1 \(pixels\)"),
        ("stage2.loss.lambda_gain_smooth", -1.0, r">= 0 \(a loss weight; 0 turns the term off\)"),
    ],
)
def test_numbers_out_of_range_are_rejected_naming_the_key(key, value, message):
    with pytest.raises(ValueError, match=rf"config key '{key}' must be {message}; got"):
        apply_overrides(preset("tiny"), {key: value})


def test_every_preset_and_variant_is_in_range():
    from m4dgs.training.variants import VARIANTS, variant_config

    for p in ("tiny", "small", "paper"):
        for v in VARIANTS:
            config.validate(variant_config(p, v))  # no error
    # a variant without stage 1 has stage1.iterations = 0, which is allowed there
    assert variant_config("small", "world-only").stage1.iterations == 0


@pytest.mark.parametrize(
    "key, text, expected",
    [
        ("stage1.densify.grad_threshold", "2e-5", 2e-5),  # YAML 1.1 reads this as a word
        ("stage1.densify.grad_threshold", "2.0e-5", 2e-5),
        ("stage2.loss.lambda_tlr", "1E-2", 0.01),
        ("stage1.iterations", "1e3", 1000),
        ("stage1.loss.lambda_dep", " 0.5 ", 0.5),
    ],
)
def test_numbers_in_exponent_notation_are_numbers(key, text, expected):
    """--set KEY=2e-5 (and a YAML config's `2e-5`) is the number a user means, not a word."""
    cfg = apply_overrides(preset("tiny"), {key: text})
    obj = cfg
    for part in key.split("."):
        obj = getattr(obj, part)
    assert obj == pytest.approx(expected) and type(obj) is type(expected)


def test_a_word_for_a_number_still_names_the_key():
    with pytest.raises(ValueError, match="stage1.densify.grad_threshold"):
        apply_overrides(preset("tiny"), {"stage1.densify.grad_threshold": "small"})


def test_colour_direction_needs_a_view_dependent_mlp():
    """tonemap.color_direction: "reflected" and tonemap.color_specular are accepted with a
    view-dependent colour MLP, refused without one (naming both keys), and a direction outside the
    choices is refused."""
    cfg = apply_overrides(
        preset("tiny"),
        {"tonemap.color_view_dependent": True, "tonemap.color_direction": "reflected"},
    )
    assert cfg.tonemap.color_direction == "reflected"
    with pytest.raises(ValueError, match=r"'tonemap.color_direction' = 'reflected' needs "
                       r"'tonemap.color_view_dependent' = true"):  # fmt: skip
        apply_overrides(preset("tiny"), {"tonemap.color_direction": "reflected"})
    with pytest.raises(ValueError, match=r"'tonemap.color_specular' = True needs "):
        apply_overrides(preset("tiny"), {"tonemap.color_specular": True})
    with pytest.raises(ValueError, match=r"tonemap.color_direction"):
        apply_overrides(
            preset("tiny"),
            {"tonemap.color_view_dependent": True, "tonemap.color_direction": "mirror"},
        )
