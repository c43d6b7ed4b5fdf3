"""Variants: equal iteration budgets across the variants of a preset; the LDR reprojection
baselines' frame pairs."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from m4dgs.training.config import PRESETS, preset
from m4dgs.training.stage2 import ldr_reprojection_refs
from m4dgs.training.variants import (
    VARIANTS,
    budget,
    describe,
    overrides_for,
    stage2_only_budget,
    variant_config,
)

STAGE2_ONLY = ("no-video-init", "static-hdr", "world-only", "ldr-reproj", "ldr-reproj-consecutive")


@pytest.mark.parametrize("name", PRESETS)
def test_every_variant_has_full_total(name):
    s1, s2, total = budget(name, "full")
    base = preset(name)
    assert (s1, s2, total) == (
        base.stage1.iterations,
        base.stage2.iterations,
        base.stage1.iterations + base.stage2.iterations,
    )
    for v in VARIANTS:
        b1, b2, bt = budget(name, v)
        assert bt == total, (name, v, b1, b2)
        if v in STAGE2_ONLY:
            assert (b1, b2) == (0, total), (name, v)
        else:
            assert (b1, b2) == (s1, s2), (name, v)
    if name == "paper":
        assert total == 15_000  # the paper: every experiment 15K iterations


@pytest.mark.parametrize("name", PRESETS)
def test_stage2_only_config_has_the_full_budget_and_scaled_schedules(name):
    full = variant_config(name, "full")
    total = full.stage1.iterations + full.stage2.iterations
    f = total / full.stage2.iterations
    for v in STAGE2_ONLY:
        cfg = variant_config(name, v)
        assert not cfg.ablation.use_video_init
        assert cfg.stage2.iterations == total and cfg.stage1.iterations == 0
        for a, b in (
            (cfg.stage2.densify_static, full.stage2.densify_static),
            (cfg.stage2.densify_dynamic, full.stage2.densify_dynamic),
        ):
            # densification ends at the same fraction
            assert a.stop_iter == round(b.stop_iter * f) < total
            # cadences kept
            assert (a.start_iter, a.every, a.reset_every) == (b.start_iter, b.every, b.reset_every)
        assert cfg.stage2.tlr_start_step() == round(full.stage2.tlr_start_step() * f)
        assert cfg.stage2.dynamic_removal_every == full.stage2.dynamic_removal_every
        if full.stage2.pr_steps is None:
            assert cfg.stage2.pr_steps is None
        else:
            assert cfg.stage2.pr_steps == round(full.stage2.pr_steps * f)
        # the position learning rate decays over the whole (longer) stage
        lr = cfg.stage2.lr
        assert lr.position_lr(total, cfg.stage2.iterations) == pytest.approx(lr.position_final)
        assert (
            lr.position_lr(full.stage2.iterations, cfg.stage2.iterations) > lr.position_final * 1.01
        )


def test_budget_transfer_is_idempotent_and_user_overrides_win():
    cfg = variant_config("paper", "no-video-init")
    assert stage2_only_budget(cfg) is cfg
    # an explicit user value is kept
    assert (
        variant_config("paper", "world-only", {"stage2.iterations": 100}).stage2.iterations == 100
    )
    # a user override that switches stage 1 off gets the transfer too; one that switches it on does
    # not
    assert (
        variant_config("small", "full", {"ablation.use_video_init": False}).stage2.iterations
        == 5_500
    )
    back = variant_config("small", "no-video-init", {"ablation.use_video_init": True})
    assert (back.stage1.iterations, back.stage2.iterations) == (3_000, 2_500)


def test_pipeline_resolve_config_uses_the_budget():
    from types import SimpleNamespace

    from m4dgs.training.pipeline import resolve_config

    clip = SimpleNamespace(width=72, height=40)
    cfg = resolve_config(clip, "tiny", "world-only")
    assert (
        cfg.stage2.iterations == 600
        and cfg.stage1.iterations == 0
        and (cfg.width, cfg.height) == (72, 40)
    )


def test_variants_cli_prints_budgets():
    from m4dgs.cli import main

    r = CliRunner().invoke(main, ["variants", "--preset", "paper"])
    assert r.exit_code == 0, r.output
    lines = {ln.split()[0]: ln.split()[1:4] for ln in r.output.splitlines()[1:]}
    assert lines["full"] == ["4000", "11000", "15000"]
    assert lines["no-video-init"] == ["0", "15000", "15000"]
    assert set(lines) == set(VARIANTS)


def test_ldr_reprojection_pairs():
    T, n_e = 12, 3
    # same exposure: i +- N_e (in an alternating schedule the same level)
    assert ldr_reprojection_refs(5, T, n_e, "same-exposure") == [2, 8]
    assert ldr_reprojection_refs(1, T, n_e, "same-exposure") == [4]
    assert ldr_reprojection_refs(10, T, n_e, "same-exposure") == [7]
    levels = [i % n_e for i in range(T)]
    for i in range(T):
        assert all(
            levels[k] == levels[i] for k in ldr_reprojection_refs(i, T, n_e, "same-exposure")
        )
        # consecutive: i +- 1, always a different level of the alternating schedule
        refs = ldr_reprojection_refs(i, T, n_e, "consecutive")
        assert refs == [k for k in (i - 1, i + 1) if 0 <= k < T]
        assert all(levels[k] != levels[i] for k in refs)
    assert ldr_reprojection_refs(0, T, 2, "consecutive") == [1]
    assert ldr_reprojection_refs(4, T, 1, "same-exposure") == [3, 5]
    with pytest.raises(ValueError):
        ldr_reprojection_refs(0, T, n_e, "nearest")


def test_ldr_reprojection_variants_pick_their_pairs():
    same, cons = (
        variant_config("tiny", "ldr-reproj"),
        variant_config("tiny", "ldr-reproj-consecutive"),
    )
    assert same.method == cons.method == "ldr-reproj"
    assert (
        same.stage2.ldr_reproj_pairs == "same-exposure"
        and cons.stage2.ldr_reproj_pairs == "consecutive"
    )
    # the two differ in nothing else
    assert {
        k: v for k, v in overrides_for("ldr-reproj").items() if k != "stage2.ldr_reproj_pairs"
    } == {
        k: v
        for k, v in overrides_for("ldr-reproj-consecutive").items()
        if k != "stage2.ldr_reproj_pairs"
    }
    with pytest.raises(ValueError, match="ldr_reproj_pairs"):  # rejected when the config is built
        variant_config("tiny", "full", {"stage2.ldr_reproj_pairs": "nearest"})
    assert "SAME-exposure" in describe("ldr-reproj")
    assert "CONSECUTIVE" in describe("ldr-reproj-consecutive")


def test_world_only_is_ablation_a_without_tlr():
    a, w = overrides_for("no-video-init"), overrides_for("world-only")
    assert a.items() <= w.items()
    extra = {k: v for k, v in w.items() if k not in a}
    # method "world-only" selects no code path of its own; reproj_loss has no effect without stage-1
    # HDR frames
    assert extra == {"method": "world-only", "ablation.reproj_loss": False, "ablation.tlr": False}
    assert "MoSca" not in describe("world-only") and "ablation (a) without TLR" in describe(
        "world-only"
    )


def test_older_override_keys_warn_once_each():
    import warnings

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        cfg = variant_config("tiny", "full", {"stage1.lambda_dep": 0.5, "stage2.track_clamp_px": 1})
    assert cfg.stage1.loss.lambda_dep == 0.5
    msgs = sorted(str(w.message) for w in caught if w.category is FutureWarning)
    assert len(msgs) == 2 and "stage1.loss.lambda_dep" in msgs[0] and "removed" in msgs[1]


@pytest.mark.parametrize("name", PRESETS)
def test_full_relight_is_full_with_a_gain_over_time_and_the_others_have_none(name):
    """Beyond the paper: full-relight differs from full in model.appearance_knots alone (its
    regulariser and learning rate are defaults that nothing reads without the gain); every other
    variant keeps the paper's time-invariant colour. The two share camera initialisation only."""
    from m4dgs.training.config import to_dict
    from m4dgs.training.phases import leaves, phase_keys
    from m4dgs.training.variants import run_plan

    full = dict(leaves(to_dict(variant_config(name, "full"))))
    relit = dict(leaves(to_dict(variant_config(name, "full-relight"))))
    assert {k for k in full if full[k] != relit[k]} == {"model.appearance_knots"}
    assert relit["model.appearance_knots"] == 8 and full["model.appearance_knots"] == 0
    for v in VARIANTS:
        if v != "full-relight":
            assert variant_config(name, v).model.appearance_knots == 0, v
    assert describe("full-relight").startswith("BEYOND THE PAPER:")
    a = phase_keys(to_dict(variant_config(name, "full")), {"clip": "c"}, "full")
    b = phase_keys(to_dict(variant_config(name, "full-relight")), {"clip": "c"}, "full-relight")
    assert a["camera_init"] == b["camera_init"] and a["stage1"] != b["stage1"]
    assert run_plan(name, "full")[1:3] == run_plan(name, "full-relight")[1:3]


@pytest.mark.parametrize("name", PRESETS)
def test_full_pixel_fit_is_full_with_the_pixel_world_fit(name):
    """Beyond the paper: full-pixel-fit differs from full in v2w.world_fit alone, so the two share
    camera initialisation and stage 1 and part at the V2W transform; every other variant keeps the
    paper's world fit."""
    from m4dgs.training.config import to_dict
    from m4dgs.training.phases import leaves, phase_keys

    full = dict(leaves(to_dict(variant_config(name, "full"))))
    pix = dict(leaves(to_dict(variant_config(name, "full-pixel-fit"))))
    assert {k for k in full if full[k] != pix[k]} == {"v2w.world_fit"}
    assert pix["v2w.world_fit"] == "pixel"
    for v in VARIANTS:
        if v != "full-pixel-fit":
            assert variant_config(name, v).v2w.world_fit == "world", v
    assert describe("full-pixel-fit").startswith("BEYOND THE PAPER:")
    a = phase_keys(to_dict(variant_config(name, "full")), {"clip": "c"}, "full")
    b = phase_keys(to_dict(variant_config(name, "full-pixel-fit")), {"clip": "c"}, "full-pixel-fit")
    assert a["camera_init"] == b["camera_init"] and a["stage1"] == b["stage1"]
    assert a["v2w"] != b["v2w"]
