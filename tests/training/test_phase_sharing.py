"""Phase sharing between runs of one clip (m4dgs.training.phases): which configuration changes force
which phases to be recomputed, and that a shared phase gives the run bit for bit what it would have
computed itself."""

from __future__ import annotations

import copy
import json

import pytest
import torch

from m4dgs.run import RunDir
from m4dgs.training import phases
from m4dgs.training.config import PRESETS, apply_overrides, preset, to_dict
from m4dgs.training.pipeline import train
from m4dgs.training.variants import VARIANTS, variant_config

CONTEXT = {
    "clip": "c" * 64,
    "code": "d" * 64,
    "torch": "x",
    "threads": 1,
    "kernel_threads": 1,
    "device": "cpu",
    "backend": "cpu",
}


def _keys(cfg, **context):
    return phases.phase_keys(to_dict(cfg), {**CONTEXT, **context})


@pytest.mark.parametrize("name", PRESETS)
def test_every_config_field_belongs_to_a_phase(name):
    d = to_dict(preset(name))
    by = phases.fields_by_phase(d)  # raises KeyError on an unassigned field
    assert sum(len(v) for v in by.values()) == len(list(phases.leaves(d)))
    # no stale entry: every PHASE_OF name covers at least one field
    names = [n for n, _ in phases.leaves(d)]
    for p in phases.PHASE_OF:
        assert any(n == p or n.startswith(p + ".") for n in names), p
    with pytest.raises(KeyError, match="PHASE_OF"):
        phases.phase_of("no_such_section.field")


@pytest.mark.parametrize(
    "field, value, changed",
    [
        ("seed", 1, {"camera_init", "stage1", "v2w", "stage2"}),
        ("camera_init.ba_steps", 17, {"camera_init", "stage1", "v2w", "stage2"}),
        ("masks.method", "epipolar", {"camera_init", "stage1", "v2w", "stage2"}),
        ("stage1.loss.lambda_dep", 0.5, {"stage1", "v2w", "stage2"}),
        ("ablation.tlr", False, {"stage1", "v2w", "stage2"}),
        ("model.control_every", 2, {"stage1", "v2w", "stage2"}),
        ("tonemap.pretrain_crf", "hdrnerf", {"stage1", "v2w", "stage2"}),
        ("ablation.cov_invariance", False, {"v2w", "stage2"}),
        ("ablation.occlusion_handling", False, {"v2w", "stage2"}),
        ("v2w.occlusion_tol", 0.1, {"v2w", "stage2"}),
        ("ablation.reproj_loss", False, {"stage2"}),
        ("stage2.lambda_pr", 0.5, {"stage2"}),
        ("ablation.occlusion_handling_removal", False, {"stage2"}),
    ],
)
def test_a_field_changes_the_keys_of_its_phase_and_the_later_ones(field, value, changed):
    base = preset("small")
    a, b = _keys(base), _keys(apply_overrides(copy.deepcopy(base), {field: value}))
    assert {p for p in phases.SHARED_PHASES if a[p] != b[p]} == changed


def test_the_context_changes_every_key():
    base = preset("small")
    a = _keys(base)
    for k in CONTEXT:
        b = _keys(base, **{k: "other"})
        assert all(a[p] != b[p] for p in phases.SHARED_PHASES), k


def test_the_variant_name_changes_only_the_stage2_key():
    """The final model records its variant: runs of one configuration under two variant names
    share everything but stage 2."""
    cfg = to_dict(preset("small"))
    a = phases.phase_keys(cfg, CONTEXT, "full")
    b = phases.phase_keys(cfg, CONTEXT, "renamed")
    assert [p for p in phases.SHARED_PHASES if a[p] != b[p]] == ["stage2"]
    assert phases.phase_keys(cfg, CONTEXT, "full") == a


def test_what_the_paper_ablation_rows_share_with_full():
    full = _keys(variant_config("small", "full"))

    def shared(v):
        k = _keys(variant_config("small", v))
        return [p for p in phases.SHARED_PHASES if k[p] == full[p]]

    assert shared("full") == list(phases.SHARED_PHASES)
    assert shared("no-reproj") == ["camera_init", "stage1", "v2w"]
    assert shared("no-occlusion") == ["camera_init", "stage1"]
    assert shared("no-cov-invariance") == ["camera_init", "stage1"]
    assert shared("no-tlr") == ["camera_init"]
    assert shared("no-video-init") == ["camera_init"]
    assert set(VARIANTS) >= {"no-reproj", "no-tlr"}
    # campaign free-movers' rows: ns-2-chains-free parts from ns-2-chains in stage 2 only, and
    # neither shares stage 1 with full (another spline, other stage-1 priors)
    chains = _keys(variant_config("small", "ns-2-chains"))
    free = _keys(variant_config("small", "ns-2-chains-free"))
    same = [p for p in phases.SHARED_PHASES if free[p] == chains[p]]
    assert same == ["camera_init", "stage1", "v2w"]
    assert shared("ns-2-chains") == shared("ns-2-chains-free") == ["camera_init"]
    # campaign held-movers' row: the held depth is stage 1's (and stage 2's) own, not the cameras'
    held = _keys(variant_config("small", "ns-2-chains-held"))
    assert [p for p in phases.SHARED_PHASES if held[p] == free[p]] == ["camera_init"]
    # campaign relative-movers' row parts from ns-2-chains-held in stage 2 only
    rel = _keys(variant_config("small", "ns-2-chains-held-rel"))
    assert [p for p in phases.SHARED_PHASES if rel[p] == held[p]] == same
    # trainer seeds never share
    s1 = _keys(variant_config("small", "full", {"seed": 1}))
    assert all(s1[p] != full[p] for p in phases.SHARED_PHASES)


# --------------------------------------------------------------------------------------------------
# end to end on tiny runs
# --------------------------------------------------------------------------------------------------
SHORT = {
    "stage1.iterations": 24,
    "stage2.iterations": 24,
    "stage1.densify.start_iter": 8,
    "stage1.densify.every": 6,
    "stage1.densify.stop_iter": 20,
    "stage1.densify.grad_threshold": 1e-7,
    "stage2.densify_static.start_iter": 8,
    "stage2.densify_static.every": 6,
    "stage2.densify_static.stop_iter": 20,
    "stage2.densify_dynamic.start_iter": 8,
    "stage2.densify_dynamic.every": 6,
    "stage2.densify_dynamic.stop_iter": 20,
    "stage1.loss.tlr_start": 12,
    "stage2.loss.tlr_start": 12,
    "camera_init.ba_steps": 30,
    "tonemap.pretrain_steps": 20,
    "v2w.scale_refit_steps": 10,
}


def test_shared_phases_give_the_run_what_it_would_compute(
    tiny_clip_realistic, tmp_path, one_thread, checkpoint_tensors, monkeypatch
):
    share = tmp_path / "shared"

    def run(name, variant, extra=None, share_dir=share):
        ov = {**SHORT, **(extra or {})}
        out = train(
            tiny_clip_realistic,
            tmp_path / name,
            preset="tiny",
            variant=variant,
            overrides=ov,
            progress=False,
            share_dir=share_dir,
        )
        return RunDir(out)

    full = run("full", "full")
    assert "shared_phases" not in full.status()
    assert sorted(p.name for p in share.iterdir() if p.is_dir()) == sorted(phases.SHARED_PHASES)

    # a row that differs only in stage 2 takes the three phases before it from the share folder
    shared = run("no-reproj", "no-reproj")
    st = shared.status()
    assert sorted(st["shared_phases"]) == ["camera_init", "stage1", "v2w"]
    assert st["shared_phases"]["stage1"]["from"] == str(full.root.resolve())
    # ... with the producer's phase times and its stage-1 log lines
    for p in ("camera_init", "stage1", "v2w"):
        assert st["stage_seconds"][p] == pytest.approx(full.status()["stage_seconds"][p])
    s1 = [r for r in shared.read_log() if r.get("stage") == "stage1"]
    assert s1 == [r for r in full.read_log() if r.get("stage") == "stage1"] and len(s1) == 24

    # ... and ends bit for bit where the same row computed alone ends
    alone = run("no-reproj-alone", "no-reproj", share_dir=None)
    a = checkpoint_tensors(alone.path("model", "final.pt"))
    b = checkpoint_tensors(shared.path("model", "final.pt"))
    assert a.keys() == b.keys() and len(a) > 10
    different = [k for k in a if not torch.equal(a[k], b[k])]
    assert not different, different

    # the same row again (another suite's copy of it) takes all four phases, renders its own
    # frames, and holds the producer's final model, cameras, stage-2 log and timings
    again = run("full-again", "full")
    st = again.status()
    assert sorted(st["shared_phases"]) == sorted(phases.SHARED_PHASES) and st["stage"] == "done"
    assert st["shared_phases"]["stage2"]["from"] == str(full.root.resolve())
    a = checkpoint_tensors(full.path("model", "final.pt"))
    b = checkpoint_tensors(again.path("model", "final.pt"))
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    assert again.path("cameras.json").read_bytes() == full.path("cameras.json").read_bytes()
    s2 = [r for r in again.read_log() if r.get("stage") == "stage2"]
    assert s2 == [r for r in full.read_log() if r.get("stage") == "stage2"] and len(s2) == 24
    assert st["stage_seconds"]["stage2"] == pytest.approx(full.status()["stage_seconds"]["stage2"])
    test_frames = sorted(p.name for p in full.path("renders", "test", "hdr").iterdir())
    assert sorted(p.name for p in again.path("renders", "test", "hdr").iterdir()) == test_frames
    # a stage-1 field forces a fresh stage 1 (and V2W); camera initialisation is still shared
    s1_changed = run("lambda-dep", "full", {"stage1.loss.lambda_dep": 0.5})
    assert sorted(s1_changed.status()["shared_phases"]) == ["camera_init"]
    # another trainer seed shares nothing
    seed1 = run("seed-1", "full", {"seed": 1})
    assert "shared_phases" not in seed1.status()
    # another torch thread count shares nothing (its reductions add up in another order)
    torch.set_num_threads(2)
    threads2 = run("threads-2", "full")
    assert "shared_phases" not in threads2.status()
    # nor does another thread count of the compiled kernels (the rasterizer's backward adds
    # per-thread partial gradients), and run.json records both counts
    from m4dgs.core.threads import threads_for

    with threads_for(2):
        kernels2 = run("kernels-2", "full")
    assert "shared_phases" not in kernels2.status()
    info = json.loads(kernels2.path("run.json").read_text())
    assert (info["torch_threads"], info["kernel_threads"]) == (1, 2)
    # nor does a machine whose torch kernels dispatch on another instruction set (they round
    # differently: docs/reliability.md, "Across machines")
    torch.set_num_threads(1)
    import m4dgs.training.pipeline as pipeline

    monkeypatch.setattr(pipeline, "cpu_capability", lambda: "AVX512-elsewhere")
    avx = run("other-cpu", "full")
    assert "shared_phases" not in avx.status()


def test_a_phase_run_alone_goes_through_the_share(tiny_clip_realistic, tmp_path, one_thread):
    """Trainer.run_phase with a share folder, as the DIBR calibration rows run the camera
    initialisation (eval.experiments.dibr_views.camera_initialisation): the first caller computes
    and publishes it, the second copies it, with the same result."""
    from eval.experiments.dibr_views import camera_initialisation

    share = tmp_path / "share"
    a = camera_initialisation(tiny_clip_realistic, tmp_path / "a", "tiny", share_dir=share)
    assert "shared_phases" not in RunDir(tmp_path / "a").status()
    assert (share / "camera_init").is_dir()
    b = camera_initialisation(tiny_clip_realistic, tmp_path / "b", "tiny", share_dir=share)
    assert set(RunDir(tmp_path / "b").status()["shared_phases"]) == {"camera_init"}
    for k in ("K", "c2w", "depth"):
        assert (a[k] == b[k]).all(), k
