"""A run killed in stage 1 and again in stage 2 and resumed from its checkpoints ends bit for bit
equal to the same run left alone (one thread): every random generator, optimiser state,
densification state and the kNN cache are in the checkpoints."""

from __future__ import annotations

import json

import pytest
import torch

from m4dgs.run import load_torch
from m4dgs.training import stage1 as s1mod
from m4dgs.training import stage2 as s2mod
from m4dgs.training.pipeline import train

# short stages that densify (splits draw random samples) after each checkpoint (steps 22, 28, 34
# in stage 1; 34 in stage 2)
OVERRIDES = {
    "stage1.iterations": 40,
    "stage2.iterations": 40,
    "checkpoint_every": 10,
    "stage1.densify.start_iter": 16,
    "stage1.densify.every": 6,
    "stage1.densify.stop_iter": 38,
    "stage1.densify.grad_threshold": 1e-7,
    "stage1.densify.max_gaussians": 20_000,
    "stage2.densify_static.start_iter": 28,
    "stage2.densify_static.every": 6,
    "stage2.densify_static.stop_iter": 38,
    "stage2.densify_static.grad_threshold": 1e-7,
    "stage2.densify_static.max_gaussians": 20_000,
    "stage2.densify_dynamic.start_iter": 28,
    "stage2.densify_dynamic.every": 6,
    "stage2.densify_dynamic.stop_iter": 38,
    "stage2.densify_dynamic.grad_threshold": 1e-7,
    "stage2.densify_dynamic.max_gaussians": 20_000,
    "stage1.loss.tlr_start": 12,
    "stage2.loss.tlr_start": 12,
    "camera_init.ba_steps": 40,
    "tonemap.pretrain_steps": 20,
    "v2w.scale_refit_steps": 10,
}


# beyond the paper: with a gain over time (model.appearance_knots) the checkpoints hold it, its
# Adam state and its densified rows as well
GAIN = {"model.appearance_knots": 4}


@pytest.mark.parametrize("extra", [pytest.param({}, id="paper"), pytest.param(GAIN, id="gain")])
def test_killed_and_resumed_run_equals_the_uninterrupted_one(
    tiny_clip_realistic, tmp_path, monkeypatch, one_thread, checkpoint_tensors, extra
):
    over = {**OVERRIDES, **extra}
    ref = train(
        tiny_clip_realistic, tmp_path / "ref", preset="tiny", overrides=over, progress=False
    )

    killed = {"stage1": False, "stage2": False}
    for mod, cls, stage, at in (
        (s1mod, "VideoStage", "stage1", 27),
        (s2mod, "WorldStage", "stage2", 33),
    ):
        real = getattr(mod, cls).step

        def dying(self, it, real=real, stage=stage, at=at):
            if it == at and not killed[stage]:
                killed[stage] = True
                raise RuntimeError(f"simulated kill in {stage}")
            return real(self, it)

        monkeypatch.setattr(getattr(mod, cls), "step", dying)
    run = tmp_path / "run"
    for stage in ("stage1", "stage2"):
        with pytest.raises(RuntimeError, match=f"simulated kill in {stage}"):
            train(tiny_clip_realistic, run, preset="tiny", overrides=over, progress=False)
        ck = load_torch(run / "model" / "ckpt.pt")
        assert ck["stage"] == stage and ck["step"] == (20 if stage == "stage1" else 30)
    train(tiny_clip_realistic, run, preset="tiny", overrides=over, progress=False)
    assert all(killed.values())

    # densification did run after each checkpoint (otherwise the test proves little)
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert any(
        r["stage"] == "stage1" and r["step"] > 20 and r.get("n_split", 0) + r.get("n_clone", 0)
        for r in log
    )
    assert any(
        r["stage"] == "stage2"
        and r["step"] > 30
        and any(k.endswith(("_split", "_clone")) and v for k, v in r.items())
        for r in log
    )
    a = checkpoint_tensors(ref / "model" / "final.pt")
    b = checkpoint_tensors(run / "model" / "final.pt")
    assert a.keys() == b.keys() and len(a) > 10
    assert any("log2_gain" in k for k in a) == bool(extra)
    different = [k for k in a if not torch.equal(a[k], b[k])]
    assert not different, different


def test_torch_on_one_thread_and_kernels_on_two_is_reproducible(
    tiny_clip_realistic, tmp_path, checkpoint_tensors
):
    """The split `m4dgs train` uses (m4dgs.core.threads: torch 1, compiled kernels N) repeats a
    seed bit for bit: each tile is composited by one thread, the rasterizer's backward reduces in
    list order and the projection's camera gradient in thread order (docs/reliability.md)."""
    from m4dgs.core.threads import threads_for

    ov = {k: v for k, v in OVERRIDES.items() if k != "checkpoint_every"}
    models = []
    for name in ("a", "b"):
        with threads_for(2):
            out = train(
                tiny_clip_realistic, tmp_path / name, preset="tiny", overrides=ov, progress=False
            )
        models.append(checkpoint_tensors(out / "model" / "final.pt"))
    # the same run with its phases called one by one (as bench/train_bench.py times them)
    from m4dgs.training.pipeline import PHASES, Trainer

    with threads_for(2):
        tr = Trainer(tiny_clip_realistic, tmp_path / "c", "tiny", "full", ov, "cpu", progress=False)
        for phase in PHASES[:-2]:  # camera_init .. stage2 (the renders do not change the model)
            tr.run_phase(phase)
    models.append(checkpoint_tensors(tmp_path / "c" / "model" / "final.pt"))
    a = models[0]
    assert len(a) > 10
    for b in models[1:]:
        assert a.keys() == b.keys()
        different = [k for k in a if not torch.equal(a[k], b[k])]
        assert not different, different
    info = json.loads((tmp_path / "a" / "run.json").read_text())
    assert (info["torch_threads"], info["kernel_threads"]) == (1, 2)
