"""Where TLR's value and gradient sit: the loss's quantity |H_w - H| / (H_w + H) (channel mean,
m4dgs.losses.temporal.tlr_loss) on the ground truth's training sequence and on finished runs'
training-frame HDR renders, every pair of consecutive training frames warped with the exact
ground-truth flow (gt/flow.npz, both directions) and masked by its visibility.

    python bench/tlr_share.py CLIP [RUN ...] [--dark 0.01,0.05,0.1,0.25] [--bright 0.01] [--every 1]

Prints, for the ground truth and each run: the mean value (the truth's is what no model can go
below on average without removing real change: textures resampled at sub-pixel offsets, noise,
lights that change); the share of the value and of the linear-HDR gradient magnitude
1 / (H_w + H) (the detached denominator's gradient per pixel) that falls on the darkest pixels of
each --dark fraction (by the frame's mean channel) and on the brightest of each --bright one; for
the ground truth, the share of its value on its 3 % most changing pixels and how many of those are
in the darkest quarter. The runs' renders are read from RUN/renders/train/hdr (written at the end
of every training).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from m4dgs.core.io import read_exr  # noqa: E402
from m4dgs.core.warp import backward_warp  # noqa: E402
from m4dgs.losses.temporal import flow_in_bounds, relative_difference  # noqa: E402


def pixel_values(frames: Path, flows: dict, every: int = 1):
    """Per visible pixel of every `every`-th flow pair (a, b): the value |W - A| / (W + A)
    (channel mean), the gradient magnitude 1 / (W + A) (channel mean) and A's mean channel, where
    W is frame b warped onto a with the flow F_{a->b}; three 1-d arrays."""
    cache = {}

    def frame(g: int) -> torch.Tensor:
        if g not in cache:
            x = read_exr(frames / f"{g:05d}.exr")[..., :3].astype(np.float32)
            cache[g] = torch.from_numpy(x)
        return cache[g]

    vals, grads, lums = [], [], []
    for k in range(0, len(flows["pairs"]), every):
        a, b = (int(x) for x in flows["pairs"][k])
        flow = torch.from_numpy(flows["flow"][k])
        vis = torch.from_numpy(flows["valid"][k]) & flow_in_bounds(flow)
        A = frame(a)
        w = backward_warp(frame(b), flow)
        vals.append(relative_difference(w, A).mean(-1)[vis].numpy())
        grads.append((1.0 / (w + A + 1e-10)).mean(-1)[vis].numpy())
        lums.append(A.mean(-1)[vis].numpy())
    return np.concatenate(vals), np.concatenate(grads), np.concatenate(lums)


def report(
    name: str, v: np.ndarray, g: np.ndarray, lum: np.ndarray, dark, truth: bool, bright=()
) -> None:
    print(
        f"{name}: mean {v.mean():.4f} over {v.size} visible pixels (median luminance "
        f"{np.median(lum):.3g})"
    )
    for q in dark:
        t = np.quantile(lum, q)
        s = lum <= t
        print(
            f"  darkest {q:.0%} (<= {t:.3g}): {v[s].sum() / v.sum():.2f} of the value, "
            f"{g[s].sum() / g.sum():.2f} of the gradient"
        )
    for q in bright:
        t = np.quantile(lum, 1.0 - q)
        s = lum >= t
        print(
            f"  brightest {q:.0%} (>= {t:.3g}): {v[s].sum() / v.sum():.2f} of the value, "
            f"{g[s].sum() / g.sum():.4f} of the gradient"
        )
    if truth:
        top = v >= np.quantile(v, 0.97)
        q25 = np.quantile(lum, 0.25)
        print(
            f"  its 3 % most changing pixels (mean {v[top].mean():.3f}): "
            f"{v[top].sum() / v.sum():.2f} of the value; {np.mean(lum[top] <= q25):.2f} of them in "
            f"the darkest quarter"
        )


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("clip", help="clip folder with gt/hdr and gt/flow.npz")
    ap.add_argument("runs", nargs="*", help="finished run folders of the clip")
    ap.add_argument("--dark", default="0.01,0.05,0.1,0.25", help="darkest fractions to report")
    ap.add_argument(
        "--bright", default="", help="brightest fractions to report too (e.g. 0.01,0.1)"
    )
    ap.add_argument("--every", type=int, default=1, help="use every n-th flow pair")
    a = ap.parse_args()
    clip = Path(a.clip)
    if not (clip / "gt" / "flow.npz").exists():
        sys.exit(f"{clip}: no gt/flow.npz (the exact flow between training frames)")
    flows = dict(np.load(clip / "gt" / "flow.npz"))
    dark = [float(x) for x in a.dark.split(",")]
    bright = [float(x) for x in a.bright.split(",") if x.strip()]
    report("ground truth", *pixel_values(clip / "gt" / "hdr", flows, a.every), dark, True, bright)
    for r in a.runs:
        d = Path(r) / "renders" / "train" / "hdr"
        if not d.is_dir():
            sys.exit(f"{r}: no renders/train/hdr (not a finished run)")
        report(r, *pixel_values(d, flows, a.every), dark, False, bright)


if __name__ == "__main__":
    main()
