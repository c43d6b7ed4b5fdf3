"""A clip in the layout of the official Mono4DGS-HDR code (m4dgs.formats.mono4dgs_hdr).

Written: the training frames (train/ and images/, the same bytes) with their log2 exposures, the
HDR ground truth of every frame (train_exr/, test_exr/), each test frame once at an observed level
(test/) and once at a novel level (test_ne/), the levels taken in turn over the test frames so
that every level is scored (real data: its own level, and test_ne/ only where an import kept one),
every test frame at every level of a synthetic clip (test_levels/<level>/), the clip's
depth prior (prior_depth/, the official code's dep_mode "prior") and track prior (the official
track file, pixel centres at integers as its loader indexes them), and the ground-truth cameras
(cameras_gt.json: not an input of the official code, which estimates its own)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from m4dgs.clip import Clip, frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.formats import CLIP_META_FILE, copy_file
from m4dgs.formats import mono4dgs_hdr as fmt


def test_levels(clip: Clip, j: int, g: int):
    """(observed level of test/, novel level of test_ne/ or None) of the j-th test frame g."""
    ex = clip.meta.exposures
    if ex.test_dt is not None:  # real data: the level it was captured at, and a novel-exposure
        # frame only where an import of this layout kept one (clip.json gt.test_ne)
        return ex.test_dt[j], (clip.meta.gt.get("test_ne") or {}).get(str(g))
    obs = ex.observed[j % len(ex.observed)]
    nov = ex.novel[j % len(ex.novel)] if ex.novel else None
    return obs, nov


def export(clip: Clip, out: Path) -> None:
    m = clip.meta
    has_hdr = clip.has_gt_part("hdr")
    train_dt, test_dt, test_ne_dt = {}, {}, {}
    for g in clip.train_frames:
        name = frame_name(g, "png")
        src = clip.path("input/ldr", name)
        copy_file(src, out / fmt.TRAIN_DIR / name)
        copy_file(src, out / fmt.IMAGES_DIR / name)
        train_dt[name] = m.train_dt_of(g)
        if has_hdr:
            copy_file(
                clip.path("gt/hdr", frame_name(g, "exr")), out / fmt.TRAIN_EXR_DIR / f"{g:05d}.exr"
            )
        dep = clip.load_depth_prior(g)
        mio.write_npz(out / fmt.PRIOR_DEPTH_DIR / f"{g:05d}.npz", dep=dep.astype(np.float32))
    for j, g in enumerate(clip.test_frames):
        name = frame_name(g, "png")
        obs, nov = test_levels(clip, j, g)
        copy_file(clip.path("gt/ldr", level_name(obs), name), out / fmt.TEST_DIR / name)
        test_dt[name] = obs
        if nov is not None:
            copy_file(clip.path("gt/ldr", level_name(nov), name), out / fmt.TEST_NE_DIR / name)
            test_ne_dt[name] = nov
        for level in m.test_levels_of(g) if m.exposures.test_dt is None else []:
            copy_file(
                clip.path("gt/ldr", level_name(level), name),
                out / fmt.TEST_LEVELS_DIR / level_name(level) / name,
            )
        if has_hdr:
            copy_file(
                clip.path("gt/hdr", frame_name(g, "exr")), out / fmt.TEST_EXR_DIR / f"{g:05d}.exr"
            )
    ts = clip.load_tracks_prior()
    mio.write_npz(
        out / fmt.PRIOR_TRACKS_FILE,
        tracks=(np.swapaxes(ts.tracks, 0, 1) - 0.5).astype(np.float32),
        visibility=np.swapaxes(ts.visible, 0, 1).astype(bool),
    )
    mio.write_json(
        out / fmt.EXPOSURES_FILE,
        fmt.exposures_json(train_dt, test_dt, test_ne_dt, len(m.exposures.observed)),
    )
    if clip.has_gt_part("cameras.json"):
        copy_file(clip.path("gt/cameras.json"), out / fmt.CAMERAS_GT_FILE)
    copy_file(clip.path("clip.json"), out / CLIP_META_FILE)
