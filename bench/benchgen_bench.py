"""Clip generation speed: frames/s and total time for a suite (default: syn-exp-3 at the small
preset).

    python bench/benchgen_bench.py [--suite syn-exp-3] [--preset small] [--out /tmp/benchgen-bench]
    [--spp N]

Generates into a fresh folder (nothing is skipped) and prints per-clip and total figures. The target
for the small 9-scene suite on a 2-core machine is at most 15 minutes."""

from __future__ import annotations

import argparse
import os
import shutil
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from benchgen.exposure import ExposureSettings  # noqa: E402
from benchgen.make import get_preset, make_clip  # noqa: E402
from benchgen.suite import load_suite  # noqa: E402
from m4dgs.clip import Clip  # noqa: E402


def main():
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--suite", default="syn-exp-3")
    ap.add_argument("--preset", default="small")
    ap.add_argument("--out", default="/tmp/benchgen-bench")
    ap.add_argument("--scenes", default=None, help="comma-separated subset")
    ap.add_argument("--spp", type=int, default=None, help="override the preset's samples per pixel")
    a = ap.parse_args()
    s = load_suite(a.suite)
    out = Path(a.out)
    if out.exists():
        shutil.rmtree(out)
    settings = ExposureSettings(tuple(s.observed), tuple(s.novel), s.schedule)
    total_frames, t_all = 0, time.perf_counter()
    pick = None if a.scenes is None else set(a.scenes.split(","))
    for p in s.scenes:
        if pick is not None and p.stem not in pick:
            continue
        t0 = time.perf_counter()
        clip_dir = make_clip(
            p, out / p.stem, a.preset, settings, "realistic", 0, progress=False, spp=a.spp
        )
        dt = time.perf_counter() - t0
        c = Clip.open(clip_dir)
        n = c.meta.num_frames
        total_frames += n
        gt = c.meta.gt
        print(
            f"{p.stem:28s} {n:4d} frames {dt:7.1f} s  {n / dt:5.2f} frames/s  "
            f"dyn {gt.get('dynamic_fraction', 0):.2f}  range "
            f"{gt.get('dynamic_range_stops', 0):.1f} stops  "
            f"TAE floor {gt.get('hdr_tae_floor') or float('nan'):.3f}  noise "
            f"{gt['render_noise']['tae_two_seeds']:.3f} "
            f"({gt['render'].get('emitter_sampling', 'uniform')})",
            flush=True,
        )
    dt = time.perf_counter() - t_all
    pr = get_preset(a.preset)
    print(
        f"total: {total_frames} frames at {pr.width}x{pr.height} in {dt / 60:.1f} min "
        f"({total_frames / dt:.2f} frames/s)"
    )


if __name__ == "__main__":
    main()
