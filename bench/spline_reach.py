"""How closely the position spline can follow a clip's true movers, at each control-point interval.

    python bench/spline_reach.py CLIP [CLIP ...] [--every 1 2 4 8] [--json OUT]

A video Gaussian of stage 1 moves along a cubic Hermite spline with a control point every N_s
training frames (m4dgs.core.spline; `model.control_every`, the paper's N_s = 4). Its x, y are the
pixel coordinates up to an affine map (m4dgs.core.camera.ortho_to_pixel), so the spline's best fit
to a point's pixel path bounds how closely any Gaussian can follow that point.

For every ground-truth point track on a moving object (gt/tracks.npz, `dynamic`) that is visible at
half of the training frames or more, this fits that spline (the trainer's knots,
m4dgs.core.spline.make_knots) to the track's pixels at its visible training frames by least squares
(with a faint curvature penalty for the control points no visible frame decides) and measures the
distance, in pixels, from the fitted curve to the track: the root mean square over
the visible training frames (the fit) and over the visible test frames between two visible training
frames (what the test frames see). Printed per clip and N_s: the median and 90th percentile of each
over the tracks, with the tracks' median speed in pixels per training frame. It reads only the
clip, not a run: a figure for choosing N_s for a clip's motion, not a score.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np
import torch

from m4dgs.clip import Clip
from m4dgs.core import spline

MIN_VISIBLE = 0.5  # fraction of the training frames a track must be visible at to be fitted
RIDGE = 1e-3  # weight of the curvature rows (px per frame^2) beside the position rows (px)


def track_residuals(
    train_xy: np.ndarray,
    train_vis: np.ndarray,
    test_xy: np.ndarray,
    test_vis: np.ndarray,
    every: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The spline fit of each track at interval `every`.

    Args:
        train_xy: [N, T, 2] pixel positions at the T training frames.
        train_vis: [N, T] bool, visible there.
        test_xy: [N, T - 1, 2] positions at the test frames between training frames t and t + 1
            (times t + 0.5 in training-frame units).
        test_vis: [N, T - 1] bool, visible there.
        every: control-point interval N_s in training frames.
    Returns:
        (fit, between): [N] root-mean-square distances in pixels over the visible training frames,
        and over the visible test frames whose two neighbouring training frames are visible (NaN
        where there is none).
    """
    n, t = train_vis.shape
    knots = spline.make_knots(t, every, dtype=torch.float64)
    b_train = spline.basis_matrix(knots, torch.arange(t, dtype=torch.float64)).numpy()  # [T, K]
    b_test = spline.basis_matrix(
        knots, torch.arange(t - 1, dtype=torch.float64) + 0.5
    ).numpy()  # [T - 1, K]
    # a faint curvature penalty decides the control points that no visible frame constrains (a track
    # hidden for a while): straight through them rather than least-norm (towards pixel 0)
    reg = RIDGE * spline.second_difference_matrix(knots).numpy()  # [K - 2, K]
    zeros = np.zeros((reg.shape[0], 2))
    fit = np.full(n, np.nan)
    between = np.full(n, np.nan)
    for i in range(n):
        v = train_vis[i]
        a = np.concatenate([b_train[v], reg])
        ctrl, *_ = np.linalg.lstsq(a, np.concatenate([train_xy[i, v], zeros]), rcond=None)  # [K, 2]
        fit[i] = np.sqrt(np.mean(np.sum((b_train[v] @ ctrl - train_xy[i, v]) ** 2, -1)))
        w = test_vis[i] & v[:-1] & v[1:]
        if w.any():
            d = np.sum((b_test[w] @ ctrl - test_xy[i, w]) ** 2, -1)
            between[i] = np.sqrt(np.mean(d))
    return fit, between


def reach_report(clip_dir: Path, every: Sequence[int] = (1, 2, 4, 8)) -> Dict:
    """Per N_s, the spline's distance to the clip's moving tracks (see the module docstring)."""
    clip = Clip.open(clip_dir)
    tracks = clip.load_gt_tracks()
    frames = [int(f) for f in tracks.frames]
    train = [frames.index(g) for g in clip.train_frames]
    # the test frames between two consecutive training frames (the benchmark's alternate frames)
    mid = [frames.index(a + 1) if (a + 1) in frames else None for a in clip.train_frames[:-1]]
    dyn = np.asarray(tracks.dynamic, bool) if tracks.dynamic is not None else np.zeros(0, bool)
    vis = tracks.visible[:, train]
    keep = dyn & (vis.mean(1) >= MIN_VISIBLE) if dyn.size else dyn
    rep: Dict = {
        "clip": Path(clip_dir).name,
        "train_frames": len(train),
        "moving_tracks": int(dyn.sum()),
        "fitted_tracks": int(keep.sum()),
        "every": {},
    }
    if not keep.any():
        return rep
    xy = tracks.tracks[keep][:, train].astype(np.float64)
    v = vis[keep]
    if any(m is None for m in mid):
        raise SystemExit(f"{clip_dir}: gt/tracks.npz lacks a frame between two training frames")
    txy = tracks.tracks[keep][:, mid].astype(np.float64)
    tv = tracks.visible[keep][:, mid]
    step = np.linalg.norm(np.diff(xy, axis=1), axis=-1)
    step = np.where(v[:, 1:] & v[:, :-1], step, np.nan)
    rep["speed_px_per_train_frame"] = float(np.nanmedian(np.nanmedian(step, axis=1)))
    for n_s in every:
        fit, between = track_residuals(xy, v, txy, tv, n_s)
        b = between[np.isfinite(between)]
        rep["every"][str(n_s)] = {
            "fit_median_px": float(np.median(fit)),
            "fit_p90_px": float(np.percentile(fit, 90)),
            "between_median_px": float(np.median(b)) if b.size else None,
            "between_p90_px": float(np.percentile(b, 90)) if b.size else None,
        }
    return rep


def _fmt(x: Optional[float]) -> str:
    return "-" if x is None else f"{x:.2f}"


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("clips", nargs="+", type=Path, help="evaluation clips (with gt/tracks.npz)")
    ap.add_argument(
        "--every", type=int, nargs="+", default=[1, 2, 4, 8], help="control-point intervals N_s"
    )
    ap.add_argument("--json", type=Path, help="also write the reports here (a JSON list)")
    a = ap.parse_args(argv)
    reports = []
    for c in a.clips:
        rep = reach_report(c, a.every)
        reports.append(rep)
        head = (
            f"{rep['clip']}: {rep['fitted_tracks']} of {rep['moving_tracks']} moving tracks fitted"
        )
        if not rep["every"]:
            print(head + " (none visible at half the training frames)")
            continue
        print(head + f", median speed {rep['speed_px_per_train_frame']:.2f} px a training frame")
        for n_s, r in rep["every"].items():
            fit = f"fit {_fmt(r['fit_median_px'])} px (p90 {_fmt(r['fit_p90_px'])})"
            test = (
                f"test frames {_fmt(r['between_median_px'])} px (p90 {_fmt(r['between_p90_px'])})"
            )
            print(f"  N_s = {n_s:>2}: {fit}, {test}")
    if a.json:
        a.json.write_text(json.dumps(reports, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
