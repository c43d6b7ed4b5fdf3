"""bench/gpu_check.py, the GPU session's one command, as a dry run on the CPU: a clip without its
ground truth is enough, every step reports, and the JSON holds what was printed."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]


def test_gpu_check_dry_run_on_a_clip_without_ground_truth(tiny_clip_realistic, tmp_path):
    clip = tmp_path / "clip"
    shutil.copytree(tiny_clip_realistic, clip, ignore=shutil.ignore_patterns("gt"))
    assert not (clip / "gt").exists()
    out = tmp_path / "out"
    cmd = [
        sys.executable,
        str(ROOT / "bench" / "gpu_check.py"),
        str(clip),
        "--out",
        str(out),
        "--steps",
        "env,train,fps,fps_scale,profile",
        "--preset",
        "tiny",
        "--iters",
        "10",
        "--fps-counts",
        "1,2000",
        "--profile-steps",
        "2",
    ]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr
    res = json.loads((out / "gpu_check.json").read_text())
    steps = res["steps"]
    assert list(steps) == ["env", "train", "fps", "fps_scale", "profile"]
    assert steps["env"]["device"] in ("cpu", "cuda")
    assert steps["train"]["rc"] == 0
    table = "\n".join(steps["train"]["table"])
    for phase in ("camera_init", "stage1", "v2w", "stage2", "total"):
        assert phase in table
    assert "(10 it)" in table  # --iters reached the training
    fps = steps["fps"]
    assert fps["num_gaussians"] > 0 and fps["fps_clip"] > 0 and fps["fps_864x480"] > 0
    # the rasterizer that ran, not the "auto" setting
    assert fps["backend"] == ("gsplat" if steps["env"]["device"] == "cuda" else "cpu")
    sc = steps["fps_scale"]
    n0 = sc["trained_gaussians"]
    assert n0 == fps["num_gaussians"]
    # count 1 keeps the trained model (k = 1); 2000 splits it k = round(2000 / n0) times
    assert [m["split_k"] for m in sc["models"]] == [1, max(1, round(2000 / n0))]
    assert [m["num_gaussians"] for m in sc["models"]] == [n0 * m["split_k"] for m in sc["models"]]
    assert all(m["fps"] > 0 for m in sc["models"])
    prof = steps["profile"]
    assert prof["rc"] == 0, prof["lines"]
    # stage 2 from the final model at the middle of its 10 iterations, 2 timed steps, profiled
    assert prof["start"] == 5 and "stage2 steps 10..11" in prof["ms_per_step"], prof
    assert any("Self CPU" in ln for ln in prof["lines"])


@pytest.mark.slow  # three trainings in their own processes (~50 s)
def test_gpu_check_jobs_step_runs_concurrent_trainings(tiny_clip_realistic, tmp_path):
    """The jobs step: N trainings of the clip at once, each with cpu_count / N threads and its own
    trainer seed, throughput against the first N."""
    out = tmp_path / "out"
    cmd = [sys.executable, str(ROOT / "bench" / "gpu_check.py"), str(tiny_clip_realistic)]
    cmd += ["--out", str(out), "--steps", "jobs", "--preset", "tiny"]
    cmd += ["--jobs", "1,2", "--jobs-iters", "5"]
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr
    res = json.loads((out / "gpu_check.json").read_text())
    runs = res["steps"]["jobs"]["runs"]
    assert runs["1"]["rc"] == [0] and runs["2"]["rc"] == [0, 0]
    assert runs["1"]["throughput_vs_first"] == 1.0
    # each of N concurrent trainings gets cpu_count / N threads, as `m4dgs-eval run --jobs N` does
    from m4dgs.core.threads import cpu_budget

    assert runs["2"]["threads_each"] == max(1, cpu_budget() // 2)
    # the two concurrent trainings were separate seeds (the trainer seed of each run's config)
    seeds = [
        yaml.safe_load((out / "jobs2" / f"run{k}" / "config.yaml").read_text())["seed"]
        for k in range(2)
    ]
    assert seeds == [0, 1]


def test_gpu_check_tests_step_collects_without_the_renderer(tmp_path):
    """The CUDA image has no mitsuba, drjit, pyoidn, imageio-ffmpeg or gsplat (until the kit's wheel
    is installed): the tests step must still collect and run the gpu-marked tests (skipped here
    without CUDA), which `pytest -m gpu` over every module would not (collection imports them
    all)."""
    block = tmp_path / "block"
    block.mkdir()
    for m in ("mitsuba", "drjit", "pyoidn", "imageio_ffmpeg", "gsplat"):
        (block / f"{m}.py").write_text(f"raise ImportError('not on the CUDA image: {m}')\n")
    tiny = tmp_path / "noclip"
    tiny.mkdir()
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=f"{block}{os.pathsep}{ROOT}")
    cmd = [sys.executable, str(ROOT / "bench" / "gpu_check.py"), str(tiny), "--out", str(out)]
    p = subprocess.run(
        cmd + ["--steps", "env,tests"], cwd=ROOT, env=env, capture_output=True, text=True
    )
    assert p.returncode == 0, p.stdout + p.stderr
    res = json.loads((out / "gpu_check.json").read_text())
    assert "import failed" in res["steps"]["env"]["gsplat"]
    t = res["steps"]["tests"]
    assert t["rc"] == 0, t["tail"]
    assert "tests/raster/test_raster_gsplat.py" in t["cmd"]
    assert any("skipped" in ln or "passed" in ln for ln in t["tail"])


def test_step_bench_times_both_stages_of_a_finished_run(tiny_clip_realistic, tmp_path):
    """bench/step_bench.py on a finished tiny run: stage 1 from its final stage-1 model, stage 2
    from the V2W output and from the final model (--from-final), with the thread split printed;
    the run folder is not touched."""
    from m4dgs.training.pipeline import train

    ov = {"stage1.iterations": 12, "stage2.iterations": 12, "camera_init.ba_steps": 20}
    run = train(tiny_clip_realistic, tmp_path / "run", preset="tiny", overrides=ov, progress=False)
    before = sorted(str(p.relative_to(run)) for p in run.rglob("*"))
    base = [
        sys.executable,
        str(ROOT / "bench" / "step_bench.py"),
        str(tiny_clip_realistic),
        str(run),
    ]
    base += ["--preset", "tiny", "--steps", "3", "--threads", "2"]
    for extra, stage in (
        (["--stage", "stage1", "--start", "5"], "stage1 steps 10..12"),
        (["--stage", "stage2", "--start", "5", "--torch-profile"], "stage2 steps 10..12"),
        (
            ["--stage", "stage2", "--start", "5", "--from-final", "--count-ops"],
            "stage2 steps 10..12",
        ),
    ):
        p = subprocess.run(base + extra, cwd=ROOT, capture_output=True, text=True, timeout=600)
        assert p.returncode == 0, p.stdout + p.stderr
        line = next(ln for ln in p.stdout.splitlines() if ln.startswith(stage))
        assert "ms/step" in line and "1 torch / 2 kernel threads" in line, line
        if "--torch-profile" in extra:
            assert "Self CPU" in p.stdout
        if "--count-ops" in extra:
            assert "tensor operations per step" in p.stdout and "training/stage.py:step" in p.stdout
    assert sorted(str(p.relative_to(run)) for p in run.rglob("*")) == before


def test_split_gaussians_keeps_volume_and_centres(tmp_path):
    """bench/gpu_check.split_gaussians against what it promises, computed here from the input:
    k times the count, each copy within its parent's extent, the summed volume (product of the
    activated scales) unchanged, opacities/features/rotations repeated, for both the static means
    and the dynamic spline control points (one offset for all of a Gaussian's points)."""
    sys.path.insert(0, str(ROOT / "bench"))
    try:
        from gpu_check import split_gaussians
    finally:
        sys.path.remove(str(ROOT / "bench"))
    import pytest
    import torch

    from m4dgs.model.gaussians import WorldGaussians, scale_activation

    g = torch.Generator().manual_seed(3)
    ns, nd, kc, jr = 40, 7, 5, 3
    static = {
        "means": torch.randn(ns, 3, generator=g),
        "quats": torch.randn(ns, 4, generator=g),
        "scales": torch.randn(ns, 3, generator=g) * 0.3 - 3.0,
        "opacities": torch.randn(ns, generator=g),
        "features": torch.randn(ns, 6, generator=g),
    }
    dynamic = {
        "ctrl": torch.randn(nd, kc, 3, generator=g),
        "rot": torch.randn(nd, jr, 4, generator=g),
        "scales": torch.randn(nd, 3, generator=g) * 0.3 - 3.0,
        "opacities": torch.randn(nd, generator=g),
        "features": torch.randn(nd, 6, generator=g),
    }
    for kind, smax in (("exp", 1.0), ("sigmoid", 0.5)):
        state = WorldGaussians(static, dynamic, torch.linspace(0, 1, kc), 9, kind, smax).to_state()
        k = 8
        out = split_gaussians(state, k, seed=1)
        w = WorldGaussians.from_state(out)
        assert w.num_static == ns * k and w.num_dynamic == nd * k
        for part, pos in (("static", "means"), ("dynamic", "ctrl")):
            a, b = state[part], out[part]
            sa = scale_activation(a["scales"], kind, smax)
            sb = scale_activation(b["scales"], kind, smax)
            vol_a = sa.prod(-1).sum()
            vol_b = sb.prod(-1).sum()
            assert float(vol_b) == pytest.approx(float(vol_a), rel=1e-4)
            for key in a:
                if key not in (pos, "scales"):
                    assert torch.equal(b[key], a[key].repeat_interleave(k, 0)), key
            off = b[pos] - a[pos].repeat_interleave(k, 0)
            if pos == "ctrl":  # the same offset on every control point of one Gaussian
                assert torch.allclose(off, off[:, :1].expand_as(off), atol=1e-6)
                off = off[:, 0]
            # offsets are N(0, scale^2) per axis: within 6 sigma of the parent, not all zero
            sig = sa.repeat_interleave(k, 0)
            assert (off.abs() <= 6 * sig).all() and off.abs().max() > 0
        assert split_gaussians(state, 1)["static"]["scales"].allclose(state["static"]["scales"])
    with pytest.raises(ValueError, match="k must be >= 1"):
        split_gaussians(state, 0)
