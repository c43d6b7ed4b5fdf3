"""The whole-scene steps of score_run (eval.experiments.score), beside the paper's metrics:

- `score_scene_hdr`: the test frames' HDR over the whole scene and its highlights
  (eval.metrics.scene_hdr): hdr_psnr_p99 (capped at PSNR_CAP_DB per frame, mean over frames),
  highlight_stops, highlight_peak_ratio and highlight_peak_ratio_resolved (the peak over the
  highlight pixels the shortest exposure resolves), the highlights defined through the clip's TRUE
  response (clip.json `crf`) and its longest and shortest observed exposure (exposures.observed);
  None without ground-truth HDR, and the highlight scores None without a known response, with
  fewer than two observed exposures or without a highlight pixel in any test frame
  (highlight_pixels counts them).
- `score_held_out_views`: the clip's held-out views (benchgen clips, gt/views/<view>/) scored by
  eval.experiments.view_scores.score_views on RUN/renders/views (an m4dgs run's, written by
  m4dgs.outputs.views in the truth's frame after a similarity alignment of the training cameras;
  another method's, imported by score-frames): nv_<view>_<split>_<metric>, their means over views
  nv_<split>_<metric>, nv_<view>_covisible and nv_covisible. None without a prediction folder.
- `camera_motion`: the clip's camera-motion statistics (clip.json gt.camera_motion, benchgen.views)
  copied into the metrics, so that the runs CSV and the tables can set the view scores beside them.

Each step takes the scorer's job (run_dir, clip, render(sub, g, ext), test_renders) and the metrics
dict `m`, fills its keys and returns the convention keys it used (None from score_held_out_views
when the prediction folder is absent: add_missing_metrics then leaves the keys out, to be added
once the views are rendered)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import List, Optional

import numpy as np

from eval.conventions import PSNR_CAP_DB
from eval.experiments.run_files import read_render_exr
from eval.experiments.view_scores import DYN_KEYS, METRICS, SPLITS, score_views
from eval.metrics.scene_hdr import (
    hdr_psnr_p99,
    highlight_scores,
    peak_geomean,
    resolved_short_code,
)
from m4dgs.core.crf import get_crf

SCENE_HDR_KEYS = [
    "hdr_psnr_p99",
    "highlight_stops",
    "highlight_peak_ratio",
    "highlight_peak_ratio_resolved",
]
#: the per-view keys of eval.experiments.view_scores.score_view (nv_<view>_<key>, nv_<key>)
VIEW_KEYS = (
    [f"{s}_{m}" for s in SPLITS for m in METRICS]
    + ["hdr_psnr_p99"]
    + list(DYN_KEYS)
    + ["covisible"]
)
NV_MEAN_KEYS = [f"nv_{k}" for k in VIEW_KEYS]
#: clip.json gt.camera_motion keys copied into metrics.json
CAMERA_MOTION_KEYS = ["camera_deg_s", "scene_deg_s", "emf"]


def _finite(v) -> Optional[float]:
    return None if v is None or not math.isfinite(float(v)) else float(v)


def true_response(clip):
    """The clip's true camera response (m4dgs.core.crf), None for a real clip or one this
    installation does not know."""
    if not clip.meta.crf:
        return None
    try:
        return get_crf(clip.meta.crf)
    except KeyError:
        return None


def score_scene_hdr(job, m: dict) -> List[str]:
    """hdr_psnr_p99, highlight_stops, highlight_peak_ratio, highlight_peak_ratio_resolved (and
    highlight_pixels, highlight_pixels_resolved) of the test HDR renders
    renders/test/hdr/<g>.exr [H, W, 3] against gt/hdr (module docstring)."""
    clip, test = job.clip, job.clip.test_frames
    if not (clip.has_gt and clip.has_gt_part("hdr") and test and job.test_hdr):
        return []
    crf = true_response(clip)
    obs = list(clip.meta.exposures.observed)
    highlights = crf is not None and len(obs) >= 2
    fine = resolved_short_code(crf) if highlights else None
    p99, stops, ratios, fine_ratios, n, n_fine = [], [], [], [], 0, 0
    for g in test:  # one frame in memory at a time
        pred = read_render_exr(job.render("test/hdr", g, "exr"))
        gt = clip.load_gt_hdr(g)
        p99.append(min(hdr_psnr_p99(pred, gt), PSNR_CAP_DB))
        if highlights:
            h = highlight_scores(pred, gt, crf, max(obs), min(obs))
            if h["highlight_pixels"]:
                n += h["highlight_pixels"]
                stops.append(h["highlight_stops"])
                ratios.append(h["highlight_peak_ratio"])
                # the resolved pixels are a subset: only a frame with highlights can have them
                h = highlight_scores(pred, gt, crf, max(obs), min(obs), max_short_code=fine)
                if h["highlight_pixels"]:
                    n_fine += h["highlight_pixels"]
                    fine_ratios.append(h["highlight_peak_ratio"])
    m["hdr_psnr_p99"] = float(np.mean(p99))
    keys = ["hdr_psnr_p99"]
    if highlights:
        m["highlight_pixels"] = n
        m["highlight_pixels_resolved"] = n_fine
        # per frame, then the mean (stops) and the geometric mean (peak ratios) over frames
        if stops:
            m["highlight_stops"] = float(np.mean(stops))
            m["highlight_peak_ratio"] = peak_geomean(ratios)
        if fine_ratios:
            m["highlight_peak_ratio_resolved"] = peak_geomean(fine_ratios)
        keys += ["highlight_stops", "highlight_peak_ratio", "highlight_peak_ratio_resolved"]
    return keys


def view_keys(clip) -> List[str]:
    """Every nv_* key of the clip: the per-view keys of its views and the means over them."""
    return [f"nv_{v}_{k}" for v in clip.view_names() for k in VIEW_KEYS] + NV_MEAN_KEYS


def score_held_out_views(job, m: dict) -> Optional[List[str]]:
    """The nv_* keys of score_views on RUN/renders/views (module docstring): all None for a clip
    without views; None returned (keys left None) when the clip has views and the run has no
    renders/views folder."""
    clip = job.clip
    keys = view_keys(clip)
    for k in keys:
        m[k] = None
    if not clip.view_names():
        return []
    root = Path(job.run_dir) / "renders" / "views"
    if not root.is_dir():
        return None
    for k, v in score_views(clip, root).items():
        m[k] = _finite(v)
    return ["psnr_cap", "nv_views", "nv_masked", "nv_dynamic", "hdr_psnr_p99"]


def camera_motion(job, m: dict) -> List[str]:
    """camera_deg_s, scene_deg_s and emf of clip.json gt.camera_motion (None where absent)."""
    cm = (job.clip.meta.gt or {}).get("camera_motion") or {}
    for k in CAMERA_MOTION_KEYS:
        v = cm.get(k)
        m[k] = None if v is None else _finite(v)
    return ["camera_motion"] if any(m[k] is not None for k in CAMERA_MOTION_KEYS) else []
