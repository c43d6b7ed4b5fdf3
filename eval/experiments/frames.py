"""Score another method's frames: `m4dgs-eval score-frames --clip CLIP --pred DIR --name NAME`.

Any method that renders frames can be scored against a benchgen clip with every metric an m4dgs
run gets from its frames; no m4dgs model is needed. The prediction folder (docs/eval.md, "Scoring
another method's frames"):

    DIR/test/hdr/<g>.exr                HDR of every test frame (required where the clip has
                                        ground-truth HDR), linear, in the clip's
                                        radiance units: LDR = CRF(HDR x dt) with clip.json's
                                        exposure times (.exr, .hdr or float .tif/.tiff)
    DIR/test/ldr/<level>/<g>.<ext>      LDR of every test frame at every observed and novel level
                                        of clip.json (required; real footage with held-out test
                                        frames: at the level each was captured at, clip.json
                                        exposures.test_dt); <level> as the clip names it
                                        (m4dgs.clip.level_name: 0.125, 0.5, 2, 8, 32); .png (8 or
                                        16 bit), .exr or .tif/.tiff (8, 16 bit or float in [0, 1])
    DIR/train/hdr/<g>.exr               optional: HDR of every training frame (hdr_train_*,
                                        HDR-TAE, HDR T-std)
    DIR/train/ldr/<g>.<ext>             optional: LDR of every training frame at its input
                                        exposure (ldr_train_*)
    DIR/test/depth/<g>.exr              optional: z-depth of every test frame (depth AbsRel)
    DIR/cameras.json                    optional: estimated cameras in the m4dgs format (ATE, RPE)

<g> is the global frame index, zero-padded to 5 digits (00007.exr). Every missing required file is
listed in one error. Images are read through OpenImageIO: RGB or RGBA by channel name (R, G, B,
else the first three channels; one channel is grey), any bit depth. LDR predictions with more than
8 bits are rounded to 8 bits (round(255 x)), the precision m4dgs renders are scored at; the number
of files of each kind is recorded in metrics.json ("options" -> "input"). HDR values must be
finite; negative values are set to 0 and counted.

The frames are copied into the m4dgs render layout of a score folder (default runs/<clip>/<NAME>)
with a run.json naming NAME as the variant, and scored by eval.score.score_run without a model:
model-only metrics (tracks, learned CRF, render FPS, #Gaussians) are None.
`m4dgs-eval table RUNS_DIR` then shows NAME as a row beside the m4dgs runs under RUNS_DIR."""

from __future__ import annotations

import os
import re
import shutil
from collections import Counter
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

from m4dgs.clip import Cameras, Clip, frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError
from m4dgs.core.io import ldr_to_8bit, read_image

LDR_EXTS = ("png", "exr", "tif", "tiff")
HDR_EXTS = ("exr", "hdr", "tif", "tiff")
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]*$")
MAX_LISTED = 20


# --------------------------------------------------------------------------------------------------
# the prediction folder
# --------------------------------------------------------------------------------------------------
def _find(folder: Path, g: int, exts) -> Tuple[Optional[Path], List[Path]]:
    """(the file of frame g under folder, every candidate found)."""
    found = [folder / frame_name(g, e) for e in exts if (folder / frame_name(g, e)).is_file()]
    return (found[0] if len(found) == 1 else None), found


def plan_inputs(clip: Clip, pred: Path) -> Dict[str, List[Tuple[Path, str]]]:
    """{group: [(source file, render path relative to renders/)]} of a prediction folder; raises
    one InputError listing every missing required file (and every frame given in two formats)."""
    pred = Path(pred)
    if not pred.is_dir():
        raise InputError(f"{pred}: the prediction folder does not exist")
    ex = clip.meta.exposures
    test, train = clip.test_frames, clip.train_frames
    if not test:
        raise InputError(f"{clip.root}/clip.json: the clip has no test frames to score")
    # a clip without ground-truth HDR (real footage with held-out test frames) scores LDR only,
    # each test frame at the level its ground truth has (Clip.meta.test_levels_of)
    hdr_gt = clip.has_gt_part("hdr")
    groups: Dict[str, Tuple[Path, List[int], tuple, str, bool]] = {
        "test/hdr": (pred / "test/hdr", test, HDR_EXTS, "exr", hdr_gt),
    }
    for lv in list(ex.observed) + list(ex.novel):
        frames_lv = [g for g in test if lv in clip.meta.test_levels_of(g)]
        if frames_lv:
            sub = f"test/ldr/{level_name(lv)}"
            groups[sub] = (pred / sub, frames_lv, LDR_EXTS, "png", True)
    groups["train/hdr"] = (pred / "train/hdr", train, HDR_EXTS, "exr", False)
    groups["train/ldr"] = (pred / "train/ldr", train, LDR_EXTS, "png", False)
    groups["test/depth"] = (pred / "test/depth", test, ("exr",), "exr", False)
    missing, ambiguous = [], []
    plan: Dict[str, List[Tuple[Path, str]]] = {}
    for sub, (folder, frames, exts, out_ext, required) in groups.items():
        if not required and not folder.is_dir():
            continue
        files, miss = [], []
        for g in frames:
            f, cands = _find(folder, g, exts)
            if len(cands) > 1:
                ambiguous.append(", ".join(str(c) for c in cands))
            elif f is None:
                miss.append(folder / frame_name(g, f"{{{','.join(exts)}}}"))
            else:
                files.append((f, f"{sub}/{frame_name(g, out_ext)}"))
        if miss and (required or files):  # an optional group given in part is an error too
            missing += miss
        elif not miss:
            plan[sub] = files
    if missing or ambiguous:
        lines = [str(m) for m in missing[:MAX_LISTED]]
        more = f"\n  ... and {len(missing) - MAX_LISTED} more" if len(missing) > MAX_LISTED else ""
        msg = f"{pred}: the prediction folder is incomplete for clip {clip.root}"
        if missing:
            msg += f"; {len(missing)} file(s) missing:\n  " + "\n  ".join(lines) + more
        if ambiguous:
            msg += "\nframes given in more than one format (keep one): " + "; ".join(ambiguous)
        msg += "\n(layout: docs/eval.md, 'Scoring another method's frames')"
        raise InputError(msg)
    return plan


def import_frames(clip: Clip, pred: Path, run_dir: Path, name: str) -> dict:
    """Copy a prediction folder into the render layout of `run_dir` (LDR as 8-bit PNG, HDR and depth
    as float32 EXR), write run.json; returns the input report {kind: count, "hdr_negative": n}."""
    plan = plan_inputs(clip, pred)
    renders = Path(run_dir) / "renders"
    counts: Counter = Counter()
    negative = 0
    H, W = clip.height, clip.width
    for sub, files in plan.items():
        for src, rel in files:
            px, kind = read_image(src)
            if px.shape[:2] != (H, W):
                raise InputError(
                    f"{src}: {px.shape[1]}x{px.shape[0]} pixels, the clip is {W}x{H} (clip.json)"
                )
            if sub.endswith("/ldr") or "/ldr/" in sub:
                counts[f"ldr_{kind}"] += 1
                mio.write_png(renders / rel, ldr_to_8bit(px, kind, src))
                continue
            if kind != "float":
                raise InputError(f"{src}: an integer ({kind}) image where linear HDR is expected")
            x = px.astype(np.float32)
            if not np.isfinite(x).all():
                raise InputError(f"{src}: NaN or infinite values")
            if sub == "test/depth":
                mio.write_exr(renders / rel, x[..., 0])
                continue
            negative += int((x < 0).sum())
            mio.write_exr(renders / rel, np.maximum(x, 0.0))
            counts["hdr"] += 1
    cams = Path(pred) / "cameras.json"
    if cams.is_file():
        Cameras.from_json(mio.read_json(cams), cams)  # a readable file, or an error naming it
        shutil.copyfile(cams, Path(run_dir) / "cameras.json")
    mio.write_json(
        Path(run_dir) / "run.json",
        {
            "clip": os.path.relpath(clip.root.resolve(), Path(run_dir).resolve()),
            "clip_abs": str(clip.root.resolve()),
            "variant": name,
            "method": "external",
            "preset": None,
            "external": {"name": name, "pred": str(Path(pred).resolve())},
        },
    )
    return {
        **dict(sorted(counts.items())),
        "hdr_negative": negative,
        "given": sorted(plan),
        "cameras": cams.is_file(),
    }


def score_frames(
    clip_dir,
    pred,
    name: str,
    out=None,
    *,
    force: bool = False,
    lpips_weights=None,
    roundtrip=None,
    flip: bool = False,
    tae_train_test: bool = False,
) -> Tuple[Path, dict]:
    """Import a prediction folder (import_frames) into `out` (default runs/<clip name>/<name>) and
    score it (eval.score.score_run, no model); returns (score folder, metrics)."""
    from eval.experiments.score import score_run  # deferred: loads torch and the metrics

    if not NAME_RE.match(name or ""):
        raise InputError(
            f"--name {name!r}: use letters, digits and . _ + - "
            "(it becomes a folder and a table row)"
        )
    clip = Clip.open(clip_dir)
    run_dir = Path(out) if out is not None else Path("runs") / clip.meta.name / name
    info = run_dir / "run.json"
    if info.exists():
        meta = mio.read_json(info)
        if not meta.get("external"):
            raise InputError(
                f"{run_dir}: an m4dgs run folder; score external frames into another --out"
            )
        if not force:
            raise InputError(f"{run_dir}: already scored (metrics.json); use --force to redo it")
    if run_dir.exists() and force:
        for sub in ("renders", "metrics.json", "cameras.json", "run.json"):
            p = run_dir / sub
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()
    report = import_frames(clip, Path(pred), run_dir, name)
    m = score_run(
        run_dir,
        clip=clip,
        lpips_weights=lpips_weights,
        roundtrip=roundtrip,
        flip=flip,
        fps=False,
        tae_train_test=tae_train_test,
        model=False,
        render_missing=False,
        write=False,
    )
    m["options"]["model"] = "none (external frames)"
    m["options"]["input"] = report
    m["run"]["external"] = True
    mio.write_json(run_dir / "metrics.json", m)
    return run_dir, m
