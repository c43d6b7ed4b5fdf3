"""Where the time of one training run goes: wall time per phase, iterations/s, top operations.

    python bench/train_bench.py CLIP [--preset small] [--variant full] [--iters1 N] [--iters2 N]
                                     [--profile-steps 20] [--threads 2] [--out DIR] [--no-score]
                                     [--device cuda] [--seed N] [--set KEY=VALUE ...] [--share DIR]

Trains `variant` on `CLIP` into a fresh run folder (default: a temporary one), timing each phase of
the pipeline (camera_init, stage1, v2w, stage2, render) and the scoring (`eval score`), then prints:
- the wall time of every phase and its share of the total;
- iterations per second of stage 1 and stage 2;
- the top operations of an iteration of each stage (torch profiler over `--profile-steps` steps
  taken after 10 warm-up steps, self CPU time), so the profile, not guessing, picks a speed-up.
`--iters1/--iters2` shorten the stages (the per-iteration figures stay representative; the phase
shares then are not). The figures are wall times on this machine: they mean something only on an
otherwise idle machine, compared side by side with the same command on another commit.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch  # noqa: E402
from torch.profiler import ProfilerActivity, profile, schedule  # noqa: E402

from m4dgs.core.threads import kernel_threads, use_threads  # noqa: E402
from m4dgs.run import RunDir  # noqa: E402
from m4dgs.training.pipeline import Trainer  # noqa: E402

PHASES = ("camera_init", "stage1", "v2w", "stage2", "render")


class StepProfiler:
    """Profiles steps [warmup, warmup + active) of each stage, driven by the run's per-step log."""

    def __init__(self, active: int, warmup: int = 10):
        self.active, self.warmup = active, warmup
        self.prof = None
        self.stage = None
        self.tables = {}

    def on_log(self, rec: dict) -> None:
        stage = rec.get("stage")
        if stage not in ("stage1", "stage2") or self.active <= 0:
            return
        if stage != self.stage:
            self.close()
            self.stage = stage
            self.prof = profile(
                activities=[ProfilerActivity.CPU],
                schedule=schedule(wait=self.warmup, warmup=1, active=self.active, repeat=1),
            )
            self.prof.__enter__()
        if self.prof is not None:
            self.prof.step()

    def close(self) -> None:
        if self.prof is not None:
            self.prof.__exit__(None, None, None)
            try:
                self.tables[self.stage] = self.prof.key_averages().table(
                    sort_by="self_cpu_time_total", row_limit=15
                )
            except (AssertionError, RuntimeError):  # fewer steps than the schedule needs
                self.tables[self.stage] = "(not enough steps to profile)"
            self.prof = None


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("clip", help="clip folder (benchgen make output)")
    ap.add_argument("--preset", default="small", choices=["tiny", "small", "paper"])
    ap.add_argument("--variant", default="full")
    ap.add_argument("--iters1", type=int, default=None, help="stage-1 iterations (default: preset)")
    ap.add_argument("--iters2", type=int, default=None, help="stage-2 iterations (default: preset)")
    ap.add_argument(
        "--profile-steps", type=int, default=20, help="profiled steps per stage (0: off)"
    )
    ap.add_argument(
        "--threads",
        type=int,
        default=None,
        help="CPU threads, spent as `m4dgs train` spends them (m4dgs.core.threads.use_threads: "
        "torch 1, the rasterizer N; default: every CPU)",
    )
    ap.add_argument(
        "--torch-threads",
        type=int,
        default=None,
        help="instead: torch.set_num_threads(N), the rasterizer following torch (the split "
        "before m4dgs.core.threads)",
    )
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--seed", type=int, default=None, help="trainer seed (default: the preset's)")
    ap.add_argument(
        "--set",
        dest="sets",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="config override, as `m4dgs train --set` takes it (repeatable)",
    )
    ap.add_argument(
        "--share",
        default=None,
        metavar="DIR",
        help="share folder of identical phases (m4dgs.training.phases): a later run of the same "
        "clip takes, e.g., the camera initialisation from it instead of computing it again (that "
        "phase's seconds then are the copy's)",
    )
    ap.add_argument("--out", default=None, help="run folder (default: a temporary one, deleted)")
    ap.add_argument("--no-score", action="store_true", help="skip timing `eval score`")
    a = ap.parse_args()
    if a.torch_threads:
        torch.set_num_threads(a.torch_threads)
    else:
        use_threads(a.threads, a.device)
    overrides = {}
    for kv in a.sets:
        if "=" not in kv:
            ap.error(f"--set: expected KEY=VALUE, got {kv!r}")
        k, v = kv.split("=", 1)
        overrides[k.strip()] = v.strip()
    if a.iters1 is not None:
        overrides["stage1.iterations"] = a.iters1
    if a.iters2 is not None:
        overrides["stage2.iterations"] = a.iters2
    if a.seed is not None:
        overrides["seed"] = a.seed
    tmp = None
    out = Path(a.out) if a.out else Path(tmp := tempfile.mkdtemp(prefix="train_bench_")) / "run"
    if out.exists():
        shutil.rmtree(out)

    prof = StepProfiler(a.profile_steps)
    log = RunDir.log

    def log_and_profile(self, rec):
        log(self, rec)
        prof.on_log(rec)

    RunDir.log = log_and_profile
    wall = {}
    t_all = time.perf_counter()
    t0 = time.perf_counter()
    tr = Trainer(
        a.clip, out, a.preset, a.variant, overrides, a.device, progress=False, share_dir=a.share
    )
    wall["set-up (config, data)"] = time.perf_counter() - t0
    for phase in PHASES:
        if phase == "stage1" and not tr.cfg.ablation.use_video_init:
            continue
        t0 = time.perf_counter()
        # seeded as `m4dgs train` seeds it, through the share folder when one is given: the same
        # run, timed by phase
        tr.run_phase(phase)
        if phase in ("stage1", "stage2"):
            prof.close()
        wall[phase] = time.perf_counter() - t0
    RunDir.log = log
    if not a.no_score:
        from eval.experiments.score import score_run

        t0 = time.perf_counter()
        score_run(out, fps=False)
        wall["score"] = time.perf_counter() - t0
    total = time.perf_counter() - t_all

    iters = {s: getattr(tr.cfg, s).iterations for s in ("stage1", "stage2")}
    print(
        f"# {Path(a.clip).name}, preset {a.preset}, variant {a.variant}, device {a.device}, "
        f"torch threads {torch.get_num_threads()}, kernel threads {kernel_threads()}, "
        f"load average {os.getloadavg()[0]:.2f}"
    )
    print(f"{'phase':24s} {'seconds':>9s} {'share':>6s}  iterations/s")
    for k, v in wall.items():
        rate = f"{iters[k] / v:8.2f} ({iters[k]} it)" if k in iters and v > 0 else ""
        print(f"{k:24s} {v:9.1f} {100 * v / total:5.1f}%  {rate}")
    print(f"{'total':24s} {total:9.1f}")
    for stage, table in prof.tables.items():
        print(
            f"\n## top operations of a {stage} iteration ({a.profile_steps} steps, self CPU time)"
        )
        print(table)
    if tmp:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
