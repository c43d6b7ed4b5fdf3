"""The largest HDR values of a run's test renders against the ground truth's: runaway highlights.

The colour of a Gaussian is 2^(MLP output) with no upper bound (the authors' choice), and past the
tone curve's shoulder at every exposure the photometric loss has no gradient left to pull a value
back; a regulariser that keeps pushing (TLR at the paper's weight 0.1, lab/results-notes.md) can
then drive the brightest values up without limit. The headline HDR PSNR does not see that (mu-law
on values normalised by the ground truth's maximum and clipped at 1; docs/metrics.md). This
measures it directly, per run, over the test frames:

- ``gt_max``: the largest ground-truth HDR value (any channel) over the test frames;
- ``render_max``: the same for the run's HDR renders (``inf`` when a render holds an infinite value;
  NaN values are left out and counted);
- ``ratio``: render_max / gt_max (about 1 for a faithful run; 1e4 is a runaway);
- ``share_above``: the fraction of rendered values (pixels x channels) above gt_max;
- ``nonfinite``: how many rendered values are NaN or infinite.

`m4dgs-eval peaks RUN [RUN ...]` prints one line per run (docs/eval.md).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

from eval.experiments.run_files import resolve_clip_dir
from eval.experiments.runner import read_failure
from m4dgs.clip import Clip, frame_name
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError


def run_peaks(run_dir, clip: Optional[Clip] = None) -> Dict:
    """{"run", "clip_name", "frames", "gt_max", "render_max", "ratio", "share_above",
    "nonfinite"} of one run's test-frame HDR renders (renders/test/hdr/<frame>.exr) against the
    clip's ground truth (gt/hdr). clip: default the run's (run.json "clip"). Raises InputError
    when the clip has no ground-truth HDR or test frames, or a test frame's render is missing."""
    run_dir = Path(run_dir)
    clip = clip if clip is not None else Clip.open(resolve_clip_dir(run_dir))
    frames = list(clip.test_frames)
    if not frames or not (clip.has_gt and clip.has_gt_part("hdr")):
        raise InputError(f"{clip.root}: no ground-truth HDR test frames to compare the peaks with")
    paths = [run_dir / "renders/test/hdr" / frame_name(g, "exr") for g in frames]
    for path in paths:
        if not path.exists():
            failed = read_failure(run_dir)
            if failed is not None:  # a diverged run has no model to render
                raise InputError(f"{run_dir}: no test renders; its last attempt failed: {failed}")
            raise InputError(f"{path}: missing; render the run first (`m4dgs render {run_dir}`)")
    # the maximum over every test frame first, then one render in memory at a time
    gt_max = max(float(np.max(clip.load_gt_hdr(g))) for g in frames)
    render_max, above, total, bad = -math.inf, 0, 0, 0
    for path in paths:
        h = mio.read_exr(path)
        nan = np.isnan(h)
        bad += int(nan.sum() + np.isinf(h).sum())
        if not nan.all():
            render_max = max(render_max, float(np.max(h[~nan])))
        above += int((h > gt_max).sum())
        total += h.size
    return {
        "run": str(run_dir),
        "clip_name": clip.meta.name,
        "frames": len(frames),
        "gt_max": gt_max,
        "render_max": render_max,
        "ratio": render_max / gt_max if gt_max > 0 else math.nan,
        "share_above": above / total if total else math.nan,
        "nonfinite": bad,
    }


def format_peaks(results: List[Dict]) -> str:
    """A Markdown table of run_peaks results, one row per run."""
    lines = [
        "| run | clip | test frames | GT max | render max | render max / GT max | values above "
        "GT max | NaN or inf |",
        "|:---|:---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        lines.append(
            f"| {r['run']} | {r['clip_name']} | {r['frames']} | {r['gt_max']:.4g} | "
            f"{r['render_max']:.4g} | {r['ratio']:.3g} | {100.0 * r['share_above']:.2f} % | "
            f"{r['nonfinite']} |"
        )
    return "\n".join(lines) + "\n"
