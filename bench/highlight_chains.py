"""Which of a clip's highlight chains follow its truly moving pixels.

    python bench/highlight_chains.py CLIP [CLIP ...] [--json OUT]

For each evaluation clip (the layout of docs/clip-format.md: input/ldr, clip.json, gt/masks/dynamic)
this runs the tracker of `full-highlights` (m4dgs.priors.highlight_tracks.highlight_chains, default
arguments) on the training frames, as training does, and measures, for every chain, the distance in
pixels from each of its blob centroids to the nearest true dynamic pixel of that frame. A chain is
"on the movers" when the median of those distances is under 1 px, and "still" by the rule of
highlight_masks (m4dgs.priors.highlight_tracks.chain_is_still: a lamp seen by a still camera, the
chains `masks.highlight_blobs` leaves out).

Printed per clip: the number of chains, and for those on the movers their lengths in training
frames, out of the clip's training frames. This is the "chains on the movers" figure of the
hard-scene readings in the research notes; it reads only the clip, not a run.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np
from scipy import ndimage

from m4dgs.clip import Clip
from m4dgs.priors.highlight_tracks import chain_is_still, highlight_chains


def chain_report(clip_dir: Path) -> Dict:
    """The chains of a clip's training frames and their distances to the true dynamic pixels."""
    clip = Clip.open(clip_dir)
    train = clip.train_frames
    frames = np.stack([clip.load_ldr(g) for g in train])
    dist = []
    for g in train:
        m = clip.load_gt_dynamic_mask(g)
        # distance of every pixel to the nearest dynamic pixel (inf on a frame without one)
        dist.append(ndimage.distance_transform_edt(~m) if m.any() else np.full(m.shape, np.inf))
    out = []
    for ch in highlight_chains(frames, clip.train_dt):
        d = [
            float(dist[t][min(int(b.y), frames.shape[1] - 1), min(int(b.x), frames.shape[2] - 1)])
            for t, b in ch
        ]
        med = float(np.median(d))  # inf: the chain's frames have no moving pixel
        out.append(
            {
                "frames": len(ch),
                "first": int(train[ch[0][0]]),
                "median_px": med,
                "still": chain_is_still(ch),
                "on_movers": med < 1.0,
            }
        )
    return {"clip": clip_dir.name, "train_frames": len(train), "chains": out}


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("clips", nargs="+", type=Path, help="evaluation clip folders")
    ap.add_argument("--json", type=Path, help="also write every chain's figures here")
    a = ap.parse_args(argv)
    reports = [chain_report(c) for c in a.clips]
    for r in reports:
        on = [c["frames"] for c in r["chains"] if c["on_movers"]]
        off = [c for c in r["chains"] if not c["on_movers"]]
        dists = ", ".join(f"{c['median_px']:.0f}" for c in off if np.isfinite(c["median_px"]))
        print(
            f"{r['clip']}: {len(r['chains'])} chains; on the movers: "
            f"{', '.join(map(str, sorted(on, reverse=True))) or 'none'} of {r['train_frames']} "
            f"training frames; elsewhere: {len(off)} ({sum(c['still'] for c in off)} still, "
            f"median distance {dists or 'n/a'} px)"
        )
    if a.json:
        for r in reports:  # JSON has no inf
            for c in r["chains"]:
                c["median_px"] = c["median_px"] if np.isfinite(c["median_px"]) else None
        a.json.write_text(json.dumps(reports, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
