"""How much of a test frame's highlight peak its neighbouring training frames show.

    python bench/highlight_interp_bound.py CLIP [CLIP ...] [--json OUT]

A method trained on the training frames renders a test frame between two of them. Where a highlight
flares between them (a glint on a turning object), the training frames never see its peak, so no
method that interpolates over time can render it. This script reads the clip's ground truth only
(no run): for every highlight pixel of each test frame (the scorer's mask:
eval.metrics.scene_hdr.highlight_mask, saturated at the longest observed exposure and measured at
the shortest), the surface point under it is carried to each neighbouring training frame by the
ground-truth point tracks (the median displacement of the `k` nearest tracks visible at both
frames, the nearest within `near_px`), and the neighbour's true luminance is read there. Three
stand-ins for a render, each scored like `highlight_peak_ratio` (the largest value over the
frame's highlight pixels / the truth's, geometric mean over the test frames):

- `max`: the brighter of the two neighbours at the carried point (a render that keeps, at every
  surface point, the brightest the training frames show it);
- `mean`: their mean (linear interpolation in time at the surface point);
- `same_pixel`: the brighter neighbour at the same pixel (a copy of a neighbouring frame).

Luminance: Rec. 709 weights of the linear HDR. Printed per clip: the three peak ratios and how
many test frames each puts in the band 0.5-2 of the highlight requirement (docs/method.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
from scipy.spatial import cKDTree

from eval.metrics.scene_hdr import LUMA, highlight_mask, peak_geomean

BAND = (0.5, 2.0)
KINDS = ("max", "mean", "same_pixel")


def luminance(hdr: np.ndarray) -> np.ndarray:
    """[H, W] Rec. 709 luminance of a linear [H, W, 3] image (the scorer's weights)."""
    return np.asarray(hdr, np.float64) @ LUMA


def carry_points(
    pts: np.ndarray,
    tracks_a: np.ndarray,
    tracks_b: np.ndarray,
    k: int = 3,
    near_px: float = 2.0,
) -> np.ndarray:
    """[N, 2] where the surface points at pixel positions pts [N, 2] (x, y; centres at +0.5) of
    frame a are in frame b: pts plus the median displacement of the k tracks nearest each point,
    tracks_a / tracks_b [M, 2] the positions at a and b of the tracks visible at both. NaN where
    the nearest track is farther than near_px (or there is none)."""
    pts = np.asarray(pts, np.float64).reshape(-1, 2)
    a = np.asarray(tracks_a, np.float64).reshape(-1, 2)
    out = np.full_like(pts, np.nan)
    if len(a) == 0:
        return out
    disp = np.asarray(tracks_b, np.float64).reshape(-1, 2) - a
    d, near = cKDTree(a).query(pts, k=min(k, len(a)))
    d, near = d.reshape(len(pts), -1), near.reshape(len(pts), -1)
    ok = d[:, 0] <= near_px
    out[ok] = pts[ok] + np.median(disp[near[ok]], axis=1)
    return out


def _at(lum: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Values of lum [H, W] at the pixels containing points q [N, 2] (0 where q is NaN)."""
    H, W = lum.shape
    ok = np.isfinite(q).all(axis=1)
    x = np.clip(np.floor(np.nan_to_num(q[:, 0])), 0, W - 1).astype(int)
    y = np.clip(np.floor(np.nan_to_num(q[:, 1])), 0, H - 1).astype(int)
    return np.where(ok, lum[y, x], 0.0)


def frame_bound(
    lum: np.ndarray,
    mask: np.ndarray,
    neighbours: Sequence[Tuple[np.ndarray, np.ndarray]],
) -> Dict[str, float]:
    """The three stand-ins' peak ratios on one test frame (module docstring).

    Args:
        lum: [H, W] the test frame's true luminance; mask: [H, W] bool, its highlight pixels.
        neighbours: per neighbouring training frame, (its true luminance [H, W], the mask's pixels
            carried there [N, 2], N = mask.sum(), in np.nonzero(mask) order; NaN = not carried).
    Returns:
        {"max", "mean", "same_pixel"}: the stand-in's largest value over the mask / the truth's.
    """
    ys, xs = np.nonzero(mask)
    peak = float(lum[ys, xs].max())
    carried = np.stack([_at(nl, q) for nl, q in neighbours])  # [K, N]
    same = np.stack([nl[ys, xs] for nl, _ in neighbours])
    return {
        "max": float(carried.max(axis=0).max()) / peak,
        "mean": float(carried.mean(axis=0).max()) / peak,
        "same_pixel": float(same.max(axis=0).max()) / peak,
    }


def clip_bound(clip_dir: Path, k: int = 3, near_px: float = 2.0) -> Dict:
    """Per test frame with highlight pixels, frame_bound's ratios, and their geometric means."""
    from eval.experiments.score_scene import true_response
    from m4dgs.clip import Clip

    clip = Clip.open(clip_dir)
    crf = true_response(clip)
    obs = list(clip.meta.exposures.observed)
    if crf is None or len(obs) < 2:
        raise SystemExit(f"{clip_dir}: no highlight pixels to score (one exposure or no response)")
    train = list(clip.train_frames)
    tr = clip.load_gt_tracks()
    index = {int(g): i for i, g in enumerate(tr.frames)}
    frames = []
    for g in clip.test_frames:
        gt = clip.load_gt_hdr(g)
        mask = highlight_mask(gt, crf, max(obs), min(obs))
        nb = [t for t in train if abs(t - g) == 1]
        if not mask.any() or not nb:
            continue
        ys, xs = np.nonzero(mask)
        pts = np.stack([xs + 0.5, ys + 0.5], axis=1)
        neighbours = []
        for t in nb:
            both = tr.visible[:, index[g]] & tr.visible[:, index[t]]
            q = carry_points(pts, tr.tracks[both, index[g]], tr.tracks[both, index[t]], k, near_px)
            neighbours.append((luminance(clip.load_gt_hdr(t)), q))
        frames.append({"frame": int(g), **frame_bound(luminance(gt), mask, neighbours)})
    summary = {}
    for kind in KINDS:
        v = [f[kind] for f in frames]
        summary[kind] = {
            "peak_ratio": peak_geomean(v),
            "in_band": int(sum(BAND[0] <= x <= BAND[1] for x in v)),
        }
    return {"clip": Path(clip_dir).name, "frames": frames, "summary": summary}


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("clips", nargs="+", type=Path, help="evaluation clip folders (with gt/)")
    ap.add_argument("--json", type=Path, help="also write every frame's figures here")
    a = ap.parse_args(argv)
    from m4dgs.clip import ClipError

    try:
        reports = [clip_bound(c) for c in a.clips]
    except ClipError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for r in reports:
        n = len(r["frames"])
        parts = [
            f"{kind} {s['peak_ratio']:.3f} ({s['in_band']} of {n} in 0.5-2)"
            for kind, s in r["summary"].items()
        ]
        print(f"{r['clip']}: {n} test frames with highlights; peak ratio " + ", ".join(parts))
    if a.json:
        a.json.write_text(json.dumps(reports, indent=1, allow_nan=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
