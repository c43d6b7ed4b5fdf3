"""How far the video-to-world transform moves the Gaussians that follow a clip's true movers.

    python bench/v2w_lift.py RUN CLIP [--json OUT]

Stage 1 ends with video Gaussians whose x, y are pixels up to an affine map; the V2W transform
lifts each dynamic one into the world along the bundle-adjusted cameras and fits a world spline to
that path (m4dgs.training.v2w). Reprojected into the same cameras, the world Gaussian lands where
the video one was only as far as that fit allows. For the followers of the true movers (stage-1
Gaussians with opacity over 0.3 whose pixel lies on gt/masks/dynamic at a third of the training
frames or more, and that V2W classified dynamic), this measures, at every training frame, the
distance in pixels between the video Gaussian (model/stage1.pt) and its world Gaussian at the
start of stage 2 (model/v2w.pt) projected by the cameras of cameras_ba.json. Printed: the
followers' count, quartiles and 90th percentile of the distance over (follower, frame), and the
same over every dynamic Gaussian. A figure of the hand-over from stage 1 to stage 2 in the
hard-lit readings of the research notes.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np
import torch

from m4dgs.clip import Cameras, Clip
from m4dgs.core.camera import ortho_to_pixel
from m4dgs.model.gaussians import VideoGaussians, WorldGaussians
from m4dgs.run import load_torch

FOLLOW_OPACITY = 0.3  # a follower is opaque ...
FOLLOW_FRACTION = 1 / 3  # ... and on the moving pixels at this fraction of the training frames


def pinhole_pixels(points_world: np.ndarray, K: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """Pixels of world points seen by per-frame pinhole cameras (OpenCV convention).

    Args:
        points_world: [N, T, 3]. K: [3, 3] or [T, 3, 3]. c2w: [T, 4, 4].
    Returns:
        [N, T, 2] pixel coordinates (NaN behind a camera).
    """
    R, t = c2w[:, :3, :3], c2w[:, :3, 3]
    cam = np.einsum("tji,ntj->nti", R, points_world - t[None])  # R^T (p - t)
    Ks = np.broadcast_to(K, (c2w.shape[0], 3, 3))
    z = cam[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = Ks[None, :, 0, 0] * cam[..., 0] / z + Ks[None, :, 0, 2]
        v = Ks[None, :, 1, 1] * cam[..., 1] / z + Ks[None, :, 1, 2]
    uv = np.stack([u, v], -1)
    uv[z <= 0] = np.nan
    return uv


def stage1_followers(run: Path, clip: Clip) -> Tuple[dict, List[int], np.ndarray, np.ndarray]:
    """A run's stage-1 state (model/stage1.pt), its training frames, the video Gaussians' pixels at
    them [N, T, 2] and the followers of the clip's true movers [N] bool: opacity over
    FOLLOW_OPACITY and on gt/masks/dynamic at FOLLOW_FRACTION of the training frames or more."""
    s1 = load_torch(Path(run) / "model" / "stage1.pt", map_location="cpu")
    video = VideoGaussians.from_state(s1["gaussians"])
    frames = [int(f) for f in s1["frames"]]
    T = len(frames)
    w, h = clip.width, clip.height
    with torch.no_grad():
        uv = ortho_to_pixel(video.positions(torch.arange(T, dtype=torch.float32))[..., :2], w, h)
        uv = uv.numpy().astype(np.float64)
        opacity = video.opacities().numpy().reshape(-1)
    on = np.zeros((opacity.size, T), bool)
    for i, g in enumerate(frames):
        m = clip.load_gt_dynamic_mask(g)
        x, y = uv[:, i, 0], uv[:, i, 1]
        ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
        on[:, i] = ok & m[np.clip(y.astype(int), 0, h - 1), np.clip(x.astype(int), 0, w - 1)]
    followers = (on.sum(1) >= T * FOLLOW_FRACTION) & (opacity > FOLLOW_OPACITY)
    return s1, frames, uv, followers


def lift_report(run: Path, clip_dir: Path) -> Dict:
    """The stage-1-to-V2W pixel distances of the followers and of every dynamic Gaussian."""
    run = Path(run)
    clip = Clip.open(clip_dir)
    _, frames, uv1, followers = stage1_followers(run, clip)
    T = len(frames)
    v2w = load_torch(run / "model" / "v2w.pt", map_location="cpu")
    world = WorldGaussians.from_state(v2w["gaussians"])
    is_dyn = np.asarray(v2w["report"]["is_dynamic"], bool)
    n_static = int(v2w["gaussians"]["static"]["means"].shape[0])
    with (run / "cameras_ba.json").open() as f:
        cams = Cameras.from_json(json.load(f), run / "cameras_ba.json")
    where = {int(g): i for i, g in enumerate(cams.frames)}
    sel = [where[g] for g in frames]
    K = np.asarray(cams.K, np.float64)[sel]
    c2w = np.asarray(cams.c2w, np.float64)[sel]
    with torch.no_grad():
        pw = world.positions(torch.arange(T, dtype=torch.float32)).numpy().astype(np.float64)
    if is_dyn.size != followers.size:
        raise SystemExit(
            f"{run}: v2w.pt's is_dynamic has {is_dyn.size} entries, stage1.pt {followers.size}"
        )
    followers = followers & is_dyn
    row = n_static + np.cumsum(is_dyn) - 1  # the world row of each dynamic stage-1 Gaussian
    uv2 = pinhole_pixels(pw[row[is_dyn]], K, c2w)  # [N_dynamic, T, 2]
    dist = np.linalg.norm(uv2 - uv1[is_dyn], axis=-1)  # [N_dynamic, T]
    fol = dist[followers[is_dyn]]

    def stats(d: np.ndarray) -> Optional[Dict]:
        d = d[np.isfinite(d)]
        if not d.size:
            return None
        q = np.percentile(d, [25, 50, 75, 90])
        return {"q25": q[0], "median": q[1], "q75": q[2], "p90": q[3]}

    return {
        "run": str(run),
        "clip": Path(clip_dir).name,
        "dynamic": int(is_dyn.sum()),
        "followers": int(followers.sum()),
        "followers_px": stats(fol),
        "dynamic_px": stats(dist),
    }


def _fmt(s: Optional[Dict]) -> str:
    if s is None:
        return "none"
    return f"{s['q25']:.2f}/{s['median']:.2f}/{s['q75']:.2f} px (90th {s['p90']:.2f})"


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("run", type=Path, help="a run folder (model/stage1.pt, model/v2w.pt inside)")
    ap.add_argument("clip", type=Path, help="its evaluation clip (gt/masks/dynamic)")
    ap.add_argument("--json", type=Path, help="also write the report here")
    a = ap.parse_args(argv)
    rep = lift_report(a.run, a.clip)
    print(
        f"{rep['clip']}: {rep['followers']} followers of the movers, of {rep['dynamic']} dynamic;"
        f" stage 1 to V2W: followers {_fmt(rep['followers_px'])}, all dynamic"
        f" {_fmt(rep['dynamic_px'])}"
    )
    if a.json:
        a.json.write_text(json.dumps(rep, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
