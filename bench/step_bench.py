"""Time training iterations of one stage, resumed from a finished run's models: the per-iteration
figure of a code change without the minutes of camera initialisation and the stages before.

    python bench/step_bench.py CLIP RUN --stage stage1 --start 1500 --steps 60 [--threads 2]
                               [--cprofile | --torch-profile] [--device cpu|cuda]

RUN is a finished run folder of CLIP (its models and stage-1 renders are copied to a temporary
folder; RUN is not touched). Stage 1 starts from the final stage-1 model at step --start (so the
step's schedule, e.g. TLR after the densification, applies); stage 2 starts from what the trainer
starts it from (the V2W output, the masks and stage-1 renders as the variant uses them: a variant
without stage 1 works too) at --start, or with --checkpoint from RUN's mid-stage
checkpoint of stage 2 (then at its step; its optimiser settings come with it, so do not use it to
compare commits that set up the optimisers differently). Five warm-up steps, then --steps timed
steps; prints milliseconds per step and, with --cprofile, the functions that take the time, with
--torch-profile the operations (on CUDA also their GPU time and the host-device synchronisations: a
step that waits for the GPU several times is bound by those waits, not by the kernels).
With --count-ops, the tensor operations a step dispatches (views apart: they launch no kernel), by
the m4dgs function that called them (backward's operations fall on the function that called
backward): on CUDA nearly every such operation is at least one kernel launch, and a step of many
small launches is bound by the host, not by the GPU.

Compare commits side by side: check out each commit in its own worktree and run the same command
with PYTHONPATH set to it, one after the other, on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import shutil
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch  # noqa: E402
from torch.utils._python_dispatch import TorchDispatchMode  # noqa: E402

from m4dgs.core.threads import kernel_threads, use_threads  # noqa: E402
from m4dgs.model.gaussians import WorldGaussians  # noqa: E402
from m4dgs.run import load_torch  # noqa: E402
from m4dgs.training.pipeline import Trainer  # noqa: E402
from m4dgs.training.stage1 import VideoStage  # noqa: E402
from m4dgs.training.stage2 import WorldStage  # noqa: E402

PKG = str(Path(__file__).resolve().parents[1] / "m4dgs")


class OpCounter(TorchDispatchMode):
    """Counts the tensor operations dispatched while active: `ops[caller]` and `views[caller]`,
    where caller is "file:function" of the innermost frame under `package` (a folder path) on the
    Python stack, "other" when none is."""

    def __init__(self, package: str = PKG):
        super().__init__()
        self.package = package
        self.ops: Counter = Counter()
        self.views: Counter = Counter()

    def _caller(self) -> str:
        f = sys._getframe(2)
        while f is not None:
            name = f.f_code.co_filename
            if name.startswith(self.package):
                rel = name[len(self.package) :].lstrip("/")
                return f"{rel}:{f.f_code.co_name}"
            f = f.f_back
        return "other"

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        (self.views if func.is_view else self.ops)[self._caller()] += 1
        return func(*args, **(kwargs or {}))


def print_op_counts(counter: OpCounter, steps: int, top: int = 25) -> None:
    """Per-step counts, the callers with the most operations first."""
    total = sum(counter.ops.values())
    print(
        f"tensor operations per step: {total / steps:.0f} "
        f"(and {sum(counter.views.values()) / steps:.0f} views), by caller:"
    )
    for where, n in counter.ops.most_common(top):
        print(f"  {n / steps:8.1f}  {100 * n / total:5.1f}%  {where}")


def copy_run_models(src: Path, dst: Path) -> None:
    """Copy what make_stage reads of the finished run `src` into the fresh folder `dst`: its models
    and stage-1 renders (a variant without stage 1 has none), without the stage-2 checkpoint (a
    Trainer on `dst` would otherwise resume from it)."""
    shutil.copytree(src / "model", dst / "model")
    if (src / "renders" / "stage1").exists():
        shutil.copytree(src / "renders" / "stage1", dst / "renders" / "stage1")
    (dst / "model" / "ckpt.pt").unlink(missing_ok=True)


def make_stage(
    tr: Trainer, src: Path, stage: str, start: int, checkpoint: bool = False, final: bool = False
):
    """The stage object of `tr` loaded from the copied models, on `tr.device`; returns (stage, first
    step). Stage 2 starts where the trainer starts it (Trainer.world_init: the same Gaussians,
    appearance, cameras, masks and stage-1 renders for the run's variant). final: stage 2 starts
    from the run's final Gaussians, appearance and cameras (model/final.pt: the size stage 2 has
    late in a run) instead of the V2W output."""
    cfg, d, dev = tr.cfg, tr.data, tr.device
    if stage == "stage1":
        st = VideoStage(d, cfg, dev, cfg.raster_backend, init=False)
        st.load_state_dict(load_torch(tr.run.path("model", "stage1.pt")))
        return st, start
    init = tr.world_init()
    if final:
        f = load_torch(src / "model" / "final.pt", map_location=dev)
        init.color.load_state_dict(f["color"])
        init.tonemap.load_state_dict(f["tonemap"])
        init.background.load_state_dict(f["background"])
        init.gauss = WorldGaussians.from_state(f["gaussians"])
        init.c2w = f["c2w"]
    st = WorldStage(d, cfg, init, dev, cfg.raster_backend)
    ck = src / "model" / "ckpt.pt"
    if checkpoint and ck.exists():
        sd = load_torch(ck)
        if sd.get("stage") == "stage2":
            st.load_state_dict(sd["state"])
            return st, int(sd["step"])
    return st, start


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("clip", help="clip folder")
    ap.add_argument("run", help="a finished run folder of the clip (read only)")
    ap.add_argument("--stage", choices=["stage1", "stage2"], default="stage1")
    ap.add_argument("--start", type=int, default=0, help="first step (schedule position)")
    ap.add_argument("--steps", type=int, default=60, help="timed steps (after 5 warm-up steps)")
    ap.add_argument("--preset", default="small", choices=["tiny", "small", "paper"])
    ap.add_argument("--variant", default="full")
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
    ap.add_argument("--cprofile", action="store_true", help="print the top functions (cProfile)")
    ap.add_argument(
        "--checkpoint",
        action="store_true",
        help="stage 2: start from RUN's mid-stage checkpoint instead of the V2W output",
    )
    ap.add_argument(
        "--from-final",
        action="store_true",
        help="stage 2: start from RUN's final model (its late-stage Gaussian count) at --start",
    )
    ap.add_argument(
        "--torch-profile",
        action="store_true",
        help="print the top operations by self CPU time (torch profiler) over the timed steps",
    )
    ap.add_argument(
        "--count-ops",
        action="store_true",
        help="count the tensor operations of the timed steps by calling m4dgs function (not timed: "
        "the counting slows the steps)",
    )
    ap.add_argument(
        "--device",
        default="cpu",
        choices=["cpu", "cuda"],
        help="where the stage runs (cuda: gsplat rasterizes; the timing synchronises the device)",
    )
    a = ap.parse_args()
    if a.torch_threads:
        torch.set_num_threads(a.torch_threads)
    else:
        use_threads(a.threads, a.device)
    cuda = a.device == "cuda"
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    src = Path(a.run)
    if a.stage == "stage1":
        need = ["model/stage1.pt", "renders/stage1"]
    else:  # stage 1's renders too where the variant has a stage 1 (Trainer.world_init says)
        need = ["model/camera_init.pt", "model/v2w.pt"] + (
            ["model/final.pt"] if a.from_final else []
        )
    missing = [n for n in need if not (src / n).exists()]
    if missing:
        ap.error(f"{src} lacks {', '.join(missing)}: RUN must be a run that got past that stage")
    tmp = Path(tempfile.mkdtemp(prefix="step_bench_"))
    try:
        copy_run_models(src, tmp)
        tr = Trainer(a.clip, tmp, a.preset, a.variant, {}, a.device, progress=False)
        st, start = make_stage(tr, src, a.stage, a.start, a.checkpoint, a.from_final)
        for it in range(start, start + 5):
            st.step(it)
        prof = cProfile.Profile() if a.cprofile else None
        tprof = None
        if a.torch_profile:
            from torch.profiler import ProfilerActivity, profile

            acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
            tprof = profile(activities=acts)
            tprof.__enter__()
        counter = OpCounter() if a.count_ops else None
        if counter is not None:
            counter.__enter__()
        sync()
        t0 = time.perf_counter()
        if prof:
            prof.enable()
        for it in range(start + 5, start + 5 + a.steps):
            st.step(it)
        sync()
        if counter is not None:
            counter.__exit__(None, None, None)
        if prof:
            prof.disable()
        dt = time.perf_counter() - t0
        if tprof is not None:
            tprof.__exit__(None, None, None)
        print(
            f"{a.stage} steps {start + 5}..{start + 4 + a.steps}: "
            f"{1000 * dt / a.steps:.1f} ms/step "
            f"({st.gauss.num_gaussians} Gaussians, {torch.get_num_threads()} torch / "
            f"{kernel_threads()} kernel threads, "
            f"load average {os.getloadavg()[0]:.2f})"
        )
        if prof:
            pstats.Stats(prof).sort_stats("cumulative").print_stats(30)
        if counter is not None:
            print_op_counts(counter, a.steps)
        if tprof is not None:
            ev = tprof.key_averages()
            print(ev.table(sort_by="self_cpu_time_total", row_limit=30))
            if cuda:
                print(ev.table(sort_by="self_device_time_total", row_limit=20))
                waits = {
                    e.key: e.count
                    for e in ev
                    if e.key
                    in ("cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaMemcpyAsync")
                    or e.key.startswith("aten::_local_scalar_dense")
                }
                print(
                    "host-device waits per step: "
                    + ", ".join(f"{k} {v / a.steps:.1f}" for k, v in sorted(waits.items()))
                )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
