"""Benchmark of the camera initialisation (dynamic masks from the flow prior + MoSca-style init +
BA) on clips.

    python bench/camera_init_bench.py CLIP_DIR [CLIP_DIR ...] [--preset tiny|small|full] [--ba-steps
    N]
        [--threshold T] [--units px|ndc] [--masks epipolar|gt|none] [--flow prior|opencv] [--json
        OUT.json]

Per clip (ground truth needed for the scores): wall time, focal error (%), ATE after Sim(3)
alignment (absolute in GT units and relative to the GT trajectory path length, %), RPE (translation
in GT units, rotation in degrees; eval.metrics.geometry conventions), dynamic-mask IoU against
gt/masks/dynamic (pooled over the training frames), the chosen fov and the number of static tracks.
Clips without priors/flow.npz use the OpenCV fallback (m4dgs.priors.epipolar.opencv_flow_prior).
Timings on a shared machine are noisy."""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

from m4dgs.clip import Clip
from m4dgs.priors.camera_init import CameraInitConfig, initialize_cameras
from m4dgs.priors.epipolar import (
    EpipolarConfig,
    dynamic_masks,
    epipolar_error_maps,
    opencv_flow_prior,
)


def run_clip(
    root,
    cam_cfg: CameraInitConfig,
    epi_cfg: EpipolarConfig,
    masks_from: str = "epipolar",
    flow: str = "prior",
) -> dict:
    """Masks + camera init on one clip; returns a row of metrics (see module docstring).

    masks_from: "epipolar" (from the flow), "gt" (ground-truth masks, an upper bound) or "none" (all
    static). flow: "prior" (priors/flow.npz, OpenCV fallback when missing) or "opencv" (always the
    OpenCV fallback)."""
    from eval.metrics.geometry import ate, rpe

    clip = Clip.open(root)
    frames = clip.train_frames
    W, H = clip.width, clip.height
    depth = np.stack([clip.load_depth_prior(g) for g in frames])
    tracks = clip.load_tracks_prior()
    t0 = time.perf_counter()
    flow_src = "prior"
    if masks_from == "epipolar":
        if flow == "prior" and clip.has_flow_prior():
            fs = clip.load_flow_prior()
        else:
            fs = opencv_flow_prior(
                np.stack([clip.load_ldr(g) for g in frames]), clip.train_dt, frames
            )
            flow_src = "opencv"
        err = epipolar_error_maps(fs, frames, epi_cfg)
        masks = dynamic_masks(err, epi_cfg.threshold)
    elif masks_from == "gt":
        masks = torch.as_tensor(np.stack([clip.load_gt_dynamic_mask(g) for g in frames]))
    else:
        masks = None
    t1 = time.perf_counter()
    res = initialize_cameras(tracks, depth, masks, W, H, cam_cfg)
    t2 = time.perf_counter()
    row = {
        "clip": Path(root).name,
        "T": len(frames),
        "flow": flow_src,
        "time_s": t2 - t0,
        "mask_time_s": t1 - t0,
        "init_time_s": t2 - t1,
        "init_timings_s": res.diagnostics.get("timings_s", {}),
        "fov_search_deg": res.diagnostics.get("fov_init_deg", float("nan")),
        "fov_deg": res.diagnostics.get("fov_final_deg", float("nan")),
        "fov_fallback": bool(res.diagnostics.get("fov_fallback", False)),
        "static_tracks": int(res.static_track_mask.sum()),
        "tracks": int(res.static_track_mask.numel()),
    }
    if clip.has_gt:
        cams = clip.load_gt_cameras()
        sel = [cams.frames.tolist().index(g) for g in frames]
        gt_c2w = cams.c2w[sel]
        f_gt = float(cams.K[sel[0], 0, 0])
        est = res.c2w.numpy()
        path_len = float(np.linalg.norm(np.diff(gt_c2w[:, :3, 3], axis=0), axis=1).sum())
        a = ate(est, gt_c2w)
        r = rpe(est, gt_c2w)
        row.update(
            focal_err_pct=100 * abs(float(res.K[0, 0]) / f_gt - 1),
            fov_gt_deg=2 * math.degrees(math.atan(W / 2 / f_gt)),
            ate=a,
            ate_rel_pct=100 * a / max(path_len, 1e-12),
            path_len=path_len,
            rpe_trans=r["rpe_trans"],
            rpe_rot_deg=r["rpe_rot"],
        )
        if masks is not None:
            gm = np.stack([clip.load_gt_dynamic_mask(g) for g in frames])
            pm = np.asarray(masks, bool)
            union = (gm | pm).sum()
            row["mask_iou"] = float((gm & pm).sum() / union) if union else 1.0
    return row


COLUMNS = [  # key, header, width, format
    ("clip", "clip", 18, "s"),
    ("T", "T", 4, "d"),
    ("time_s", "time", 7, ".1f"),
    ("fov_gt_deg", "fovGT", 6, ".1f"),
    ("fov_deg", "fov", 6, ".1f"),
    ("focal_err_pct", "f err%", 7, ".2f"),
    ("ate", "ATE", 8, ".4f"),
    ("ate_rel_pct", "ATE%", 7, ".2f"),
    ("rpe_trans", "RPE-t", 8, ".4f"),
    ("rpe_rot_deg", "RPE-r", 7, ".3f"),
    ("mask_iou", "IoU", 6, ".3f"),
    ("static_tracks", "static", 6, "d"),
]


def format_table(rows) -> str:
    """Fixed-width text table of the rows (missing values as '-')."""

    def cell(v, w, f):
        if v is None or (isinstance(v, float) and not math.isfinite(v)):
            return "-".rjust(w)
        return f"{v:<{w}{f}}" if f == "s" else f"{v:>{w}{f}}"

    lines = [" ".join(h.ljust(w) if f == "s" else h.rjust(w) for _, h, w, f in COLUMNS)]
    for r in rows:
        lines.append(" ".join(cell(r.get(k), w, f) for k, _, w, f in COLUMNS))
    lines.append(
        "time = masks + camera init (s); ATE in GT units after Sim(3) alignment, ATE% of the GT "
        "path length; "
        "RPE-t GT units, RPE-r degrees; IoU = dynamic masks vs gt (pooled)"
    )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("clips", nargs="+")
    ap.add_argument(
        "--preset",
        default="full",
        help="tiny | small | full: BA steps 300 / 800 / 2000, static tracks 1024 / 2048 / 4096",
    )
    ap.add_argument("--ba-steps", type=int, default=None)
    ap.add_argument("--ba-dtype", choices=["float64", "float32"], default=None)
    ap.add_argument(
        "--threshold", type=float, default=None, help="epipolar threshold (units of --units)"
    )
    ap.add_argument("--units", default="px", choices=["px", "ndc"])
    ap.add_argument("--masks", default="epipolar", choices=["epipolar", "gt", "none"])
    ap.add_argument(
        "--flow",
        default="prior",
        choices=["prior", "opencv"],
        help="flow for the masks: the clip's prior (OpenCV fallback when missing) or always "
        "OpenCV DIS",
    )
    ap.add_argument("--json", default=None, help="also write the rows to this JSON file")
    args = ap.parse_args(argv)
    cam_cfg = CameraInitConfig.for_preset(args.preset)
    if args.ba_dtype is not None:
        cam_cfg.ba_dtype = args.ba_dtype
    if args.ba_steps is not None:
        cam_cfg.ba_steps = args.ba_steps
        cam_cfg.depth_correction_start = min(cam_cfg.depth_correction_start, args.ba_steps // 4)
    epi_cfg = EpipolarConfig(units=args.units)
    if args.units == "ndc":
        epi_cfg.threshold = 1e-5
    if args.threshold is not None:
        epi_cfg.threshold = args.threshold
    rows = []
    for c in args.clips:
        rows.append(run_clip(c, cam_cfg, epi_cfg, args.masks, args.flow))
        print(f"done {c}", file=sys.stderr, flush=True)
    print(format_table(rows))
    if args.json:
        from m4dgs.core.io import write_json

        write_json(
            args.json, {"camera_init": cam_cfg.__dict__, "epipolar": epi_cfg.__dict__, "rows": rows}
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
