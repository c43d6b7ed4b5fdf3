"""End-to-end: stage 1 fits a tiny oracle clip; the whole pipeline runs, is killed mid-way, and
resumes."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from m4dgs.clip import Clip, frame_name, level_name
from m4dgs.core.crf import get_crf
from m4dgs.training.data import load_training_data
from m4dgs.training.phases import code_fingerprint
from m4dgs.training.pipeline import resolve_config, train
from m4dgs.training.stage1 import VideoStage, train_stage1


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(-10 * np.log10(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)))


def test_stage1_fits_training_frames(tiny_clip_oracle):
    torch.manual_seed(0)
    clip = Clip.open(tiny_clip_oracle)
    data = load_training_data(clip)
    cfg = resolve_config(clip, "tiny")
    stage = VideoStage(data, cfg)
    out0 = stage.render_training_video()
    train_stage1(stage, progress=False)
    out = stage.render_training_video()
    ldr = data.ldr.numpy()
    p0 = np.mean([_psnr(out0["ldr"][i].numpy(), ldr[i]) for i in range(data.num_frames)])
    p1 = np.mean([_psnr(out["ldr"][i].numpy(), ldr[i]) for i in range(data.num_frames)])
    assert p1 > p0 + 3.0, (p0, p1)
    assert p1 > 24.0, p1  # measured 27.7 dB (300 iterations)
    # the learned HDR, tone-mapped with the TRUE CRF at the TRUE exposure, reproduces the input: the
    # unit-exposure loss fixes the HDR scale, so H is in the clip's radiometric units (up to the
    # tone mapper's residual error)
    crf = get_crf(clip.meta.crf)
    true_ldr = [crf(out["hdr"][i].numpy() * dt) for i, dt in enumerate(clip.train_dt)]
    p_true = np.mean([_psnr(true_ldr[i], ldr[i]) for i in range(data.num_frames)])
    assert p_true > 23.0, p_true  # measured 27.7 dB
    # and it agrees with the ground-truth HDR in the mu-law domain better than the initial model did
    gt = np.stack([clip.load_gt_hdr(g) for g in clip.train_frames])
    mu = lambda h: np.log1p(5000 * np.clip(h / gt.max(), 0, 1)) / np.log(5001)  # noqa: E731
    assert _psnr(mu(out["hdr"].numpy()), mu(gt)) > _psnr(mu(out0["hdr"].numpy()), mu(gt))


def test_pipeline_runs_resumes_and_renders(tiny_clip_realistic, tmp_path, monkeypatch):
    from m4dgs.training import stage2 as s2mod

    run = tmp_path / "run"
    over = {
        "stage1.iterations": 30,
        "stage2.iterations": 30,
        "checkpoint_every": 10,
        "camera_init.ba_steps": 60,
        "tonemap.pretrain_steps": 30,
        "v2w.scale_refit_steps": 20,
    }
    real_step = s2mod.WorldStage.step
    calls = {"n": 0}

    def dying_step(self, it):
        calls["n"] += 1
        if it == 25 and calls["n"] < 100:
            calls["n"] = 100
            raise RuntimeError("simulated kill")
        return real_step(self, it)

    monkeypatch.setattr(s2mod.WorldStage, "step", dying_step)
    with pytest.raises(RuntimeError, match="simulated kill"):
        train(tiny_clip_realistic, run, preset="tiny", overrides=over, progress=False)
    status = json.loads((run / "status.json").read_text())
    assert status["stage"] == "stage2" and status["finished"] == "v2w"
    assert (run / "model" / "ckpt.pt").exists()
    train(tiny_clip_realistic, run, preset="tiny", overrides=over, progress=False)
    status = json.loads((run / "status.json").read_text())
    assert status["stage"] == "done"
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    for stage, n in (("stage1", 30), ("stage2", 30)):
        steps = [r["step"] for r in log if r["stage"] == stage]
        assert steps == list(range(n)), (stage, steps)
    clip = Clip.open(tiny_clip_realistic)
    for g in clip.test_frames:
        assert (run / "renders/test/hdr" / frame_name(g, "exr")).exists()
        for lv in clip.meta.exposures.observed + clip.meta.exposures.novel:
            assert (run / "renders/test/ldr" / level_name(lv) / frame_name(g, "png")).exists()
    info = json.loads((run / "run.json").read_text())
    assert info["train_seconds"] > 0 and info["num_gaussians"] > 0
    # the fingerprint of the sources it was trained with (the one the phase-sharing keys use)
    assert info["code"] == code_fingerprint() and len(info["code"]) == 64
    # and where it ran: the instruction set torch dispatched on, no GPU on the CPU
    host = info["host"]
    assert host["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert host["torch"] == torch.__version__ and host["gpu"] is None
    cams = json.loads((run / "cameras.json").read_text())
    assert len(cams["c2w"]) == clip.meta.num_frames
    # tiny preset: union of the epipolar and rigidity masks, cameras re-adjusted once on them
    # (m4dgs.priors.rigidity)
    ci = torch.load(run / "model" / "camera_init.pt", weights_only=False)
    assert ci["diagnostics"]["masks"]["method"] == "union" and "first_pass" in ci["diagnostics"]
    assert ci["masks"].shape == ci["masks_epipolar"].shape and bool(
        (ci["masks"] | ~ci["masks_epipolar"]).all()
    )
    # a finished run is not retrained
    assert train(tiny_clip_realistic, run, preset="tiny", overrides=over, progress=False) == run


def test_kill_in_stage1_resumes_from_checkpoint(tiny_clip_realistic, tmp_path, monkeypatch):
    from m4dgs.training import stage1 as s1mod

    run = tmp_path / "run"
    over = {
        "stage1.iterations": 30,
        "stage2.iterations": 10,
        "checkpoint_every": 10,
        "camera_init.ba_steps": 40,
        "tonemap.pretrain_steps": 20,
        "v2w.scale_refit_steps": 10,
    }
    real_step = s1mod.VideoStage.step

    def dying_step(self, it):
        if it == 25:
            raise RuntimeError("simulated kill")
        return real_step(self, it)

    monkeypatch.setattr(s1mod.VideoStage, "step", dying_step)
    with pytest.raises(RuntimeError, match="simulated kill"):
        train(tiny_clip_realistic, run, preset="tiny", overrides=over, progress=False)
    monkeypatch.setattr(s1mod.VideoStage, "step", real_step)
    # the newest checkpoint (step 20) damaged: the run falls back to the previous one (step 10)
    assert (run / "model" / "ckpt.prev.pt").exists()
    ck = run / "model" / "ckpt.pt"
    ck.write_bytes(ck.read_bytes()[:1000])
    with pytest.warns(RuntimeWarning, match="unreadable checkpoint"):
        train(tiny_clip_realistic, run, preset="tiny", overrides=over, progress=False)
    log = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log if r["stage"] == "stage1"] == list(range(30))
    assert json.loads((run / "status.json").read_text())["stage"] == "done"
    assert (
        not (run / "model" / "ckpt.pt").exists() and not (run / "model" / "ckpt.prev.pt").exists()
    )


def test_a_gain_over_time_is_handed_over_saved_and_rendered_by_the_loaded_model(
    tiny_clip_realistic, tmp_path, monkeypatch, short_training
):
    """Beyond the paper (model.appearance_knots): stage 1 trains a gain, V2W hands each video
    Gaussian's gain to its world Gaussian, and the trained model loaded from final.pt renders
    exactly what stage 2 rendered before saving it, at training and fractional times."""
    from m4dgs.model.trained import load_model
    from m4dgs.run import load_torch
    from m4dgs.training import pipeline

    seen = {}
    real = pipeline.train_stage2

    def recording(stage, *args, **kw):
        real(stage, *args, **kw)
        c2w = stage.cameras().detach()[1]
        with torch.no_grad():
            seen.update({t: stage.render_at(t, c2w).hdr.clone() for t in (0.0, 1.5, 2.75)})
        seen["c2w"] = c2w.clone()

    monkeypatch.setattr(pipeline, "train_stage2", recording)
    k = 4
    over = {**short_training, "model.appearance_knots": k}
    run = train(
        tiny_clip_realistic, tmp_path / "run", preset="tiny", overrides=over, progress=False
    )
    video = load_torch(run / "model" / "stage1.pt")["gaussians"]["params"]["log2_gain"]
    assert video.shape[1] == k and video.abs().max() > 0  # trained away from zero
    v2w = load_torch(run / "model" / "v2w.pt")
    dyn = torch.tensor(v2w["report"]["is_dynamic"])
    assert torch.equal(v2w["gaussians"]["static"]["log2_gain"], video[~dyn])
    assert torch.equal(v2w["gaussians"]["dynamic"]["log2_gain"], video[dyn])
    final = load_torch(run / "model" / "final.pt")["gaussians"]
    assert final["static"]["log2_gain"].shape[1] == final["dynamic"]["log2_gain"].shape[1] == k
    model = load_model(run)
    assert model.gauss.appearance_knots == k
    for t in (0.0, 1.5, 2.75):
        got = model.render(t, seen["c2w"].numpy())["hdr"]
        assert torch.equal(got, seen[t]), t
    # the gain changes the render: the same model without it renders something else
    from m4dgs.model.gaussians import WorldGaussians

    plain = {
        p: {n: v for n, v in final[p].items() if n != "log2_gain"} for p in ("static", "dynamic")
    }
    model.gauss = WorldGaussians.from_state({**final, **plain})
    assert not torch.equal(model.render(1.5, seen["c2w"].numpy())["hdr"], seen[1.5])


def test_the_trained_model_keeps_the_reflected_colour_direction(
    tiny_clip_realistic, tmp_path, monkeypatch, short_training
):
    """Beyond the paper (tonemap.color_direction = "reflected", tonemap.color_specular): the model
    loaded from final.pt feeds its colour MLP the reflected direction, has the specular lobe, and
    renders exactly what stage 2 rendered."""
    from m4dgs.model.color import SPEC_LOG2_AMPLITUDE0
    from m4dgs.model.trained import load_model
    from m4dgs.training import pipeline

    seen = {}
    real = pipeline.train_stage2

    def recording(stage, *args, **kw):
        real(stage, *args, **kw)
        seen["c2w"] = stage.cameras().detach()[1].clone()
        with torch.no_grad():
            seen["hdr"] = stage.render_at(1.5, seen["c2w"]).hdr.clone()

    monkeypatch.setattr(pipeline, "train_stage2", recording)
    over = {
        **short_training,
        "tonemap.color_view_dependent": True,
        "tonemap.color_direction": "reflected",
        "tonemap.color_specular": True,
    }
    run = train(
        tiny_clip_realistic, tmp_path / "run", preset="tiny", overrides=over, progress=False
    )
    model = load_model(run)
    assert model.color.view_dependent and model.color.direction == "reflected"
    assert model.color.specular  # and its head trained away from the start:
    assert (model.color.spec.bias[:3] != SPEC_LOG2_AMPLITUDE0).any()
    assert torch.equal(model.render(1.5, seen["c2w"].numpy())["hdr"], seen["hdr"])
    model.color.direction = "view"  # the other direction renders something else
    assert not torch.equal(model.render(1.5, seen["c2w"].numpy())["hdr"], seen["hdr"])


def test_a_run_of_the_older_config_layout_is_accepted(tiny_clip_realistic, tmp_path):
    """An older run's config.yaml (loss weights directly under stage1 / stage2, since-removed
    never-read keys) with the same settings is taken as this run's and rewritten in the current
    layout; another setting is still refused."""
    import warnings

    from m4dgs.run import RunDir
    from m4dgs.training.config import to_dict
    from m4dgs.training.pipeline import Trainer

    old = to_dict(resolve_config(Clip.open(tiny_clip_realistic), "tiny"))
    for stage in ("stage1", "stage2"):
        old[stage].update(old[stage].pop("loss"))
        old[stage]["track_clamp_px"] = 100.0
    old["v2w"]["fov_clamp"] = 1.3
    run = tmp_path / "run"
    RunDir(run).write_config(old)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # internal upgrade: no warning
        tr = Trainer(tiny_clip_realistic, run, preset="tiny", progress=False)
    assert RunDir(run).read_config() == to_dict(tr.cfg)
    with pytest.raises(ValueError, match="different configuration"):
        Trainer(tiny_clip_realistic, run, preset="tiny", variant="no-tlr", progress=False)


def test_failed_camera_initialisation_stops_unless_allowed(
    tiny_clip_realistic, tmp_path, monkeypatch
):
    """Too few static tracks: the trainer stops naming the clip and the way on; with
    camera_init.allow_fallback it goes on with the identity cameras, recorded in diagnostics."""
    from m4dgs.core.errors import InputError
    from m4dgs.priors.camera_init import CameraInitResult
    from m4dgs.training import pipeline as P

    def failing(tracks, depth, masks, width, height, cfg, progress=""):
        T = depth.shape[0]
        eye = torch.eye(4, dtype=torch.float64).expand(T, 4, 4).clone()
        K = torch.tensor([[50.0, 0, width / 2], [0, 50.0, height / 2], [0, 0, 1]])
        diag = {"warning": "too few static tracks; identity cameras", "num_used": 3}
        n = tracks.tracks.shape[0]
        return CameraInitResult(K, eye, torch.ones(T), torch.zeros(n, dtype=torch.bool), diag)

    monkeypatch.setattr(P, "initialize_cameras", failing)
    tr = P.Trainer(tiny_clip_realistic, tmp_path / "a", preset="tiny", progress=False)
    with pytest.raises(
        InputError, match=r"camera initialisation failed: too few static .*allow_fallback"
    ):
        tr.camera_init()
    assert not (tmp_path / "a" / "model" / "camera_init.pt").exists()
    over = {"camera_init.allow_fallback": True, "masks.method": "epipolar"}
    tr = P.Trainer(
        tiny_clip_realistic, tmp_path / "b", preset="tiny", overrides=over, progress=False
    )
    tr.camera_init()
    ci = torch.load(tmp_path / "b" / "model" / "camera_init.pt", weights_only=False)
    assert "too few static tracks" in ci["diagnostics"]["warning"]


def test_a_run_refuses_to_resume_on_changed_clip_inputs(tiny_clip_realistic, tmp_path):
    """The clip's input fingerprint (clip.json, input/, priors/) is stored when a run starts; a
    changed prior afterwards stops the next start instead of resuming stale phase outputs."""
    import shutil

    from m4dgs.core.errors import InputError
    from m4dgs.training.pipeline import Trainer

    clip = tmp_path / "clip"
    shutil.copytree(tiny_clip_realistic, clip)
    run = tmp_path / "run"
    Trainer(clip, run, preset="tiny", progress=False)
    fp = json.loads((run / "status.json").read_text())["clip_fingerprint"]
    assert fp == Clip.open(clip).input_fingerprint() and len(fp) == 64
    Trainer(clip, run, preset="tiny", progress=False)  # unchanged: fine
    # the ground truth is not an input: changing it changes nothing
    gt = next(p for p in (clip / "gt").rglob("*") if p.is_file())
    gt.write_bytes(gt.read_bytes() + b"x")
    assert Clip.open(clip).input_fingerprint() == fp
    depth = sorted((clip / "priors" / "depth").iterdir())[0]
    depth.write_bytes(depth.read_bytes()[:-1] + bytes([depth.read_bytes()[-1] ^ 1]))
    with pytest.raises(InputError, match=r"changed since this run started .*--force"):
        Trainer(clip, run, preset="tiny", progress=False)
