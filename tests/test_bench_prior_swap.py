"""bench/prior_swap_bench.py: clips assembled from two clips of one render take each prior family
from the clip asked for, the trainer's camera initialisation runs on them, the scores are right
on an analytic case, and clips of different renders are refused."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch


def test_combinations_and_names(load_bench):
    b = load_bench("prior_swap_bench")
    single = b.combinations("single")
    assert single == [(), ("depth",), ("tracks",), ("flow",), ("depth", "tracks", "flow")]
    every = b.combinations("all")
    assert len(every) == 8 and len(set(every)) == 8 and every[0] == () and every[-1] == b.FAMILIES
    assert [b.combo_name(c) for c in single] == [
        "base",
        "other-depth",
        "other-tracks",
        "other-flow",
        "other",
    ]
    assert b.combo_name(("depth", "flow")) == "other-depth+flow"
    assert b.combo_name(("depth",), "harsh") == "harsh-depth"
    assert b.combo_name(b.FAMILIES, "harsh") == "harsh" and b.combo_name((), "harsh") == "base"
    assert b.combinations("depth") == [(), ("depth",)]
    assert b.combinations("flow+depth") == [(), ("depth", "flow")]
    for bad in ("some", "depth+some", ""):
        with pytest.raises(ValueError, match="single, all"):
            b.combinations(bad)


def test_assembled_clip_takes_each_family_from_the_clip_asked_for(
    tiny_clip_realistic, tiny_clip_oracle, tmp_path, load_bench
):
    from m4dgs.clip import Clip

    b = load_bench("prior_swap_bench")
    base, other = Path(tiny_clip_realistic), Path(tiny_clip_oracle)
    out = b.assemble_clip(base, other, ("depth",), tmp_path / "c")
    assert (out / "priors" / "depth").resolve() == (other / "priors" / "depth").resolve()
    assert (out / "priors" / "tracks.npz").resolve() == (base / "priors" / "tracks.npz").resolve()
    assert (out / "input").resolve() == (base / "input").resolve()
    meta = json.loads((out / "clip.json").read_text())["priors"]
    assert meta["families"] == {"depth": "oracle", "tracks": "realistic", "flow": "realistic"}
    clip, o = Clip.open(out), Clip.open(other)
    g = clip.train_frames[1]
    np.testing.assert_array_equal(clip.load_depth_prior(g), o.load_depth_prior(g))
    assert not np.array_equal(clip.load_depth_prior(g), Clip.open(base).load_depth_prior(g))
    np.testing.assert_array_equal(
        clip.load_tracks_prior().tracks, Clip.open(base).load_tracks_prior().tracks
    )
    # assembling again (a resumed bench) keeps the links
    b.assemble_clip(base, other, ("depth",), tmp_path / "c")
    assert (out / "priors" / "depth").resolve() == (other / "priors" / "depth").resolve()


def test_clips_of_another_render_are_refused(tiny_clip_realistic, tmp_path, load_bench):
    b = load_bench("prior_swap_bench")
    other = tmp_path / "other" / "tiny-flag-arm"
    shutil.copytree(tiny_clip_realistic, other, symlinks=True)
    meta = json.loads((other / "clip.json").read_text())
    meta["gt"]["render_key"] = "0" * 16
    (other / "clip.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="different renders"):
        b.assemble_clip(tiny_clip_realistic, other, ("flow",), tmp_path / "c")
    # taking nothing from the other clip needs no common render
    b.assemble_clip(tiny_clip_realistic, other, (), tmp_path / "c")


def test_scores_of_the_true_cameras(tiny_clip_realistic, tmp_path, load_bench):
    """The ground-truth cameras and masks as a camera initialisation: zero focal error, ATE and
    RPE, IoU 1."""
    from m4dgs.clip import Clip
    from m4dgs.run import save_torch

    b = load_bench("prior_swap_bench")
    clip = Clip.open(tiny_clip_realistic)
    cams = clip.load_gt_cameras()
    sel = [cams.frames.tolist().index(g) for g in clip.train_frames]
    masks = np.stack([clip.load_gt_dynamic_mask(g) for g in clip.train_frames])
    run = tmp_path / "run"
    (run / "model").mkdir(parents=True)
    save_torch(
        run / "model" / "camera_init.pt",
        {
            "K": torch.as_tensor(cams.K[sel[0]]),
            "c2w": torch.as_tensor(cams.c2w[sel]),
            "masks": torch.as_tensor(masks),
        },
    )
    s = b.score_camera_init(tiny_clip_realistic, run)
    assert s["focal_err_pct"] == pytest.approx(0, abs=1e-9)
    assert s["ate"] == pytest.approx(0, abs=1e-6)
    assert s["rpe_trans"] == pytest.approx(0, abs=1e-6)
    assert s["rpe_rot_deg"] == pytest.approx(0, abs=1e-4)
    assert s["mask_iou"] == 1.0
    # one frame's camera moved by 0.1 along x: the RPE sees it
    c2w = cams.c2w[sel].copy()
    c2w[2, 0, 3] += 0.1
    save_torch(
        run / "model" / "camera_init.pt",
        {
            "K": torch.as_tensor(cams.K[sel[0]]),
            "c2w": torch.as_tensor(c2w),
            "masks": torch.as_tensor(masks),
        },
    )
    assert b.score_camera_init(tiny_clip_realistic, run)["rpe_trans"] > 0.01


def test_main_runs_the_trainers_camera_init(
    tiny_clip_realistic, tiny_clip_oracle, tmp_path, load_bench
):
    """The whole bench on one tiny scene: the base combination's camera initialisation is the one
    `Trainer.run_phase` computes on the realistic clip itself (bit for bit), and a resumed bench
    recomputes nothing."""
    from m4dgs.run import load_torch
    from m4dgs.training.pipeline import Trainer

    b = load_bench("prior_swap_bench")
    scene = Path(tiny_clip_realistic).name
    args = [
        "--base",
        str(Path(tiny_clip_realistic).parent),
        "--other",
        str(Path(tiny_clip_oracle).parent),
        "--scenes",
        scene,
        "--out",
        str(tmp_path / "out"),
        "--preset",
        "tiny",
        "--quiet",
        "--json",
        str(tmp_path / "rows.json"),
    ]
    assert b.main(args) == 0
    rows = json.loads((tmp_path / "rows.json").read_text())["rows"]
    assert [r["combo"] for r in rows] == [
        "base",
        "other-depth",
        "other-tracks",
        "other-flow",
        "other",
    ]
    direct = tmp_path / "direct"
    Trainer(tiny_clip_realistic, direct, "tiny", "full", device="cpu", progress=False).run_phase(
        "camera_init"
    )
    a = load_torch(tmp_path / "out" / "runs" / scene / "base" / "model" / "camera_init.pt")
    d = load_torch(direct / "model" / "camera_init.pt")
    assert torch.equal(a["c2w"], d["c2w"]) and torch.equal(a["masks"], d["masks"])
    stamp = os.path.getmtime(
        tmp_path / "out" / "runs" / scene / "other" / "model" / "camera_init.pt"
    )
    assert b.main(args) == 0
    assert (
        os.path.getmtime(tmp_path / "out" / "runs" / scene / "other" / "model" / "camera_init.pt")
        == stamp
    )
    assert json.loads((tmp_path / "rows.json").read_text())["rows"] == rows
