"""Render a trained run's frames to disk (the files `eval score` reads), resumable and atomic.

renders/train/hdr/<g>.exr   renders/train/ldr/<g>.png (at the frame's input exposure)
renders/train/depth/<g>.exr renders/test/hdr/<g>.exr    renders/test/ldr/<level>/<g>.png (every
observed + novel level)  renders/test/depth/<g>.exr
renders/views/<view>/...    the clip's held-out views, when it has them (m4dgs.outputs.views)"""

from __future__ import annotations

import math
from typing import Dict

import numpy as np
import torch

from m4dgs.clip import frame_name, level_name
from m4dgs.core.io import write_exr, write_png
from m4dgs.core.lock import FolderLock
from m4dgs.core.progress import progress_bar
from m4dgs.model.trained import load_model
from m4dgs.outputs.views import render_views
from m4dgs.run import RunDir


@torch.no_grad()
def render_run(
    run_dir, overwrite: bool = False, progress: bool = True, device: str = "cpu"
) -> Dict[str, int]:
    """Write every train/test render that is missing (or all with overwrite), and the clip's
    held-out views (m4dgs.outputs.views); returns counts of frames written ("train", "test",
    "views"). Holds the run folder's lock (a no-op inside the trainer, which holds it)."""
    with FolderLock(run_dir):
        return _render_run(run_dir, overwrite, progress, device)


def _render_run(run_dir, overwrite: bool, progress: bool, device: str) -> Dict[str, int]:
    run = RunDir(run_dir)
    model = load_model(run_dir, device=device)
    clip = model.clip
    levels = list(clip.meta.exposures.observed) + list(clip.meta.exposures.novel)
    # training frames are rendered at the exposure written on the input (not a perturbed one)
    dt_of = dict(zip(clip.train_frames, np.log2(clip.train_dt).tolist()))
    jobs = [("train", g) for g in clip.train_frames] + [("test", g) for g in clip.test_frames]
    it = jobs
    if progress:
        it = progress_bar(jobs, desc="render", unit="frame")
    written = {"train": 0, "test": 0}
    for split, g in it:
        hdr_p = run.path("renders", split, "hdr", frame_name(g, "exr"))
        dep_p = run.path("renders", split, "depth", frame_name(g, "exr"))
        if split == "train":
            ldr_ps = {dt_of[g]: run.path("renders", "train", "ldr", frame_name(g, "png"))}
        else:
            ldr_ps = {
                math.log2(lv): run.path(
                    "renders", "test", "ldr", level_name(lv), frame_name(g, "png")
                )
                for lv in levels
            }
        todo = (
            overwrite
            or not hdr_p.exists()
            or not dep_p.exists()
            or any(not p.exists() for p in ldr_ps.values())
        )
        if not todo:
            continue
        r = model.render_frame(g)
        write_exr(hdr_p, r["hdr"].cpu().numpy())
        write_exr(dep_p, r["depth"].cpu().numpy())
        for l2, p in ldr_ps.items():
            ldr = model.tm(r["hdr"], _t(l2, r["hdr"])).clamp(0, 1)
            write_png(p, ldr.cpu().numpy())
        written[split] += 1
    written["views"] = render_views(model, run, overwrite, progress_bar if progress else None)[0]
    return written


def _t(v: float, like):
    return torch.tensor(float(v), dtype=like.dtype, device=like.device)
