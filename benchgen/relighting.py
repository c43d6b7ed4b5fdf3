"""How much the light on a clip's static surfaces changes over time.

The paper's model gives every Gaussian one colour for the whole clip (section 3, "Gaussian
Dynamics": scaling, opacity and colour are time-invariant). A static surface whose radiance changes
over time, because a light moves past it (a swinging bulb, a spark crossing a room, a car's
headlights) or an object shadows it, is then outside the model: the method cannot fit even its own
training frames there, while a 2D prediction (a copy of the nearest frame) copies the lighting.

`static_relighting` measures that change from exact ground truth: for every static ground-truth
track point seen on at least `min_frames` frames (every frame of a shorter clip), the ratio of the
90th to the 10th percentile of its HDR luminance (a 3x3 box mean around its pixel, against render
noise) over the frames that see it. 1 means constant light; glossy surfaces seen from a moving
camera also change with the view, so a few percent above 1 is normal. The clip's figure is the
median of that ratio over the points, with the fraction of points whose ratio exceeds `RELIT_RATIO`
(for scenes where only part of the room is relit; points on high-contrast edges, where a sub-pixel
shift changes the box mean, count there too, 4-15 % of the points in the shipped scenes whose
lights do not move).

Pure functions of numpy arrays; `clip_relighting` reads a clip's gt/tracks.npz and gt/hdr/.
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, Optional

import numpy as np

#: Rec. 709 luminance weights (linear RGB)
LUMA = np.array([0.2126, 0.7152, 0.0722])
#: a point must be seen on this many frames to count (on every frame of a shorter clip)
MIN_FRAMES = 10
#: a point whose 90th / 10th percentile ratio exceeds this counts as relit
RELIT_RATIO = 2.0
#: side of the box mean taken around a point's pixel (odd)
BOX = 3


def box_mean(img: np.ndarray, box: int = BOX) -> np.ndarray:
    """img [H, W] -> [H, W], the mean over a box x box window (edges repeated)."""
    r = box // 2
    p = np.pad(np.asarray(img, np.float64), r, mode="edge")
    h, w = img.shape
    return sum(p[i : i + h, j : j + w] for i in range(box) for j in range(box)) / (box * box)


def static_relighting(
    luminance: np.ndarray,
    tracks: np.ndarray,
    visible: np.ndarray,
    dynamic: np.ndarray,
    min_frames: int = MIN_FRAMES,
    box: int = BOX,
) -> Dict[str, Optional[float]]:
    """Relighting statistics of a clip (module docstring).

    luminance [T, H, W] the HDR luminance of every frame; tracks [N, T, 2] exact pixel positions
    (x, y) of N surface points in those frames, visible [N, T] whether each is seen, dynamic [N]
    whether it moves (moving points are left out: their light may change because they move).
    Returns median_ratio (the median of the per-point 90th / 10th percentile ratios), relit_fraction
    (the fraction of points whose ratio exceeds RELIT_RATIO), both None when no point qualifies, and
    points (how many qualified)."""
    lum = np.asarray(luminance, np.float64)
    tracks = np.asarray(tracks, np.float64)
    visible = np.asarray(visible, bool)
    dynamic = np.asarray(dynamic, bool)
    t, h, w = lum.shape
    if tracks.shape[:2] != (len(dynamic), t) or visible.shape != tracks.shape[:2]:
        raise ValueError(
            f"tracks {tracks.shape}, visible {visible.shape} and dynamic {dynamic.shape} do not "
            f"match {t} frames of luminance"
        )
    smooth = np.stack([box_mean(f, box) for f in lum])
    keep = ~dynamic
    xy = tracks[keep]
    seen = visible[keep] & np.isfinite(xy).all(-1)
    x = np.round(np.nan_to_num(xy[..., 0], nan=-1.0)).astype(np.int64)
    y = np.round(np.nan_to_num(xy[..., 1], nan=-1.0)).astype(np.int64)
    seen &= (x >= 0) & (x < w) & (y >= 0) & (y < h)
    frame = np.broadcast_to(np.arange(t)[None, :], seen.shape)
    vals = np.where(seen, smooth[frame, np.clip(y, 0, h - 1), np.clip(x, 0, w - 1)], np.nan)
    vals = vals[seen.sum(1) >= min(min_frames, t)]
    if len(vals) == 0:
        return {"median_ratio": None, "relit_fraction": None, "points": 0}
    hi = np.nanpercentile(vals, 90, axis=1)
    lo = np.nanpercentile(vals, 10, axis=1)
    ratio = hi / np.maximum(lo, 1e-12)
    return {
        "median_ratio": float(np.median(ratio)),
        "relit_fraction": float(np.mean(ratio > RELIT_RATIO)),
        "points": int(len(ratio)),
    }


def clip_relighting(
    clip_root, min_frames: int = MIN_FRAMES
) -> Optional[Dict[str, Optional[float]]]:
    """static_relighting of a clip folder from gt/tracks.npz (tracks, visible, dynamic, frames) and
    gt/hdr/<frame>.exr; None when the clip has no ground-truth tracks."""
    from m4dgs.core.io import read_exr

    root = Path(clip_root)
    path = root / "gt" / "tracks.npz"
    if not path.exists():
        return None
    with np.load(path) as d:
        missing = [k for k in ("tracks", "visible", "dynamic", "frames") if k not in d.files]
        if missing:
            raise ValueError(
                f"{path}: no field {missing[0]!r} (expected tracks, visible, dynamic, frames)"
            )
        tracks, visible, dynamic, frames = (
            d[k] for k in ("tracks", "visible", "dynamic", "frames")
        )
    lum = []
    for f in frames:
        exr = root / "gt" / "hdr" / f"{int(f):05d}.exr"
        if not exr.exists():
            raise FileNotFoundError(
                f"{exr}: missing (gt/tracks.npz field 'frames' lists frame {int(f)})"
            )
        lum.append(read_exr(exr)[..., :3] @ LUMA)
    return static_relighting(np.stack(lum), tracks, visible, dynamic, min_frames=min_frames)
