"""Score one run against its clip: `score_run(run_dir) -> dict`, written to <run>/metrics.json
(docs/eval.md).

What is scored (keys of metrics.json; None where a metric cannot be computed: no ground truth, no
LPIPS weights, no model, no file):

- LDR test frames at every OBSERVED level (ldr_oe_*) and every NOVEL level (ldr_ne_*): psnr, ssim,
  lpips; the mean over frames then over levels (equal frame counts, so the mean over all images);
  `per_level` has each level. Real footage with held-out test frames (exposures.test_dt): each test
  frame at its own level only, the levels weighted by their frame counts (the mean over images).
- LDR training frames against the input video (ldr_train_*; the paper's GFlow comparison).
- HDR test frames: hdr_psnr / hdr_ssim / hdr_lpips (mu-law, GT-max), hdr_psnr_ownmax (labelled
  extra), pu21_psnr, hdr_flip (only with flip=True: slow); HDR training frames: hdr_train_psnr /
  hdr_train_ssim.
- The test frames' HDR over the whole scene (eval.experiments.score_scene, eval.metrics.scene_hdr):
  hdr_psnr_p99 (mu-law on H / p99 of the truth's luminance), highlight_stops and
  highlight_peak_ratio over the pixels the longest observed exposure saturates and the shortest
  measures (through the clip's true response; highlight_pixels counts them).
- Held-out views (clips with gt/views/, eval.experiments.view_scores on renders/views):
  nv_<view>_<split>_<metric> (split ldr_oe, ldr_ne, hdr; metric psnr, mpsnr, ssim, mssim; mpsnr /
  mssim over the co-visible pixels), nv_<view>_hdr_psnr_p99, nv_<view>_covisible, and the means over
  views nv_<split>_<metric>, nv_hdr_psnr_p99, nv_covisible; None without views or their renders.
- The clip's camera motion (clip.json gt.camera_motion): camera_deg_s, scene_deg_s, emf.
- HDR-TAE on the rendered TRAINING frames with the exact ground-truth flow and visibility between
  consecutive training frames (gt/flow.npz; a clip made from an HDR video: the flow given with it,
  else DIS flow on its ground-truth HDR frames); without ground truth (real clips) DIS flow on the
  tone-mapped renders. hdr_tae_interior (the same without occlusion-edge pixels, gt depth); hdr_tce
  (the renders' change between consecutive training frames against the ground truth's, same flow and
  visibility: 0 for a perfect prediction, the clip's HDR-TAE floor for one frozen in time; gt HDR
  needed); hdr_tae_train_test (all frames, DIS flow; optional), hdr_t_std.
- Cameras (cameras.json and cameras_ba.json vs gt/cameras.json, Sim(3) over all common frames): ate,
  rpe_trans, rpe_rot, ate_ba, rpe_trans_ba, rpe_rot_ba.
- depth_absrel: rendered test depth vs gt depth, ONE median scale over all test frames (the
  reconstruction has one global scale).
- track_epe / track_epe_median / track_delta_avg: model.track_2d from the first frame vs gt tracks
  (<= 256 gt tracks visible at the first frame, seeded sample).
- dyn_ldr_psnr (observed levels) / dyn_hdr_psnr (mu-law): PSNR over the gt dynamic-mask pixels of
  the test frames.
- mask_precision / mask_recall / mask_iou: the run's dynamic masks (model/camera_init.pt "masks",
  one per training frame; epipolar, or their union with the rigidity masks of m4dgs.priors.rigidity)
  against the gt dynamic masks, pooled over all training-frame pixels. Low recall means moving
  objects that the video-to-world transform will treat as static (e.g. motion along the epipolar
  lines).
- crf_rmse and crf_curve: the learned tone curve (model.tonemap_curve) vs the clip's true CRF over
  log2 x in
  [-10, 10]; crf_error (eval.metrics.crf): mean |learned - true| in 8-bit codes over the exposure
  range the training
  frames recorded unclipped, per channel, then the mean over RGB (None without a model or a true
  CRF).
- train_seconds / train_minutes, num_gaussians, peak_memory_mib (run.json); fps at the clip
  resolution and fps_864x480 (model.render timed with eval.metrics.measure_fps).
- conventions (key -> sentence of every convention used) and options (roundtrip, LPIPS weights,
  ...).

PSNR of identical images is +inf; every PSNR is capped at PSNR_CAP_DB = 100 dB per image before
averaging (so a perfect render reads 100.00 and JSON stays standard). NaN is stored as None.

LDR renders are read from the 8-bit PNG files written by m4dgs.outputs.render, so LDR is scored on
8-bit renders (the PNG round-trip convention; `roundtrip="jpeg"` adds a JPEG round trip to compare
with the authors' numbers).

score_run and the steps of the paper's metrics share the per-run state (_Job) and the metric-group
helpers here; the whole-scene steps (scene HDR, held-out views, camera motion) are
eval.experiments.score_scene, which reads the job through the same attributes. The run folder as it
is read (run.json, the clip, the render files) is eval.experiments.run_files; the conventions
printed under the tables are eval.conventions; the model-based metrics are
eval.experiments.score_model. At about 840 lines this module stays one: what is left here is one
computation (score_run and the paper's metric groups over one _Job), and splitting it further would
spread that computation over files."""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Iterable, List, Optional, Tuple

import numpy as np

from eval.conventions import (
    PSNR_CAP_DB,
    all_conventions,
)
from eval.experiments.run_files import (
    ensure_renders,
    has_test_renders,
    has_view_renders,
    read_render_exr,
    read_run_info,
    resolve_clip_dir,
)
from eval.experiments.score_model import score_model, to_numpy
from eval.experiments.score_scene import (
    CAMERA_MOTION_KEYS,
    NV_MEAN_KEYS,
    SCENE_HDR_KEYS,
    camera_motion,
    score_held_out_views,
    score_scene_hdr,
)
from eval.metrics import (
    ate,
    depth_absrel,
    dis_flow,
    hdr_flip,
    hdr_ssim,
    hdr_t_std,
    hdr_tae_pairs,
    hdr_tonemap_pair,
    load_lpips_weights,
    lpips_metric,
    masked_psnr,
    psnr_per_image,
    pu21_psnr,
    rpe,
    ssim,
)
from eval.metrics import roundtrip as ldr_roundtrip
from eval.metrics.temporal import depth_edges, hdr_tce_pairs, interior_visibility
from m4dgs.clip import Cameras, Clip, frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.core.device import resolve_device
from m4dgs.core.errors import InputError
from m4dgs.run import load_torch

CHUNK = 8  # frames per batch when scoring (bounds memory at 864x480)
FPS_SIZE = (864, 480)


# --------------------------------------------------------------------------------------------------
# small helpers
# --------------------------------------------------------------------------------------------------
def _clean(v):
    """JSON-safe number: NaN -> None, +-inf -> +-PSNR_CAP_DB (only PSNRs can be infinite)."""
    if v is None:
        return None
    v = float(v)
    if math.isnan(v):
        return None
    if math.isinf(v):
        return PSNR_CAP_DB if v > 0 else -PSNR_CAP_DB
    return v


def _capped_mean(vals: Iterable[float]) -> Optional[float]:
    vals = [min(float(v), PSNR_CAP_DB) for v in vals if v is not None and not math.isnan(float(v))]
    return float(np.mean(vals)) if vals else None


def _mean(vals: Iterable[Optional[float]]) -> Optional[float]:
    vals = [v for v in vals if v is not None and not math.isnan(v)]
    return float(np.mean(vals)) if vals else None


def _weighted(pairs: List[tuple]) -> Optional[float]:
    """Mean of chunk means weighted by chunk sizes; None if any chunk gave None."""
    if not pairs or any(v is None for v, _ in pairs):
        return None
    n = sum(w for _, w in pairs)
    return float(sum(v * w for v, w in pairs) / n)


def _chunks(seq: List, n: int = CHUNK):
    for i in range(0, len(seq), n):
        yield seq[i : i + n]


def _ldr_pred(path: Path, rt):
    return ldr_roundtrip(mio.read_png(path), rt)


# --------------------------------------------------------------------------------------------------
# metric groups
# --------------------------------------------------------------------------------------------------
def _score_ldr_set(preds: List[Path], gts: List, rt, lpips_w) -> dict:
    """PSNR (capped per image) / SSIM / LPIPS of rendered PNGs vs gt images (paths or arrays),
    chunked."""
    ps, ss, ls = [], [], []
    for idx in _chunks(list(range(len(preds)))):
        p = np.stack([mio.read_png(preds[i]) for i in idx])
        g = np.stack([gts[i]() if callable(gts[i]) else gts[i] for i in idx])
        ps += psnr_per_image(p, g, roundtrip_mode=rt)
        ss.append((ssim(p, g, roundtrip=rt), len(idx)))
        if lpips_w is not None:
            ls.append((lpips_metric(ldr_roundtrip(p, rt), g, lpips_w), len(idx)))
    return {
        "psnr": _capped_mean(ps),
        "ssim": _weighted(ss),
        "lpips": _weighted(ls) if lpips_w is not None else None,
        "frames": len(preds),
    }


def _score_hdr_set(
    preds: List[Path], gt_fn, frames: List[int], lpips_w, flip: bool, full: bool
) -> dict:
    """mu-law PSNR/SSIM/LPIPS (GT-max), own-max PSNR, PU21, FLIP over HDR frames, chunked."""
    ps, po, ss, ls, pu, fl = [], [], [], [], [], []
    for idx in _chunks(list(range(len(preds)))):
        p = np.stack([read_render_exr(preds[i]) for i in idx])
        g = np.stack([gt_fn(frames[i]) for i in idx])
        tp, tg = hdr_tonemap_pair(p, g, norm="gt")
        ps += psnr_per_image(tp, tg)
        ss.append((hdr_ssim(p, g), len(idx)))
        if full:
            op, og = hdr_tonemap_pair(p, g, norm="own")
            po += psnr_per_image(op, og)
            pu.append((min(pu21_psnr(p, g), PSNR_CAP_DB), len(idx)))
            if lpips_w is not None:
                ls.append((lpips_metric(tp, tg, lpips_w), len(idx)))
            if flip:
                fl.append((hdr_flip(p, g), len(idx)))
    out = {"psnr": _capped_mean(ps), "ssim": _weighted(ss)}
    if full:
        out.update(
            psnr_ownmax=_capped_mean(po),
            pu21_psnr=_weighted(pu),
            lpips=_weighted(ls) if lpips_w is not None else None,
            flip=_weighted(fl) if flip else None,
        )
    return out


def _pairwise(frames: List[int], load, flow_fn, pair_value) -> Optional[float]:
    """Mean over consecutive frame pairs of pair_value(xa, xb, ff, fb, vf, vb) (NaN skipped), one
    pair in memory at a time: load(g) -> a tuple of frames of g whose first is the rendered HDR,
    flow_fn(a, b, Ha, Hb) -> (ff, fb, vf, vb) for the pair (vf / vb may be None), each given to
    pair_value with a leading pair axis of 1."""
    vals, prev = [], None
    for a, b in zip(frames[:-1], frames[1:]):
        xa = prev if prev is not None else load(a)
        xb = load(b)
        ff, fb, vf, vb = flow_fn(a, b, xa[0], xb[0])
        v = pair_value(
            xa,
            xb,
            ff[None],
            fb[None],
            None if vf is None else vf[None],
            None if vb is None else vb[None],
        )
        if not math.isnan(v):
            vals.append(v)
        prev = xb
    return float(np.mean(vals)) if vals else None


def _tae_pairwise(frames: List[int], load, flow_fn) -> Optional[float]:
    """HDR-TAE over consecutive frames (load(g) -> the rendered HDR of g)."""
    return _pairwise(
        frames,
        lambda g: (load(g),),
        flow_fn,
        lambda xa, xb, *f: hdr_tae_pairs(np.stack([xa[0], xb[0]]), *f)[0],
    )


def _tce_pairwise(frames: List[int], load, load_gt, flow_fn) -> Optional[float]:
    """HDR-TCE over consecutive frames, the renders (load) against the ground truth (load_gt)."""
    return _pairwise(
        frames,
        lambda g: (load(g), load_gt(g)),
        flow_fn,
        lambda xa, xb, *f: hdr_tce_pairs(np.stack([xa[0], xb[0]]), np.stack([xa[1], xb[1]]), *f)[0],
    )


def _dis_flows(a, b, ha, hb):
    return dis_flow(ha, hb), dis_flow(hb, ha), None, None


def _cameras(run_dir: Path, clip: Clip, name: str) -> Dict[str, Optional[float]]:
    p = run_dir / name
    if not p.exists() or not clip.has_gt or not (clip.root / "gt/cameras.json").exists():
        return {"ate": None, "rpe_trans": None, "rpe_rot": None}
    est = Cameras.from_json(mio.read_json(p), p)
    gt = clip.load_gt_cameras()
    common = [int(g) for g in est.frames if int(g) in set(gt.frames.tolist())]
    if len(common) < 3:
        return {"ate": None, "rpe_trans": None, "rpe_rot": None}
    ie = [est.frames.tolist().index(g) for g in common]
    ig = [gt.frames.tolist().index(g) for g in common]
    ce, cg = est.c2w[ie], gt.c2w[ig]
    r = rpe(ce, cg)
    return {"ate": ate(ce, cg), "rpe_trans": r["rpe_trans"], "rpe_rot": r["rpe_rot"]}


def mask_metrics(run_dir: Path, clip: Clip) -> Optional[Dict[str, Optional[float]]]:
    """Precision / recall / IoU of the run's dynamic masks (model/camera_init.pt "masks" [T, H, W],
    training-frame order) against the gt dynamic masks, pooled over all pixels of all training
    frames; None without either."""
    p = run_dir / "model" / "camera_init.pt"
    if not p.exists() or not clip.has_gt or not (clip.root / "gt/masks/dynamic").is_dir():
        return None
    est = load_torch(p, map_location="cpu").get("masks")
    if est is None:
        return None
    est = to_numpy(est) > 0.5
    train = clip.train_frames
    if est.shape[0] != len(train):
        raise ValueError(
            f"{p}: 'masks' has {est.shape[0]} frames, the clip has {len(train)} training frames"
        )
    gt = np.stack([clip.load_gt_dynamic_mask(g) for g in train])
    if gt.shape != est.shape:
        raise ValueError(f"{p}: 'masks' is {est.shape[1:]}, the clip's gt masks are {gt.shape[1:]}")
    return mask_scores(est, gt)


def mask_scores(est: np.ndarray, gt: np.ndarray) -> Dict[str, Optional[float]]:
    """Precision / recall / IoU of boolean masks `est` against `gt` (same shape), pixel counts
    pooled over the whole array; None where a count it divides by is 0."""
    tp = float(np.logical_and(est, gt).sum())
    n_est, n_gt, union = float(est.sum()), float(gt.sum()), float(np.logical_or(est, gt).sum())
    return {
        "mask_precision": tp / n_est if n_est else None,
        "mask_recall": tp / n_gt if n_gt else None,
        "mask_iou": tp / union if union else None,
    }


# --------------------------------------------------------------------------------------------------
# the entry point
# --------------------------------------------------------------------------------------------------
METRIC_KEYS = [
    "ldr_oe_psnr",
    "ldr_oe_ssim",
    "ldr_oe_lpips",
    "ldr_ne_psnr",
    "ldr_ne_ssim",
    "ldr_ne_lpips",
    "ldr_train_psnr",
    "ldr_train_ssim",
    "ldr_train_lpips",
    "hdr_psnr",
    "hdr_ssim",
    "hdr_lpips",
    "hdr_psnr_ownmax",
    "pu21_psnr",
    "hdr_flip",
    "hdr_train_psnr",
    "hdr_train_ssim",
    "hdr_tae",
    "hdr_tae_interior",
    "hdr_tce",
    "hdr_tae_train_test",
    "hdr_t_std",
    "ate",
    "rpe_trans",
    "rpe_rot",
    "ate_ba",
    "rpe_trans_ba",
    "rpe_rot_ba",
    "depth_absrel",
    "track_epe",
    "track_epe_median",
    "track_delta_avg",
    "dyn_ldr_psnr",
    "dyn_hdr_psnr",
    "mask_precision",
    "mask_recall",
    "mask_iou",
    "crf_rmse",
    "crf_error",
    "train_seconds",
    "train_minutes",
    "fps",
    "fps_864x480",
    "num_gaussians",
    "peak_memory_mib",
    *SCENE_HDR_KEYS,
    *NV_MEAN_KEYS,
    *CAMERA_MOTION_KEYS,
]


def score_run(
    run_dir,
    clip=None,
    lpips_weights=None,
    roundtrip=None,
    flip: bool = False,
    fps: bool = True,
    *,
    tae_train_test: bool = False,
    device: str = "auto",
    model: bool = True,
    write: bool = True,
    progress: bool = False,
    render_missing: bool = True,
) -> dict:
    """Score a run folder against its clip and write <run>/metrics.json (atomic). Returns the
    metrics dict.

    Args:
        run_dir: the run folder (layout in m4dgs/run.py; docs/eval.md "eval score RUN"). clip: clip
            folder (default: run.json "clip").
        lpips_weights: path of the LPIPS weights file (eval.metrics.lpips); None -> every *_lpips is
            None.
        roundtrip: None | "png" | "jpeg": 8-bit round trip of the LDR predictions (renders are PNG
            already).
        flip: also compute HDR-FLIP (slow: ~1 s per 864x480 frame).
        fps: time model.render at the clip resolution and at 864x480.
        tae_train_test: also HDR-TAE over all frames (train + test, DIS flow on the renders).
        device: "auto" | "cpu" | "cuda" for loading the model (tracks, CRF, FPS).
        model: load the trained model at all (tracks, CRF curve, FPS); False skips those metrics.
        write: write metrics.json.
        render_missing: render what renders/ lacks from the run's model (m4dgs runs; the held-out
            views too). False (frames of another method, eval.experiments.frames): score what is
            there; the training-frame metrics (ldr_train_*, hdr_train_*, hdr_tae, hdr_t_std) are
            None without training renders, the nv_* keys None without renders/views, and a folder
            with view renders but no test-frame render at all (a views-only prediction) has every
            test-frame metric None.

    The steps, in order (each adds metrics and the keys of the conventions it used): LDR test frames
    per level, LDR training frames, HDR, temporal, cameras and dynamic masks, depth and dynamic
    regions, run.json, model-based metrics (eval.experiments.score_model); the scene-HDR, view and
    camera-motion steps (eval.experiments.score_scene) come after HDR. Then the metrics are cleaned
    (NaN -> None, PSNR cap) and the conventions, options and run description are attached.
    """
    t0 = time.perf_counter()
    run_dir = Path(run_dir)
    if roundtrip in ("none", ""):
        roundtrip = None
    if roundtrip not in (None, "png", "jpeg"):
        raise ValueError(f"roundtrip must be None, 'png' or 'jpeg', got {roundtrip!r}")
    if write and run_dir.is_dir() and not os.access(run_dir, os.W_OK):
        # found now, not after minutes of metrics
        raise InputError(f"{run_dir}: the run folder is read-only; metrics.json cannot be written")
    clip_obj = clip if isinstance(clip, Clip) else Clip.open(resolve_clip_dir(run_dir, clip))
    dev = str(resolve_device(device))
    rendered = (
        ensure_renders(run_dir, clip_obj, progress=progress, device=dev)
        if render_missing
        else False
    )
    job = _Job(
        run_dir,
        clip_obj,
        roundtrip,
        None if lpips_weights is None else load_lpips_weights(lpips_weights),
    )
    conv_keys = [
        "psnr",
        "psnr_cap",
        "ssim",
        "ldr_jpeg" if roundtrip == "jpeg" else "ldr_png",
        "lpips" if job.lpips_w is not None else "lpips_na",
    ]
    m: Dict[str, object] = {k: None for k in METRIC_KEYS}
    # a views-only prediction (another method's frames): no test-frame metric
    job.test_renders = (
        render_missing or has_test_renders(run_dir, clip_obj) or not has_view_renders(run_dir)
    )
    per_level = _score_ldr_levels(job, m)
    _score_ldr_train(job, m)
    conv_keys += _score_hdr(job, m, flip)
    conv_keys += score_scene_hdr(job, m)
    conv_keys += score_held_out_views(job, m) or []
    conv_keys += camera_motion(job, m)
    conv_keys += _score_temporal(job, m, tae_train_test)
    conv_keys += _score_cameras_and_masks(job, m)
    conv_keys += _score_depth_and_dynamic(job, m)
    info = read_run_info(run_dir)
    conv_keys += _run_info_metrics(info, m)
    model_note = "not loaded (model=False)"
    if model:
        model_note, keys = score_model(job, m, fps, dev)
        conv_keys += keys
    _finish(m, per_level, conv_keys, roundtrip)
    m["options"] = {
        "roundtrip": roundtrip,
        "lpips_weights": None if lpips_weights is None else str(Path(lpips_weights).resolve()),
        "flip": bool(flip),
        "fps": bool(fps),
        "tae_train_test": bool(tae_train_test),
        "model": model_note,
        "rendered_missing": rendered,
        "psnr_cap_db": PSNR_CAP_DB,
    }
    m["run"] = {
        "variant": info.get("variant"),
        "preset": info.get("preset"),
        "clip": str(clip_obj.root),
        "clip_name": clip_obj.meta.name,
        "has_gt": clip_obj.has_gt,
    }
    m["score_seconds"] = round(time.perf_counter() - t0, 3)
    if write:
        mio.write_json(run_dir / "metrics.json", m)
    return m


# --------------------------------------------------------------------------------------------------
# the steps of score_run (each fills its keys of the metrics dict `m` and returns the convention
# keys it used)
# --------------------------------------------------------------------------------------------------
@dataclass
class _Job:
    """What every step of score_run reads: the run, its clip, the LDR round trip, LPIPS weights."""

    run_dir: Path
    clip: Clip
    roundtrip: Optional[str]
    lpips_w: Optional[object]
    test_renders: bool = True  # False: a views-only prediction, no test-frame metric

    @property
    def renders(self) -> Path:
        return self.run_dir / "renders"

    def render(self, sub: str, g: int, ext: str) -> Path:
        """renders/<sub>/<g>.<ext> (sub e.g. "train/hdr", "test/ldr/<level>")."""
        return self.renders / sub / frame_name(g, ext)

    def has_all(self, sub: str, frames: List[int], ext: str) -> bool:
        return all(self.render(sub, g, ext).exists() for g in frames)

    @property
    def test_hdr(self) -> bool:
        """Whether the test frames' HDR is scored: test renders, and an HDR render of each (another
        method's LDR-only frames, e.g. a Nerfies-style method's, have none; an m4dgs run has them
        all, ensure_renders sees to it)."""
        return self.test_renders and self.has_all("test/hdr", self.clip.test_frames, "exr")

    def load_train_hdr(self, g: int) -> np.ndarray:
        return read_render_exr(self.render("train/hdr", g, "exr"))


def _score_ldr_levels(job: _Job, m: dict) -> dict:
    """LDR test frames at every observed and novel level: ldr_oe_* / ldr_ne_* (mean over levels);
    returns the per-level results."""
    clip, test = job.clip, job.clip.test_frames
    ex = clip.meta.exposures
    per_level = {}
    if not (clip.has_gt and test and job.test_renders):
        return per_level
    for kind, levels in (("observed", ex.observed), ("novel", ex.novel)):
        for lv in levels:
            # a real clip's test frame has ground truth at its own exposure only
            frames = [g for g in test if lv in clip.meta.test_levels_of(g)]
            if not frames:
                continue
            preds = [job.render(f"test/ldr/{level_name(lv)}", g, "png") for g in frames]
            gts = [(lambda g=g, lv=lv: clip.load_gt_ldr(lv, g)) for g in frames]
            res = _score_ldr_set(preds, gts, job.roundtrip, job.lpips_w)
            res["kind"] = kind
            per_level[level_name(lv)] = res
    # the mean over levels; with a test frame per captured exposure (real clips) the levels hold
    # different frame counts, so the mean over images (levels weighted by their counts)
    weighted = ex.test_dt is not None
    for pre, kind in (("ldr_oe", "observed"), ("ldr_ne", "novel")):
        lv = [v for v in per_level.values() if v["kind"] == kind]
        if lv:
            for k in ("psnr", "ssim", "lpips"):
                if k == "lpips" and job.lpips_w is None:
                    m[f"{pre}_lpips"] = None
                elif weighted:
                    m[f"{pre}_{k}"] = _weighted([(v[k], v["frames"]) for v in lv])
                else:
                    m[f"{pre}_{k}"] = _mean(v[k] for v in lv)
    return per_level


def _score_ldr_train(job: _Job, m: dict) -> None:
    """LDR training frames against the input video (ldr_train_*; None without those renders)."""
    train = job.clip.train_frames
    if not job.has_all("train/ldr", train, "png"):
        return
    tr = _score_ldr_set(
        [job.render("train/ldr", g, "png") for g in train],
        [(lambda g=g: job.clip.load_ldr(g)) for g in train],
        job.roundtrip,
        job.lpips_w,
    )
    m["ldr_train_psnr"], m["ldr_train_ssim"], m["ldr_train_lpips"] = (
        tr["psnr"],
        tr["ssim"],
        tr["lpips"],
    )


def _score_hdr(job: _Job, m: dict, flip: bool) -> List[str]:
    """HDR test frames (mu-law PSNR/SSIM/LPIPS, own-max PSNR, PU21, FLIP) and training frames."""
    clip = job.clip
    if not (clip.has_gt and clip.has_gt_part("hdr")):
        return []
    keys = ["hdr_mu_law", "hdr_mu_law_own", "pu21"]
    test, train = clip.test_frames, clip.train_frames
    if test and job.test_hdr:
        h = _score_hdr_set(
            [job.render("test/hdr", g, "exr") for g in test],
            clip.load_gt_hdr,
            test,
            job.lpips_w,
            flip,
            full=True,
        )
        m.update(
            hdr_psnr=h["psnr"],
            hdr_ssim=h["ssim"],
            hdr_lpips=h["lpips"],
            hdr_psnr_ownmax=h["psnr_ownmax"],
            pu21_psnr=h["pu21_psnr"],
            hdr_flip=h["flip"],
        )
        if flip:
            keys.append("hdr_flip")
    if not job.has_all("train/hdr", train, "exr"):
        return keys
    h = _score_hdr_set(
        [job.render("train/hdr", g, "exr") for g in train],
        clip.load_gt_hdr,
        train,
        None,
        False,
        full=False,
    )
    m["hdr_train_psnr"], m["hdr_train_ssim"] = h["psnr"], h["ssim"]
    return keys


def _gt_flows(clip: Clip):
    """(flow_fn, convention key) for HDR-TAE and TCE, flow_fn(a, b, Ha, Hb) -> (F_ab, F_ba, V_ab,
    V_ba) the same for every method: the clip's gt/flow.npz (exact for a benchgen render; given with
    the clip for one made from an HDR video), else, when the clip has ground-truth HDR, OpenCV DIS
    on it (visibility from forward-backward consistency); None without ground truth."""
    if not clip.has_gt:
        return None
    if clip.has_gt_part("flow.npz"):
        fs = clip.load_gt_flow()

        def flows(a, b, ha, hb):
            fab, vab = fs.get(a, b)
            fba, vba = fs.get(b, a)
            return fab, fba, vab, vba

        given = (clip.meta.generator or {}).get("tool") == "benchgen from-hdr"
        return flows, "hdr_tae_given_flow" if given else "hdr_tae_gt_flow"
    if not all(clip.has_gt_part(f"hdr/{frame_name(g, 'exr')}") for g in clip.train_frames):
        return None

    def gt_dis(a, b, ha, hb):
        return _dis_flows(a, b, clip.load_gt_hdr(a), clip.load_gt_hdr(b))

    return gt_dis, "hdr_tae_gt_dis_flow"


def _score_tce(job: _Job, m: dict, flows=None) -> List[str]:
    """hdr_tce of the training renders against the ground truth (exact flow and gt HDR needed)."""
    clip, train = job.clip, job.clip.train_frames
    if flows is None:
        flows = (_gt_flows(clip) or (None, None))[0]
    if flows is None or not job.has_all("train/hdr", train, "exr"):
        return []
    if not all((clip.root / "gt/hdr" / frame_name(g, "exr")).exists() for g in train):
        return []
    m["hdr_tce"] = _tce_pairwise(train, job.load_train_hdr, clip.load_gt_hdr, flows)
    return ["hdr_tce"]


# metrics a metrics.json of an earlier version may lack, each with the step that computes it alone
# (`add_missing_metrics`; a step computing several keys runs once)
ADDABLE = {
    "hdr_tce": _score_tce,
    **{k: score_scene_hdr for k in SCENE_HDR_KEYS},
    **{k: score_held_out_views for k in NV_MEAN_KEYS},
    **{k: camera_motion for k in CAMERA_MOTION_KEYS},
}


def add_missing_metrics(
    run_dir, clip=None, write: bool = True, render_missing: bool = False
) -> Tuple[dict, List[str]]:
    """Compute the metrics of ADDABLE that RUN/metrics.json lacks (scored before they existed)
    without recomputing anything else, and merge them in (with their conventions). Returns (the
    metrics, the keys added; a key whose step finds no input is added as None, except the held-out
    views' keys of a clip with views when the run has no renders/views: left out, to be added once
    rendered). render_missing: first render the missing view renders from the run's model (an m4dgs
    run; eval.experiments.run_files.ensure_renders)."""
    run_dir = Path(run_dir)
    mpath = run_dir / "metrics.json"
    if not mpath.exists():
        raise InputError(f"{mpath}: no metrics.json to add to; score the run first")
    m = mio.read_json(mpath)
    todo = [k for k in ADDABLE if k not in m]
    if not todo:
        return m, []
    clip_obj = clip if isinstance(clip, Clip) else Clip.open(resolve_clip_dir(run_dir, clip))
    if render_missing and any(ADDABLE[k] is score_held_out_views for k in todo):
        ensure_renders(run_dir, clip_obj)
    job = _Job(run_dir, clip_obj, None, None)
    job.test_renders = has_test_renders(run_dir, clip_obj)
    conv = all_conventions()
    before = set(m)
    added: List[str] = []
    for step in dict.fromkeys(ADDABLE[k] for k in todo):
        had = set(m)
        for k in todo:
            if ADDABLE[k] is step:
                m[k] = None
        used = step(job, m)
        if used is None:  # no input yet: leave its keys out
            for k in set(m) - had:
                del m[k]
            continue
        for c in used:
            m.setdefault("conventions", {})[c] = conv[c]
    for k in m:
        if k not in before:
            m[k] = _clean(m[k]) if isinstance(m[k], float) else m[k]
            added.append(k)
    if write and added:
        mio.write_json(mpath, m)
    return m, added


def _score_temporal(job: _Job, m: dict, tae_train_test: bool) -> List[str]:
    """HDR-TAE of the training renders (gt flow and visibility, or DIS flow without them), its
    interior variant (gt depth), optionally over all frames, and HDR_T_std."""
    clip, train, test = job.clip, job.clip.train_frames, job.clip.test_frames
    keys: List[str] = []
    if not job.has_all("train/hdr", train, "exr"):
        return keys
    gt = _gt_flows(clip)
    if gt is not None:
        flows, flow_key = gt
        m["hdr_tae"] = _tae_pairwise(train, job.load_train_hdr, flows)
        keys += ["hdr_tae", "hdr_tae_train", flow_key]
        keys += _score_tce(job, m, flows)
        if all((clip.root / "gt/depth" / frame_name(g, "exr")).exists() for g in train):
            # the same pairs without occlusion-edge pixels (gt depth)
            def interior_flows(a, b, ha, hb):
                fab, fba, vab, vba = flows(a, b, ha, hb)
                ea, eb = depth_edges(clip.load_gt_depth(a)), depth_edges(clip.load_gt_depth(b))
                return (
                    fab,
                    fba,
                    interior_visibility(vab, fab, ea, eb),
                    interior_visibility(vba, fba, eb, ea),
                )

            m["hdr_tae_interior"] = _tae_pairwise(train, job.load_train_hdr, interior_flows)
            keys.append("hdr_tae_interior")
    else:
        m["hdr_tae"] = _tae_pairwise(train, job.load_train_hdr, _dis_flows)
        keys += ["hdr_tae", "hdr_tae_train", "hdr_tae_dis_flow"]
    if tae_train_test and job.test_renders:

        def load_any(g):
            sub = "train" if g in set(train) else "test"
            return read_render_exr(job.render(f"{sub}/hdr", g, "exr"))

        allf = sorted(set(train) | set(test))
        m["hdr_tae_train_test"] = _tae_pairwise(allf, load_any, _dis_flows)
        keys.append("hdr_tae_dis_flow")
    means = np.array([float(job.load_train_hdr(g).mean()) for g in train])
    m["hdr_t_std"] = hdr_t_std(means.reshape(-1, 1, 1, 1))
    keys.append("hdr_t_std")
    return keys


def _score_cameras_and_masks(job: _Job, m: dict) -> List[str]:
    """ATE / RPE of the refined (cameras.json) and bundle-adjusted (cameras_ba.json) cameras, and
    the run's dynamic masks against the gt ones."""
    keys: List[str] = []
    m.update(_cameras(job.run_dir, job.clip, "cameras.json"))
    cba = _cameras(job.run_dir, job.clip, "cameras_ba.json")
    m.update(ate_ba=cba["ate"], rpe_trans_ba=cba["rpe_trans"], rpe_rot_ba=cba["rpe_rot"])
    if m["ate"] is not None or m["ate_ba"] is not None:
        keys += ["ate", "rpe", "cameras_all_frames"]
    mk = mask_metrics(job.run_dir, job.clip)
    if mk is not None:
        m.update(mk)
        keys.append("dyn_masks")
    return keys


def _score_depth_and_dynamic(job: _Job, m: dict) -> List[str]:
    """depth_absrel of the test depth renders, and PSNR over the gt dynamic-mask pixels of the test
    frames (dyn_ldr_psnr at the observed levels, dyn_hdr_psnr mu-law)."""
    clip, test = job.clip, job.clip.test_frames
    keys: List[str] = []
    if not (clip.has_gt and test and job.test_renders):
        return keys
    dpaths = [job.render("test/depth", g, "exr") for g in test]
    if clip.has_gt_part("depth") and all(p.exists() for p in dpaths):
        m["depth_absrel"] = depth_absrel(
            np.stack([read_render_exr(p) for p in dpaths]),
            np.stack([clip.load_gt_depth(g) for g in test]),
        )
        keys.append("depth_absrel_clip")
    if not (clip.root / "gt/masks/dynamic").is_dir():
        return keys
    masks = {g: clip.load_gt_dynamic_mask(g) for g in test}
    if not any(mk.any() for mk in masks.values()):
        return keys
    moving = [g for g in test if masks[g].any()]
    dl = []
    observed = set(clip.meta.exposures.observed)
    for g in moving:
        # the observed levels the frame is scored at (all of them, but for another method's
        # frames rendered at some levels only: eval.experiments.frames.scored_clip)
        for lv in [lv for lv in clip.meta.test_levels_of(g) if lv in observed]:
            p = _ldr_pred(job.render(f"test/ldr/{level_name(lv)}", g, "png"), job.roundtrip)
            dl.append(masked_psnr(p, clip.load_gt_ldr(lv, g), masks[g]))
    m["dyn_ldr_psnr"] = _capped_mean(dl)
    dh = []
    for g in moving if job.test_hdr else []:
        tp, tg = hdr_tonemap_pair(
            read_render_exr(job.render("test/hdr", g, "exr")), clip.load_gt_hdr(g)
        )
        dh.append(masked_psnr(tp, tg, masks[g]))
    m["dyn_hdr_psnr"] = _capped_mean(dh) if dh else None
    keys.append("masked")
    return keys


def _run_info_metrics(info: dict, m: dict) -> List[str]:
    """train_seconds / train_minutes, num_gaussians and peak_memory_mib from run.json."""
    if info.get("train_seconds") is not None:
        m["train_seconds"] = float(info["train_seconds"])
        m["train_minutes"] = float(info["train_seconds"]) / 60.0
    for k in ("num_gaussians", "peak_memory_mib"):
        if info.get(k) is not None:
            m[k] = float(info[k])
    return ["peak_mem"] if info.get("peak_memory_mib") is not None else []


def _finish(m: dict, per_level: dict, conv_keys: List[str], roundtrip: Optional[str]) -> None:
    """JSON-safe metric values, the per-level table, and the conventions used (first-use order)."""
    for k in METRIC_KEYS:
        m[k] = _clean(m[k])
    m["per_level"] = {
        k: {kk: (_clean(vv) if kk not in ("kind", "frames") else vv) for kk, vv in v.items()}
        for k, v in per_level.items()
    }
    allc = all_conventions()
    m["conventions"] = {k: allc[k] for k in dict.fromkeys(conv_keys)}
    m["ldr_convention"] = "ldr_jpeg" if roundtrip == "jpeg" else "ldr_png"
