"""How much of the movers' radiance a run renders: mean HDR over the moving pixels, render / truth.

    python bench/mover_hdr.py RUN CLIP [--json OUT]

For each of a run's HDR renders (renders/stage1/hdr: stage 1 at the training frames;
renders/train/hdr and renders/test/hdr: the final model), and each frame with moving pixels (the
clip's gt/masks/dynamic), the mean over those pixels of the render's HDR (the mean of R, G, B)
divided by the truth's (gt/hdr), and the same over the still pixels. The method's HDR is known up
to the exposure scale it learned, so the figure to read is their quotient: 1 when the movers are
rendered as bright, relative to the rest of the frame, as they are; 0.02 when 98 % of their
radiance is lost. Printed: quartiles over the frames of the quotient and of the movers' ratio, and
the number of frames. It is the "render / truth over the spark's pixels" figure of the hard-lit
readings in the research notes."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

from m4dgs.clip import Clip
from m4dgs.core.io import read_exr

RENDERS = ("stage1/hdr", "train/hdr", "test/hdr")


def frame_ratios(render: np.ndarray, truth: np.ndarray, moving: np.ndarray) -> tuple:
    """(movers, still): mean render HDR / mean true HDR over the moving pixels and over the rest.

    Args:
        render, truth: [H, W, 3] linear HDR.
        moving: [H, W] bool, with at least one moving and one still pixel.
    """
    r, t = render[..., :3].mean(-1), truth[..., :3].mean(-1)
    still = ~moving
    return float(r[moving].mean() / t[moving].mean()), float(r[still].mean() / t[still].mean())


def mover_report(run: Path, clip_dir: Path) -> Dict:
    """Per render folder of RUN: quartiles over frames of the movers' ratio and of the quotient."""
    clip = Clip.open(clip_dir)
    out: Dict = {"run": str(run), "clip": Path(clip_dir).name, "renders": {}}
    for sub in RENDERS:
        folder = Path(run) / "renders" / sub
        if not folder.is_dir():
            continue
        movers, quotient = [], []
        for p in sorted(folder.glob("*.exr")):
            g = int(p.stem)
            m = clip.load_gt_dynamic_mask(g)
            if not m.any() or m.all():
                continue
            dyn, still = frame_ratios(read_exr(p), clip.load_gt_hdr(g), m)
            movers.append(dyn)
            quotient.append(dyn / still)
        if movers:
            out["renders"][sub] = {
                "frames": len(movers),
                "movers_q": np.percentile(movers, [25, 50, 75]).tolist(),
                "quotient_q": np.percentile(quotient, [25, 50, 75]).tolist(),
            }
    return out


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("run", type=Path, help="a run folder (renders/ inside)")
    ap.add_argument("clip", type=Path, help="its evaluation clip (gt/hdr, gt/masks/dynamic)")
    ap.add_argument("--json", type=Path, help="also write the report here")
    a = ap.parse_args(argv)
    rep = mover_report(a.run, a.clip)
    if not rep["renders"]:
        print(f"{a.run}: no HDR render of a frame with moving pixels")
        return 1
    for sub, r in rep["renders"].items():
        q = "/".join(f"{x:.3f}" for x in r["quotient_q"])
        mv = "/".join(f"{x:.3f}" for x in r["movers_q"])
        print(f"{sub}: movers / still {q}, movers {mv} (quartiles over {r['frames']} frames)")
    if a.json:
        a.json.write_text(json.dumps(rep, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
