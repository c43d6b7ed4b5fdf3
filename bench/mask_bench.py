"""Dynamic-mask accuracy of finished runs, and of the rigidity test with a depth tolerance.

    python bench/mask_bench.py RUN_DIR [RUN_DIR ...] [--depth-tolerance 0,0.1,0.2,0.5] [--json OUT]

For each run (its clip from run.json; ground-truth dynamic masks needed): precision, recall and IoU
against gt/masks/dynamic, pooled over the training frames, of
- `saved`: the masks the run trained with (model/camera_init.pt "masks"),
- `epipolar`: its epipolar masks (the paper's test, saved beside them),
- for each depth tolerance delta: the rigidity masks recomputed from the run's final bundle-adjusted
  cameras and depth scales with `reprojection_error_maps(..., depth_tolerance=delta)` and the run's
  relative threshold (masks.median_factor, masks.min_threshold), alone and OR'd with the epipolar
  masks ("union", the small preset's method). delta 0 with the run's own settings reproduces `saved`
  for a union run (the script says so), a check that the recomputation matches the trainer's.

The recomputed masks use the cameras of the run's second bundle adjustment (which ran on the saved
masks), not a second adjustment of their own, so they are an estimate of what the trainer would
make with the tolerance. The question it answers (docs/method.md, "Dynamic masks"): does a
tolerance for the depth prior's error make the rigidity test precise when the flow is good and the
depth is not, without costing the motion along the epipolar lines it exists to see?"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from eval.experiments.run_files import resolve_clip_dir
from eval.experiments.score import mask_scores
from m4dgs.clip import Clip
from m4dgs.core.threads import threads_for
from m4dgs.priors.rigidity import relative_threshold_masks, reprojection_error_maps
from m4dgs.run import RunDir, load_torch
from m4dgs.training.data import load_training_data


def bench_run(run_dir: Path, tolerances) -> list:
    """Rows {run, masks, delta, precision, recall, iou, fraction} for one run."""
    run = RunDir(run_dir)
    clip = Clip.open(resolve_clip_dir(run_dir))
    ci = load_torch(run.path("model", "camera_init.pt"))
    mc = (run.read_config() or {}).get("masks", {})
    factor, floor = float(mc.get("median_factor", 3.0)), float(mc.get("min_threshold", 1e-3))
    combine = mc.get("combine", "mean")
    gt = np.stack([clip.load_gt_dynamic_mask(g) for g in clip.train_frames])
    data = load_training_data(clip)
    fs = clip.load_flow_prior()
    index = {g: i for i, g in enumerate(data.frames)}
    keep = [p for p, (a, b) in enumerate(fs.pairs.tolist()) if a in index and b in index]
    pairs = [(index[a], index[b]) for a, b in fs.pairs[keep].tolist()]
    flow, valid = torch.from_numpy(fs.flow[keep]), torch.from_numpy(fs.valid[keep])
    saved, epi = ci["masks"].bool(), ci["masks_epipolar"].bool()
    rows = []

    def add(name, delta, m):
        s = mask_scores(m.numpy(), gt)
        rows.append(
            {
                "run": str(run_dir),
                "masks": name,
                "delta": delta,
                "precision": s["mask_precision"],
                "recall": s["mask_recall"],
                "iou": s["mask_iou"],
                "fraction": float(m.float().mean()),
            }
        )

    add("saved", None, saved)
    add("epipolar", None, epi)
    for delta in tolerances:
        err, ok = reprojection_error_maps(
            data.depth.cpu(), ci["depth_scale"], ci["K"], ci["c2w"], flow, valid, pairs,
            combine, depth_tolerance=delta,
        )  # fmt: skip
        rig = relative_threshold_masks(err, ok, factor, floor)
        add("rigidity", delta, rig)
        add("union", delta, rig | epi)
        if delta == 0 and mc.get("method") == "union":
            rows[-1]["reproduces_saved"] = bool(torch.equal(rig | epi, saved))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("runs", nargs="+", help="finished run folders (model/camera_init.pt)")
    ap.add_argument(
        "--depth-tolerance",
        default="0,0.1,0.2,0.5",
        help="comma-separated depth tolerances delta to recompute the rigidity masks with",
    )
    ap.add_argument("--json", default=None, help="also write the rows to this JSON file")
    args = ap.parse_args(argv)
    tolerances = [float(x) for x in args.depth_tolerance.split(",") if x.strip()]
    rows = []
    print("| run | masks | delta | precision | recall | IoU | dynamic fraction |")
    print("|---|---|---:|---:|---:|---:|---:|")
    with threads_for(1):
        for r in args.runs:
            for row in bench_run(Path(r), tolerances):
                rows.append(row)
                f = lambda v: "n/a" if v is None else f"{v:.2f}"  # noqa: E731
                note = " (= saved)" if row.get("reproduces_saved") else ""
                delta = "" if row["delta"] is None else row["delta"]
                print(
                    f"| {r} | {row['masks']}{note} | {delta} | {f(row['precision'])} "
                    f"| {f(row['recall'])} | {f(row['iou'])} | {row['fraction']:.3f} |"
                )
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
