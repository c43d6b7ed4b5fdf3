"""A run folder as the scorer reads it: run.json, the clip it was trained on, the render files
scoring needs (m4dgs.outputs.render layout; rendered through m4dgs when missing) and a checked
read of a rendered EXR. Free of torch: the commands that inspect runs (regions, error maps,
peaks, responses) read runs through it without loading the scorer (eval.experiments.score)."""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List

import numpy as np

from m4dgs.clip import Clip, frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.core.errors import NonFiniteError


def read_render_exr(path) -> np.ndarray:
    """A rendered EXR (HDR or depth) of the run, refused when it holds NaN or infinite values: a
    mean over the finite frames would score a broken model as if it were fine."""
    a = mio.read_exr(path)
    bad = int(a.size - np.isfinite(a).sum())
    if bad:
        raise NonFiniteError(
            f"{path}: {bad} of {a.size} values are NaN or infinite; the run's model is broken "
            "(retrain it) or the render is damaged (delete renders/ and score again)"
        )
    return a


def read_run_info(run_dir) -> dict:
    p = Path(run_dir) / "run.json"
    return mio.read_json(p) if p.exists() else {}


def resolve_clip_dir(run_dir, clip=None) -> Path:
    """The run's clip folder: `clip` if given, else run.json "clip" (absolute, relative to the run,
    or to the cwd)."""
    if clip is not None:
        return Path(clip)
    info = read_run_info(run_dir)
    if "clip" not in info:
        raise FileNotFoundError(
            f"{Path(run_dir) / 'run.json'}: no 'clip' entry; pass the clip folder explicitly"
        )
    p = Path(info["clip"])
    if p.is_absolute():
        return p
    for cand in (Path(run_dir) / p, Path(info.get("clip_abs", p)), Path.cwd() / p):
        if (cand / "clip.json").exists():
            return cand
    return Path(run_dir) / p


def render_paths(run_dir, clip: Clip) -> Dict[str, List[Path]]:
    """The render files scoring needs (m4dgs.outputs.render layout), grouped: the training and test
    frames, and for a clip with held-out views renders/views/<view>/{hdr,ldr/<level>}/<g> of every
    test frame (m4dgs.outputs.views)."""
    r = Path(run_dir) / "renders"
    ex = clip.meta.exposures
    out = {
        "train_hdr": [r / "train/hdr" / frame_name(g, "exr") for g in clip.train_frames],
        "train_ldr": [r / "train/ldr" / frame_name(g, "png") for g in clip.train_frames],
    }
    if clip.test_frames:
        out["test_hdr"] = [r / "test/hdr" / frame_name(g, "exr") for g in clip.test_frames]
        for lv in list(ex.observed) + list(ex.novel):
            out[f"test_ldr_{level_name(lv)}"] = [
                r / "test/ldr" / level_name(lv) / frame_name(g, "png") for g in clip.test_frames
            ]
    for v in clip.view_names() if clip.test_frames else []:
        base = r / "views" / v
        out[f"views_{v}_hdr"] = [base / "hdr" / frame_name(g, "exr") for g in clip.test_frames]
        for lv in list(ex.observed) + list(ex.novel):
            out[f"views_{v}_ldr_{level_name(lv)}"] = [
                base / "ldr" / level_name(lv) / frame_name(g, "png") for g in clip.test_frames
            ]
    return out


def has_test_renders(run_dir, clip: Clip) -> bool:
    """Whether the run folder holds any render of a test frame (renders/test/)."""
    groups = render_paths(run_dir, clip)
    return any(p.exists() for k, ps in groups.items() if k.startswith("test_") for p in ps)


def has_view_renders(run_dir) -> bool:
    """Whether the run folder holds a renders/views/ folder (held-out views)."""
    return (Path(run_dir) / "renders" / "views").is_dir()


def missing_renders(run_dir, clip: Clip) -> List[Path]:
    return [p for ps in render_paths(run_dir, clip).values() for p in ps if not p.exists()]


def ensure_renders(run_dir, clip: Clip, progress: bool = False, device: str = "cpu") -> bool:
    """Render what is missing through m4dgs.outputs.render.render_run; returns True when it had to
    render."""
    if not missing_renders(run_dir, clip):
        return False
    # the trainer's entry points are imported when called (tests replace them in sys.modules)
    from m4dgs.outputs.render import render_run

    render_run(
        run_dir,
        overwrite=False,
        progress=progress,
        **({"device": device} if device != "cpu" else {}),
    )
    still = missing_renders(run_dir, clip)
    if still:
        raise FileNotFoundError(
            f"{run_dir}: render_run left {len(still)} render(s) missing, e.g. {still[0]}"
        )
    return True
