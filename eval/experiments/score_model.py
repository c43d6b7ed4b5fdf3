"""The model-based step of score_run (eval.experiments.score): from the trained model
(m4dgs.model.trained.load_model), the track error against the gt tracks, the learned tone curve
against the clip's true CRF (crf_rmse, crf_error, crf_curve) and the render speed (fps,
fps_864x480). Split from the scorer because it is the one step that loads the model."""

from __future__ import annotations

from pathlib import Path
from typing import List, Tuple

import numpy as np
import torch

from eval.conventions import CRF_LOG2_RANGE, CRF_SAMPLES, TRACK_SAMPLES
from eval.metrics import crf_error, measure_fps, observed_exposure_range, track_error
from m4dgs.clip import Clip
from m4dgs.core.crf import get_crf

FPS_SIZE = (864, 480)


def to_numpy(x) -> np.ndarray:
    """A torch tensor or array as a float64 numpy array."""
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=np.float64)


def load_model_or_reason(run_dir: Path, device: str):
    """(model, None) or (None, reason) when the trained model cannot be loaded (checkpoint
    missing)."""
    # the trainer's entry points are imported when called (tests replace them in sys.modules)
    from m4dgs.model.trained import load_model

    try:
        return load_model(run_dir, device=device), None
    except FileNotFoundError as e:
        return None, f"no trained model ({e})"


def model_metrics(model, clip: Clip, fps: bool, device: str) -> dict:
    """Track error, learned CRF and render FPS from a loaded TrainedModel."""
    out: dict = {}
    # learned CRF vs the true one
    z = np.linspace(*CRF_LOG2_RANGE, CRF_SAMPLES)
    with torch.no_grad():
        learned = to_numpy(model.tonemap_curve(torch.tensor(z, dtype=torch.float32)))
    learned = learned.reshape(len(z), -1)
    true = None
    true_crf = None
    if clip.meta.crf:
        try:
            true_crf = get_crf(clip.meta.crf)
        except KeyError:  # a curve this installation does not know
            true_crf = None
    if true_crf is not None:
        true = np.asarray(true_crf(np.exp2(z)), np.float64)
        true_rgb = np.asarray(
            true_crf.rgb(np.repeat(np.exp2(z)[:, None], learned.shape[1], 1)), np.float64
        )
        out["crf_rmse"] = float(np.sqrt(np.mean((learned - true_rgb) ** 2)))
        if clip.has_gt and clip.has_gt_part("hdr") and clip.train_frames:
            frames = (clip.load_gt_hdr(g) for g in clip.train_frames)
            ranges = observed_exposure_range(frames, clip.meta.exposures.train_dt, true_crf)

            def curve(log2_x):
                with torch.no_grad():
                    return to_numpy(model.tonemap_curve(torch.tensor(log2_x, dtype=torch.float32)))

            ce = crf_error(curve, true_crf, ranges)
            out["crf_error"] = ce.pop("crf_error")
            out["crf_error_detail"] = ce
    out["crf_curve"] = {
        "log2_x": z.tolist(),
        "learned": learned.tolist(),
        "true": None if true is None else true.tolist(),
        "crf": clip.meta.crf,
    }
    # induced 2D tracks vs gt tracks
    if hasattr(model, "track_2d") and clip.has_gt and (clip.root / "gt/tracks.npz").exists():
        ts = clip.load_gt_tracks()
        cand = np.nonzero(ts.visible[:, 0])[0]
        if cand.size:
            rng = np.random.default_rng(0)
            idx = np.sort(rng.choice(cand, size=min(TRACK_SAMPLES, cand.size), replace=False))
            uv = torch.tensor(ts.tracks[idx, 0], dtype=torch.float32)
            with torch.no_grad():
                pred = to_numpy(model.track_2d(uv, int(ts.frames[0]), [int(g) for g in ts.frames]))
            gt_tr, vis = ts.tracks[idx].astype(np.float64), ts.visible[idx]
            # NaN: the model has no surface at the query (or it went behind the camera)
            ok = np.isfinite(pred).all(-1)
            out["track_coverage"] = float((ok & vis).sum() / max(int(vis.sum()), 1))
            vis = vis & ok
            pred = np.where(ok[..., None], pred, 0.0)
            te = track_error(pred, gt_tr, vis)
            out["track_epe"], out["track_delta_avg"] = te["epe"], te["delta_avg"]
            err = np.linalg.norm(pred - gt_tr, axis=-1)[vis]  # robust companion of the mean EPE
            out["track_epe_median"] = float(np.median(err)) if err.size else None
            out["track_points"] = int(idx.size)
    # render speed
    if fps:
        g = clip.meta.frames[len(clip.meta.frames) // 2]
        t = model.time_of(g)
        K, c2w = model.camera(g)
        K = np.asarray(K, np.float64)
        W, H = clip.width, clip.height

        def at(w, h):
            Ks = K.copy()
            Ks[0] *= w / W
            Ks[1] *= h / H
            return lambda: model.render(t, c2w, Ks, w, h)

        dev = getattr(model, "device", device)
        out["fps"] = measure_fps(at(W, H), warmup=2, iters=10, device=dev)["fps"]
        out["fps_864x480"] = measure_fps(at(*FPS_SIZE), warmup=2, iters=5, device=dev)["fps"]
        out["fps_device"] = str(dev)
    return out


def score_model(job, m: dict, fps: bool, device: str) -> Tuple[str, List[str]]:
    """Track error, learned CRF and render FPS from the trained model; returns (what happened to the
    model, convention keys)."""
    mdl, why = load_model_or_reason(job.run_dir, device)
    if mdl is None:
        return why, []
    keys: List[str] = []
    mm = model_metrics(mdl, job.clip, fps, device)
    if m["num_gaussians"] is None and getattr(mdl, "num_gaussians", None) is not None:
        m["num_gaussians"] = float(mdl.num_gaussians)
    m["crf_curve"] = mm.pop("crf_curve")
    if "crf_error_detail" in mm:
        m["crf_error_detail"] = mm.pop("crf_error_detail")
    m.update(mm)
    keys.append("crf_rmse")
    if mm.get("crf_error") is not None:
        keys.append("crf_error")
    if mm.get("track_epe") is not None:
        keys += ["track", "track_first_frame"]
    if fps:
        keys.append("fps")
    return "loaded", keys
