"""The checks of the GPU path in one command, for a session that is lent a CUDA machine.

    python bench/gpu_check.py CLIP --out DIR [--steps env,tests,train,fps,fps_scale,profile,jobs]
                              [--preset small] [--variant full] [--iters N] [--jobs 1,2,4]
                              [--jobs-iters 300] [--fps-counts 50000,150000] [--run RUN]

CLIP needs only input/ and priors/ (no ground truth), so a small clip can travel with the working
tree; `bench/gpu_kit.sh` packs one and the wheels the CUDA machine lacks. Steps, in order:

- env:   torch / CUDA / device, the gsplat import and the seconds of its first rasterization (gsplat
         compiles its CUDA code on first use; the later steps reuse that build).
- tests: `pytest -m gpu` on the modules holding gpu-marked tests (the gsplat backend against the
         C++ cpu backend on values and gradients, the device selection, FPS synchronisation) in a
         subprocess, its last lines kept.
- train: one `bench/train_bench.py CLIP --device cuda --no-score` run (wall time per phase and
         iterations/s), the run folder kept in DIR/run.
- fps:   render FPS of that trained model (or of --run) at the clip's resolution and at 864x480
         (eval.metrics.measure_fps, device synchronised), the Gaussian count and the peak GPU
         memory of the renders.
- fps_scale: render FPS at 864x480 of the trained model with its Gaussians split into more,
         smaller ones (--fps-counts totals; `split_gaussians`: each Gaussian becomes k copies,
         jittered within its own extent, scales shrunk by k^(-1/3) so the summed volume stays),
         a stand-in for a model densified to paper scale (~150K) when no full-length run fits.
- profile: `bench/step_bench.py` on the trained run (or --run): stage-2 steps from its final
         model (its final Gaussian count) at the middle of stage 2, or at TLR's first step if
         later (three renders a step), on the device, with the torch profiler: milliseconds per
         step, the top operations by CPU and by GPU time, and the host-device waits per step.
- jobs:  for each N of --jobs, N trainings of CLIP at once with --jobs-iters iterations per stage
         (different seeds, separate run folders, cpu_count / N CPU threads each as `m4dgs-eval
         run --jobs N` gives its workers): the wall time and the runs per second relative to the
         first N (what `m4dgs-eval run --jobs N` can expect from one GPU).

Everything measured goes to DIR/gpu_check.json (rewritten after every step, so a command stopped at
its time limit still leaves what it finished) and is printed. On a machine without CUDA the script
says so and runs the steps on the CPU (a dry run of the script itself, not a GPU figure).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from m4dgs.core.host import host_info  # noqa: E402
from m4dgs.core.threads import cpu_budget  # noqa: E402

STEPS = ("env", "tests", "train", "fps", "fps_scale", "profile", "jobs")
FPS_SIZE = (864, 480)


def _save(out: Path, res: dict) -> None:
    tmp = out / "gpu_check.json.tmp"
    tmp.write_text(json.dumps(res, indent=2, default=str))
    os.replace(tmp, out / "gpu_check.json")


def _env(device: str) -> dict:
    """Versions and the seconds of the first gsplat rasterization (its CUDA build)."""
    host = host_info(torch.device(device))  # python, torch, CPU model and dispatch, GPU name
    info = {
        **host,
        "cuda": torch.version.cuda,
        "device": device,
        "device_name": host["gpu"] or host["cpu"],
    }
    try:
        import gsplat

        info["gsplat"] = gsplat.__version__
    except Exception as exc:  # reported, not fatal: the cpu backend still runs
        info["gsplat"] = f"import failed: {type(exc).__name__}: {exc}"
        return info
    if device == "cuda":
        from m4dgs.raster import render

        g = torch.Generator().manual_seed(0)
        n = 1000
        means = torch.randn(n, 3, generator=g) * 0.3 + torch.tensor([0.0, 0.0, 3.0])
        quats = torch.randn(n, 4, generator=g)
        scales = torch.full((n, 3), 0.02)
        op = torch.full((n,), 0.8)
        feats = torch.rand(n, 3, generator=g)
        K = torch.tensor([[100.0, 0, 64], [0, 100.0, 48], [0, 0, 1]])
        args = [t.cuda() for t in (means, quats, scales, op, feats, torch.eye(4), K)]
        t0 = time.perf_counter()
        render(*args[:5], args[5], args[6], 128, 96, backend="gsplat")
        torch.cuda.synchronize()
        info["gsplat_first_render_s"] = round(time.perf_counter() - t0, 1)
    return info


def gpu_test_files() -> list:
    """The test modules that hold `gpu`-marked tests. Only these are collected: the CUDA image lacks
    benchgen's renderer and denoiser (mitsuba, pyoidn), which other test modules import."""
    tests = ROOT / "tests"
    return sorted(
        str(p.relative_to(ROOT)) for p in tests.rglob("test_*.py") if "mark.gpu" in p.read_text()
    )


def _tests() -> dict:
    cmd = [sys.executable, "-m", "pytest", "-q", "-rs", "-m", "gpu", "-p", "no:cacheprovider"]
    cmd += gpu_test_files()
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    tail = (p.stdout + p.stderr).strip().splitlines()[-15:]
    return {
        "cmd": " ".join(cmd),
        "rc": p.returncode,
        "seconds": round(time.perf_counter() - t0, 1),
        "tail": tail,
    }


def _train_cmd(clip: str, out: Path, a, device: str, extra=()) -> list:
    return [
        sys.executable,
        str(ROOT / "bench" / "train_bench.py"),
        clip,
        "--preset",
        a.preset,
        "--variant",
        a.variant,
        "--device",
        device,
        "--no-score",
        "--profile-steps",
        "0",
        "--out",
        str(out),
        *extra,
    ]


def _train(clip: str, out: Path, a, device: str) -> dict:
    extra = ["--iters1", str(a.iters), "--iters2", str(a.iters)] if a.iters else []
    t0 = time.perf_counter()
    p = subprocess.run(
        _train_cmd(clip, out / "run", a, device, extra), cwd=ROOT, capture_output=True, text=True
    )
    lines = (p.stdout + p.stderr).strip().splitlines()
    table = [
        ln
        for ln in lines
        if ln.startswith(("#", "phase", "set-up", "camera_init", "stage", "v2w", "render", "total"))
    ]
    return {
        "rc": p.returncode,
        "wall_s": round(time.perf_counter() - t0, 1),
        "table": table,
        "tail": lines[-8:] if p.returncode else [],
    }


def _middle_view(model, size):
    """(time, c2w, K) of the trained model's middle frame, K scaled to `size` = (w, h)."""
    frames = model.clip.meta.frames
    g = frames[len(frames) // 2]
    K, c2w = model.camera(g)
    K = K.copy()
    K[0] *= size[0] / model.width
    K[1] *= size[1] / model.height
    return model.time_of(g), c2w, K


def _fps(run: Path, device: str) -> dict:
    from eval.metrics.perf import measure_fps
    from m4dgs.model.trained import load_model
    from m4dgs.raster import resolve_backend

    model = load_model(run, device=device)
    backend = getattr(model, "backend", None) or "auto"
    # the rasterizer that actually ran ("auto" resolves to gsplat on CUDA when it imports)
    res = {
        "num_gaussians": model.num_gaussians,
        "backend": resolve_backend(backend, torch.device(device)),
    }
    if device == "cuda":
        torch.cuda.reset_peak_memory_stats()
    for name, (w, h) in (("clip", (model.width, model.height)), ("864x480", FPS_SIZE)):
        t, c2w, Ks = _middle_view(model, (w, h))
        r = measure_fps(
            lambda t=t, c2w=c2w, Ks=Ks, w=w, h=h: model.render(t, c2w, Ks, w, h),
            warmup=10,
            iters=20,
            device=device,
        )
        res[f"fps_{name}"] = round(r["fps"], 1)
        res[f"ms_per_frame_{name}"] = round(r["ms_per_frame"], 2)
    if device == "cuda":
        res["peak_render_memory_mib"] = round(torch.cuda.max_memory_allocated() / 2**20, 1)
    return res


def split_gaussians(state: dict, k: int, seed: int = 0) -> dict:
    """A WorldGaussians state (`to_state()`) with every Gaussian split into `k` copies: positions
    (static means, dynamic spline control points, the same offset for all of one Gaussian's
    points) jittered by N(0, scale^2) along each axis, activated scales divided by k^(1/3) (the
    summed volume of the model stays), everything else repeated. What a model densified k-fold
    costs the rasterizer, without training one. Returns a new state; `state` is not changed."""
    from m4dgs.model.gaussians import scale_activation, scale_inverse

    if k < 1:
        raise ValueError(f"split_gaussians: k must be >= 1, got {k}")
    g = torch.Generator().manual_seed(seed)
    kind, smax = state["scale_kind"], state["scale_max"]
    out = {key: val for key, val in state.items() if key not in ("static", "dynamic")}
    for part, pos in (("static", "means"), ("dynamic", "ctrl")):
        p = {key: v.detach().cpu() for key, v in state[part].items()}
        sc = scale_activation(p["scales"], kind, smax)  # [N, 3]
        new = {key: v.repeat_interleave(k, dim=0) for key, v in p.items()}
        jitter = torch.randn(sc.shape[0] * k, 3, generator=g) * sc.repeat_interleave(k, dim=0)
        # means [N*k, 3]; ctrl [N*k, K, 3]: one offset for all of a Gaussian's control points
        new[pos] = new[pos] + (jitter if pos == "means" else jitter[:, None, :])
        new["scales"] = scale_inverse(sc.repeat_interleave(k, dim=0) / k ** (1.0 / 3.0), kind, smax)
        out[part] = new
    return out


def _fps_scale(run: Path, device: str, counts) -> dict:
    """Render FPS at 864x480 of the model in `run` split (`split_gaussians`) to about each total of
    `counts` (k = round(count / N), at least 1)."""
    from eval.metrics.perf import measure_fps
    from m4dgs.model.gaussians import WorldGaussians
    from m4dgs.model.trained import load_model
    from m4dgs.raster import resolve_backend

    model = load_model(run, device=device)
    base = model.gauss.to_state()
    n0 = model.num_gaussians
    w, h = FPS_SIZE
    t, c2w, K = _middle_view(model, FPS_SIZE)
    res = {
        "trained_gaussians": n0,
        "backend": resolve_backend(model.backend or "auto", torch.device(device)),
        "size": f"{w}x{h}",
        "models": [],
    }
    for count in counts:
        k = max(1, round(count / n0))
        model.gauss = WorldGaussians.from_state(split_gaussians(base, k)).to(device)
        if device == "cuda":
            torch.cuda.reset_peak_memory_stats()
        r = measure_fps(lambda: model.render(t, c2w, K, w, h), warmup=10, iters=20, device=device)
        row = {
            "num_gaussians": model.num_gaussians,
            "split_k": k,
            "fps": round(r["fps"], 1),
            "ms_per_frame": round(r["ms_per_frame"], 2),
        }
        if device == "cuda":
            row["peak_render_memory_mib"] = round(torch.cuda.max_memory_allocated() / 2**20, 1)
        res["models"].append(row)
    return res


def profile_start(run: Path, steps: int) -> int:
    """The stage-2 step a step benchmark of `steps` timed steps (after 5 warm-up ones) starts at on
    a finished run: the middle of its stage 2 or, when TLR starts later, TLR's first step (three
    renders a step), kept inside the stage."""
    from m4dgs.training.config import load_yaml

    s2 = load_yaml(Path(run) / "config.yaml").stage2
    return max(s2.iterations // 2, min(s2.tlr_start_step(), s2.iterations - steps - 5))


def _profile(clip: str, run: Path, a, device: str) -> dict:
    """bench/step_bench.py --torch-profile on `run` (stage 2 from its final model, from
    `profile_start`) on `device`; the printed lines are kept."""
    start = profile_start(run, a.profile_steps)
    cmd = [sys.executable, str(ROOT / "bench" / "step_bench.py"), clip, str(run)]
    cmd += ["--preset", a.preset, "--variant", a.variant, "--stage", "stage2", "--from-final"]
    cmd += ["--start", str(start), "--steps", str(a.profile_steps), "--device", device]
    cmd += ["--torch-profile"]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    lines = [ln for ln in (p.stdout + p.stderr).splitlines() if ln.strip()]
    head = next((ln for ln in lines if "ms/step" in ln), None)
    return {
        "rc": p.returncode,
        "seconds": round(time.perf_counter() - t0, 1),
        "start": start,
        "ms_per_step": head,
        "waits": next((ln for ln in lines if ln.startswith("host-device waits")), None),
        "lines": lines[-80:],
    }


def _jobs(clip: str, out: Path, a, device: str, progress=None) -> dict:
    """`progress(res)` after every N: a command cut at its time limit keeps the Ns it finished."""
    res = {"iters_per_stage": a.jobs_iters, "runs": {}}
    first = None  # runs per second of the first N (1 by default): the reference throughput
    for n in [int(x) for x in a.jobs.split(",") if x]:
        threads = max(1, cpu_budget() // n)  # as eval.experiments.runner.run_suite splits the CPUs
        t0 = time.perf_counter()
        procs = []
        for k in range(n):
            run = out / f"jobs{n}" / f"run{k}"
            # separate seeds, as `m4dgs-eval run --seeds` gives separate runs (no shared work)
            extra = ["--iters1", str(a.jobs_iters), "--iters2", str(a.jobs_iters), "--seed", str(k)]
            extra += ["--threads", str(threads)]
            cmd = _train_cmd(clip, run, a, device, extra)
            procs.append(
                subprocess.Popen(
                    cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
                )
            )
        rcs = [p.wait() for p in procs]
        wall = time.perf_counter() - t0
        first = first or n / wall
        res["runs"][str(n)] = {
            "wall_s": round(wall, 1),
            "rc": rcs,
            "threads_each": threads,
            "throughput_vs_first": round(n / wall / first, 2),
        }
        if progress:
            progress(res)
    return res


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("clip", help="clip folder (input/ and priors/ are enough)")
    ap.add_argument("--out", required=True, help="folder for gpu_check.json and the run")
    ap.add_argument("--steps", default=",".join(STEPS), help=f"comma-separated subset of {STEPS}")
    ap.add_argument("--preset", default="small", choices=["tiny", "small", "paper"])
    ap.add_argument("--variant", default="full")
    ap.add_argument(
        "--iters", type=int, default=None, help="train step: iterations per stage (default: preset)"
    )
    ap.add_argument("--jobs", default="1,2,4", help="numbers of concurrent trainings to time")
    ap.add_argument(
        "--jobs-iters",
        type=int,
        default=300,
        help="iterations per stage of each timed concurrent training",
    )
    ap.add_argument(
        "--fps-counts",
        default="50000,150000,300000",
        help="fps_scale step: Gaussian totals to split the trained model to",
    )
    ap.add_argument(
        "--run",
        default=None,
        help="the finished run folder that the fps, fps_scale and profile steps read (default: "
        "the train step's OUT/run)",
    )
    ap.add_argument("--profile-steps", type=int, default=30, help="profile step: timed steps")
    a = ap.parse_args()
    steps = [s for s in a.steps.split(",") if s]
    bad = [s for s in steps if s not in STEPS]
    if bad:
        ap.error(f"--steps: unknown {bad}; choose from {STEPS}")
    device = "cuda" if torch.cuda.is_available() else "cpu"
    if device == "cpu":
        print("[gpu_check] no CUDA device: running the steps on the CPU (a dry run of this script)")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    res = {"clip": a.clip, "preset": a.preset, "variant": a.variant, "steps": {}}
    run = Path(a.run) if a.run else out / "run"
    for s in steps:
        t0 = time.perf_counter()
        if s == "env":
            r = _env(device)
        elif s == "tests":
            r = _tests()
        elif s == "train":
            r = _train(a.clip, out, a, device)
        elif s == "fps":
            r = _fps(run, device)
        elif s == "profile":
            r = _profile(a.clip, run, a, device)
        elif s == "fps_scale":
            r = _fps_scale(run, device, [int(x) for x in a.fps_counts.split(",") if x])
        else:

            def progress(partial):
                res["steps"]["jobs"] = partial
                _save(out, res)

            r = _jobs(a.clip, out, a, device, progress)
        r["step_s"] = round(time.perf_counter() - t0, 1)
        res["steps"][s] = r
        _save(out, res)
        print(f"[gpu_check] {s}: {json.dumps(r, default=str)}", flush=True)


if __name__ == "__main__":
    main()
