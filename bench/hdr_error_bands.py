"""Where a run's HDR PSNR error sits: the share of the mu-law squared error (the HDR PSNR metric's
own tone mapping, eval.metrics.hdr_tonemap_pair) in the brightest 1 % of the ground truth's pixels
and in pixels the clip never recorded unclipped, and the prediction's scale in the mid-tones.

    python bench/hdr_error_bands.py RUN_DIR [RUN_DIR ...] [--ref ROW] [--json OUT.json]

Per run (its clip from run.json, test frames from renders/test/hdr): HDR PSNR of the pooled error
(close to, not equal to, `metrics.json` hdr_psnr, which averages per-image PSNR); the share of the
squared error in the brightest 1 % of each frame's pixels (by the ground truth's max channel); the
share in "never observed" pixels, whose brightest channel times the shortest training exposure
time is past the exposure at which the clip's response reaches code 254.5 (saturated in every
training frame), and the fraction of values those are; and the median prediction / ground truth
luminance ratio over the 20th-90th percentile of each frame's luminance (a global scale error
shows there, a highlight error does not). Used to read the crf suite's HDR PSNR differences
(lab/notes/crf.md).

--ref ROW: each run beside the run of row ROW on the same scene and seed (run folders
ROOT/runs/SUITE/SCENE/ROW for seed 0 and ROW-seed-K for seed K, as `m4dgs-eval run` names them):
how many times its squared error in the brightest 1 % and in the other 99 % of the pixels is the
reference's (the exposure-schedules reading, lab/notes/exposure-schedules.md).

`m4dgs-eval regions RUN --ref RUN --bright-top 0.01` gives the same brightest-1 % ratio (its "hdr"
row, "bright err x"; lamp-room-orbit's random values at seed 1: x2.36 in both) and splits the rest
into moving and static pixels, at every LDR level too; this script keeps what that command does
not have: the never-observed band and the mid-tone scale."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np


def error_bands(
    pred: np.ndarray, gt: np.ndarray, saturation_exposure: float, dt_min: float
) -> Dict:
    """Sums for one frame. pred, gt: [H, W, 3] linear HDR; saturation_exposure: H * dt at which
    the response saturates; dt_min: the shortest observed exposure time. Returns {sq_err, n,
    sq_err_top1, sq_err_never, n_never, mid_ratio}."""
    from eval.metrics import hdr_tonemap_pair

    p, g = hdr_tonemap_pair(pred, gt)
    e = ((p - g) ** 2)[0].numpy()  # [H, W, 3]
    peak = gt.max(-1)
    top = peak >= np.quantile(peak, 0.99)
    never = peak * dt_min > saturation_exposure
    lum_g, lum_p = gt.mean(-1), pred.mean(-1)
    mid = (lum_g > np.quantile(lum_g, 0.2)) & (lum_g < np.quantile(lum_g, 0.9)) & (lum_g > 0)
    return {
        "sq_err": float(e.sum()),
        "n": int(e.size),
        "sq_err_top1": float(e[top].sum()),
        "sq_err_never": float(e[never].sum()),
        "n_never": int(never.sum()) * 3,
        "mid_ratio": float(np.median(lum_p[mid] / lum_g[mid])) if mid.any() else float("nan"),
    }


def run_bands(run_dir) -> Dict:
    """error_bands over a run's test frames, pooled; the clip is the one run.json names."""
    from m4dgs.clip import Clip
    from m4dgs.core import io as mio
    from m4dgs.core.crf import get_crf

    run = Path(run_dir)
    if not (run / "run.json").is_file():
        raise ValueError(f"{run}: not a run folder (no run.json)")
    info = json.loads((run / "run.json").read_text())
    clip_root = (run / info["clip"]).resolve() if "clip" in info else Path(info["clip_abs"])
    if not (clip_root / "clip.json").exists():
        clip_root = Path(info["clip_abs"])
    clip = Clip.open(clip_root)
    crf = get_crf(clip.meta.crf)
    saturation = float(np.min(crf.inverse_rgb(np.full(3, 254.5 / 255.0))))
    dt_min = float(min(clip.meta.exposures.train_dt))
    sums, ratios = (
        {"sq_err": 0.0, "n": 0, "sq_err_top1": 0.0, "sq_err_never": 0.0, "n_never": 0},
        [],
    )
    frames = sorted((run / "renders" / "test" / "hdr").glob("*.exr"))
    if not frames:
        raise ValueError(f"{run}: no renders/test/hdr/*.exr")
    for p in frames:
        b = error_bands(mio.read_exr(p), clip.load_gt_hdr(int(p.stem)), saturation, dt_min)
        ratios.append(b.pop("mid_ratio"))
        for k in sums:
            sums[k] += b[k]
    mse = sums["sq_err"] / sums["n"]
    return {
        "run": str(run),
        "mse_top1": sums["sq_err_top1"] / sums["n"],
        "mse_rest": (sums["sq_err"] - sums["sq_err_top1"]) / sums["n"],
        "crf": clip.meta.crf,
        "frames": len(frames),
        "pooled_hdr_psnr": -10 * math.log10(mse) if mse > 0 else float("inf"),
        "share_top1": sums["sq_err_top1"] / sums["sq_err"] if sums["sq_err"] else 0.0,
        "share_never_observed": sums["sq_err_never"] / sums["sq_err"] if sums["sq_err"] else 0.0,
        "never_observed_fraction": sums["n_never"] / sums["n"],
        "mid_tone_scale": float(np.median(ratios)),
    }


def run_key(run) -> Tuple[str, str, int]:
    """(scene, row, trainer seed) of a run folder SCENE/ROW (seed 0) or SCENE/ROW-seed-K, as
    `m4dgs-eval run` names them (eval.experiments.runner.split_run_name)."""
    from eval.experiments.runner import split_run_name

    p = Path(run)
    return (p.parent.name, *split_run_name(p.name))


def reference_ratios(rows: List[Dict], ref_row: str) -> List[Dict]:
    """For each row of run_bands whose run is not of row ref_row: {"run", "ref", "top1", "rest"},
    its mean squared error in the brightest 1 % and in the rest divided by the same of the ref_row
    run with the same scene and seed (both scored on the same test frames). ValueError when that
    run is missing."""
    from eval.experiments.runner import seed_run_name

    refs = {}
    for r in rows:
        scene, row, seed = run_key(r["run"])
        if row == ref_row:
            refs[scene, seed] = r
    out = []
    for r in rows:
        scene, row, seed = run_key(r["run"])
        if row == ref_row:
            continue
        ref = refs.get((scene, seed))
        if ref is None:
            name = seed_run_name(ref_row, seed)
            raise ValueError(f"{r['run']}: no {name} run of {scene} among the runs")
        out.append(
            {
                "run": r["run"],
                "ref": ref["run"],
                "top1": r["mse_top1"] / ref["mse_top1"] if ref["mse_top1"] else math.inf,
                "rest": r["mse_rest"] / ref["mse_rest"] if ref["mse_rest"] else math.inf,
            }
        )
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="run folders (with run.json and renders/test/hdr)")
    ap.add_argument(
        "--ref",
        default=None,
        metavar="ROW",
        help="also each run's error in the brightest 1 %% and in the rest as a multiple of the "
        "ROW run of the same scene and seed (run folders SCENE/ROW, SCENE/ROW-seed-K)",
    )
    ap.add_argument("--json", default=None, help="also write the rows to this JSON file")
    args = ap.parse_args(argv)
    rows = [run_bands(r) for r in args.runs]
    head = ("run", "crf", "PSNR", "top 1%", "never", "of vals", "mid x")
    print("{:50s} {:14s} {:>6s} {:>7s} {:>6s} {:>8s} {:>6s}".format(*head))
    for r in rows:
        cells = (
            r["run"][-50:],
            r["crf"],
            r["pooled_hdr_psnr"],
            r["share_top1"],
            r["share_never_observed"],
            100 * r["never_observed_fraction"],
            r["mid_tone_scale"],
        )
        print("{:50s} {:14s} {:6.2f} {:7.2f} {:6.2f} {:7.2f}% {:6.3f}".format(*cells))
    ratios = reference_ratios(rows, args.ref) if args.ref else []
    if ratios:
        print(f"\nsquared error against {args.ref} (same scene and seed): brightest 1 %, rest")
        for r in ratios:
            print("{:50s} x{:5.2f}  x{:5.2f}".format(r["run"][-50:], r["top1"], r["rest"]))
    if args.json:
        from m4dgs.core.io import write_json

        write_json(args.json, {"rows": rows, **({"ratios": ratios} if args.ref else {})})
    return 0


if __name__ == "__main__":
    sys.exit(main())
