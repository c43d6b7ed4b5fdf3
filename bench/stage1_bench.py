"""Stage-1 speed on a clip: iterations/s and peak memory of the video-Gaussian optimisation.

    python bench/stage1_bench.py CLIP_DIR [--iterations 200] [--preset small] [--backend auto]

Prints the measured figures (after a warm-up that builds the C++ rasterizer); with
OMP_WAIT_POLICY=PASSIVE."""

from __future__ import annotations

import argparse
import os
import resource
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch  # noqa: E402

from m4dgs.clip import Clip  # noqa: E402
from m4dgs.raster import resolve_backend  # noqa: E402
from m4dgs.training.data import load_training_data  # noqa: E402
from m4dgs.training.pipeline import resolve_config  # noqa: E402
from m4dgs.training.stage1 import VideoStage  # noqa: E402


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("clip")
    ap.add_argument(
        "--iterations", type=int, default=200, help="timed iterations (after 10 warm-up ones)"
    )
    ap.add_argument("--preset", default="small")
    ap.add_argument("--backend", default="auto")
    ap.add_argument(
        "--start",
        type=int,
        default=0,
        help="iteration index to time from (e.g. past densification to include TLR)",
    )
    a = ap.parse_args()
    clip = Clip.open(a.clip)
    cfg = resolve_config(clip, a.preset)
    data = load_training_data(clip)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.perf_counter()
    stage = VideoStage(data, cfg, "cpu", a.backend)
    t_init = time.perf_counter() - t0
    for i in range(10):
        stage.step(a.start + i)
    t0 = time.perf_counter()
    for i in range(a.iterations):
        stage.step(a.start + 10 + i)
    dt = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        f"clip {clip.meta.name} {clip.width}x{clip.height}, {data.num_frames} training frames, "
        f"preset {a.preset}"
    )
    print(
        f"threads {torch.get_num_threads()}, OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY')}, "
        f"backend {resolve_backend(stage.backend, stage.device)}"
    )
    print(f"init (lift + tone-mapper pre-training): {t_init:.1f} s")
    print(f"Gaussians: {stage.gauss.num_gaussians}")
    print(
        f"stage 1: {a.iterations / dt:.2f} it/s ({1000 * dt / a.iterations:.1f} ms/it) from "
        f"iteration {a.start}"
    )
    print(f"peak RSS: {peak:.0f} MiB (before the model: {rss0:.0f} MiB)")


if __name__ == "__main__":
    main()
