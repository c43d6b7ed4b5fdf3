"""The highlights only exposure fusion recovers, scored on a run's training or test renders.

`highlight_stops` and `highlight_peak_ratio` (eval.metrics.scene_hdr) score the test frames in
metrics.json. The same scores over the training frames tell a highlight the run cannot fit from one
it cannot predict: a highlight missed on the training frames, whose own pixels measure it, is a fit
the model does not make; one kept there and missed on the test frames is one the test frame's
neighbours do not show. On the training frames the scores are also split by each frame's exposure:
at the shortest exposure the frame itself measures the highlight, at the longest it only shows it
saturated.

Per run and split:

- ``frames``: the split's frames; ``highlight_frames``: those with highlight pixels;
- ``highlight_pixels``: their number over the split;
- ``highlight_stops``: the mean over those frames of the mean |log2 render - log2 truth| (stops);
- ``highlight_peak_ratio``: the geometric mean over those frames of max(render) / max(truth) over
  the frame's highlight pixels;
- ``by_level`` (training frames only): {exposure time: {"frames", "stops", "peak_ratio"}}.

``max_code`` (default 254, every unclipped code, as metrics.json) counts only the pixels the
shortest exposure shows at that code or below: near clipping one code spans a wide range of HDR
values, so the peak ratio over every unclipped pixel is decided where 8 bits resolve it least.

`m4dgs-eval inspect highlights RUN [RUN ...] [--split train]` prints one row per run (docs/eval.md).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

from eval.experiments.run_files import read_render_exr, resolve_clip_dir
from eval.experiments.runner import read_failure
from eval.experiments.score_scene import true_response
from eval.metrics.scene_hdr import highlight_scores, peak_geomean
from m4dgs.clip import Clip, frame_name
from m4dgs.core.errors import InputError

SPLITS = ("train", "test")


def run_highlights(
    run_dir, clip: Optional[Clip] = None, split: str = "test", max_code: int = 254
) -> Dict:
    """The highlight scores (module docstring) of one run's HDR renders of `split` ("train" or
    "test": renders/<split>/hdr/<frame>.exr) against the clip's ground truth. clip: default the
    run's (run.json "clip"). max_code: count only pixels the shortest exposure shows at this code
    or below (254: every unclipped one, as metrics.json; eval.metrics.scene_hdr.highlight_mask).
    Raises InputError when the clip has no ground-truth HDR, no known true response or fewer than
    two observed exposures, or a frame's render is missing."""
    if split not in SPLITS:
        raise InputError(f"split {split!r}: expected one of {', '.join(SPLITS)}")
    if not 1 <= int(max_code) <= 254:
        raise InputError(f"max_code {max_code}: expected a code from 1 to 254")
    run_dir = Path(run_dir)
    clip = clip if clip is not None else Clip.open(resolve_clip_dir(run_dir))
    frames = list(clip.train_frames if split == "train" else clip.test_frames)
    crf = true_response(clip)
    obs = list(clip.meta.exposures.observed)
    if not frames or not (clip.has_gt and clip.has_gt_part("hdr")):
        raise InputError(f"{clip.root}: no ground-truth HDR {split} frames to score highlights on")
    if crf is None or len(obs) < 2:
        raise InputError(
            f"{clip.root}: highlights need the clip's true response and two observed exposures "
            f"(crf {clip.meta.crf!r}, {len(obs)} observed)"
        )
    paths = [run_dir / f"renders/{split}/hdr" / frame_name(g, "exr") for g in frames]
    for path in paths:
        if not path.exists():
            failed = read_failure(run_dir)
            if failed is not None:
                raise InputError(
                    f"{run_dir}: no {split} renders; its last attempt failed: {failed}"
                )
            raise InputError(f"{path}: missing; render the run first (`m4dgs render {run_dir}`)")
    stops, ratios, pixels = [], [], 0
    levels: Dict[float, Dict[str, list]] = {}
    for g, path in zip(frames, paths):  # one frame in memory at a time
        gt = clip.load_gt_hdr(g)
        h = highlight_scores(read_render_exr(path), gt, crf, max(obs), min(obs), max_code)
        if not h["highlight_pixels"]:
            continue
        pixels += h["highlight_pixels"]
        stops.append(h["highlight_stops"])
        ratios.append(h["highlight_peak_ratio"])
        if split == "train":
            lv = levels.setdefault(float(clip.meta.train_dt_of(g)), {"stops": [], "ratios": []})
            lv["stops"].append(h["highlight_stops"])
            lv["ratios"].append(h["highlight_peak_ratio"])
    return {
        "run": str(run_dir),
        "clip_name": clip.meta.name,
        "split": split,
        "max_code": int(max_code),
        "frames": len(frames),
        "highlight_frames": len(stops),
        "highlight_pixels": pixels,
        "highlight_stops": float(np.mean(stops)) if stops else math.nan,
        "highlight_peak_ratio": peak_geomean(ratios),
        "by_level": {
            dt: {
                "frames": len(v["stops"]),
                "stops": float(np.mean(v["stops"])),
                "peak_ratio": peak_geomean(v["ratios"]),
            }
            for dt, v in sorted(levels.items())
        },
    }


def _split_label(r: Dict) -> str:
    code = r.get("max_code", 254)
    return r["split"] if code == 254 else f"{r['split']}, codes <= {code}"


def format_highlights(results: List[Dict]) -> str:
    """A Markdown table of run_highlights results, one row per run."""
    lines = [
        "| run | clip | split | frames with highlights | pixels | error (stops) | peak ratio | "
        "peak ratio by exposure (frames) |",
        "|:---|:---|:---|---:|---:|---:|---:|:---|",
    ]
    for r in results:
        by = ", ".join(
            f"{dt:g}: {v['peak_ratio']:.3g} ({v['frames']})" for dt, v in r["by_level"].items()
        )
        lines.append(
            f"| {r['run']} | {r['clip_name']} | {_split_label(r)} | {r['highlight_frames']} of "
            f"{r['frames']} | {r['highlight_pixels']} | {r['highlight_stops']:.3f} | "
            f"{r['highlight_peak_ratio']:.3g} | {by or 'n/a'} |"
        )
    return "\n".join(lines) + "\n"
