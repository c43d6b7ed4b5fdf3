"""How bright stage 1 makes the Gaussians that follow a clip's true movers, against the truth.

    python bench/follower_colour.py RUN CLIP [--json OUT]

The followers are those of bench/v2w_lift.py: stage-1 Gaussians with opacity over 0.3 whose pixel
lies on gt/masks/dynamic at a third of the training frames or more. Their HDR colour is the run's
stage-1 colour MLP on their features (no view direction, as stage 1 renders), the mean of R, G, B.
It is put in units of the still background: divided by the run's HDR scale (median over the
training frames of render / truth over the still pixels, renders/stage1/hdr) times the truth's
median HDR over the still pixels. Printed: the followers' quartiles, 90th percentile and maximum in
those units, beside the truth's peak over the moving pixels in the same units (median over the
frames) and the brightest opaque Gaussian of the whole model: a mover rendered as bright as it is
has followers near its peak.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np
import torch

from m4dgs.clip import Clip
from m4dgs.core.io import read_exr
from m4dgs.model.color import ColorMLP
from m4dgs.model.gaussians import VideoGaussians

sys.path.insert(0, str(Path(__file__).resolve().parent))
from v2w_lift import FOLLOW_OPACITY, stage1_followers  # noqa: E402


def colour_report(run: Path, clip_dir: Path) -> Dict:
    """The followers' HDR colour in units of the still background (module docstring)."""
    run = Path(run)
    clip = Clip.open(clip_dir)
    s1, frames, _, followers = stage1_followers(run, clip)
    video = VideoGaussians.from_state(s1["gaussians"])
    mlp = ColorMLP()
    mlp.load_state_dict(s1["color"])
    with torch.no_grad():
        opacity = video.opacities().reshape(-1).numpy()
        colour = mlp(video.params["features"]).mean(-1).numpy()  # [N]
    peak, still_truth, still_ratio = [], [], []
    for g in frames:
        m = clip.load_gt_dynamic_mask(g)
        truth = clip.load_gt_hdr(g)[..., :3].mean(-1)
        if m.any() and not m.all():
            render = read_exr(run / "renders" / "stage1" / "hdr" / f"{g:05d}.exr")[..., :3].mean(-1)
            peak.append(float(truth[m].max()))
            still_truth.append(float(np.median(truth[~m])))
            still_ratio.append(float(np.median(render[~m]) / max(np.median(truth[~m]), 1e-12)))
    rep: Dict = {"run": str(run), "clip": Path(clip_dir).name, "followers": 0}
    if not peak:
        return rep
    unit = float(np.median(still_ratio) * np.median(still_truth))  # the background in run units
    rep.update(
        followers=int(followers.sum()),
        hdr_scale=float(np.median(still_ratio)),
        truth_peak=float(np.median(np.asarray(peak) / np.asarray(still_truth))),
        brightest_opaque=float(colour[opacity > FOLLOW_OPACITY].max() / unit),
    )
    if followers.any():
        q = np.percentile(colour[followers] / unit, [25, 50, 75, 90, 100])
        rep["followers_q"] = [float(v) for v in q]
    return rep


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("run", type=Path, help="a run folder (model/stage1.pt, renders/stage1/hdr)")
    ap.add_argument("clip", type=Path, help="its evaluation clip (gt/hdr, gt/masks/dynamic)")
    ap.add_argument("--json", type=Path, help="also write the report here")
    a = ap.parse_args(argv)
    rep = colour_report(a.run, a.clip)
    if "truth_peak" not in rep:
        print(f"{rep['clip']}: no frame with moving pixels")
        return 1
    head = (
        f"{rep['clip']}: truth's peak {rep['truth_peak']:.1f} x the still background; "
        f"brightest opaque Gaussian {rep['brightest_opaque']:.1f}"
    )
    if "followers_q" in rep:
        q = "/".join(f"{v:.1f}" for v in rep["followers_q"][:3])
        head += (
            f"; {rep['followers']} followers: {q} (quartiles), 90th {rep['followers_q'][3]:.1f},"
            f" max {rep['followers_q'][4]:.1f}"
        )
    else:
        head += "; no follower"
    print(head)
    if a.json:
        a.json.write_text(json.dumps(rep, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
