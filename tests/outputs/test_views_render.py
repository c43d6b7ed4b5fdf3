"""A trained run rendered at its clip's held-out views: the similarity that carries the views'
cameras into the run's frame (checked on known transforms, and the identity for a run whose
cameras are the truth), and the files a short training leaves."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from m4dgs.clip import Clip
from m4dgs.core.io import read_exr, read_json
from m4dgs.outputs.views import align_to_truth, alignment_of, truth_to_run


def _cams(n=6, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        q *= np.sign(np.linalg.det(q))
        c = np.eye(4)
        c[:3, :3], c[:3, 3] = q, rng.normal(size=3) * 2
        out.append(c)
    return np.stack(out)


def test_alignment_recovers_a_known_similarity_and_inverts_it():
    gt = _cams()
    a = np.radians(30)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    s, t = 0.4, np.array([1.0, -2.0, 0.5])
    run = np.stack([truth_to_run(c, s, R, t) for c in gt])  # the truth seen in a run's frame
    al = align_to_truth(run, gt)
    assert al["s"] == pytest.approx(s) and al["rmse"] < 1e-9
    np.testing.assert_allclose(al["R"], R, atol=1e-9)
    np.testing.assert_allclose(al["t"], t, atol=1e-9)
    # and back: a run camera mapped to the truth's frame is the true camera
    for c_run, c_gt in zip(run, gt):
        back = np.eye(4)
        back[:3, :3] = R @ c_run[:3, :3]
        back[:3, 3] = s * R @ c_run[:3, 3] + t
        np.testing.assert_allclose(back, c_gt, atol=1e-9)


def test_a_run_whose_cameras_are_the_truth_is_aligned_by_the_identity(tiny_clip_oracle):
    clip = Clip.open(tiny_clip_oracle)
    gt = clip.load_gt_cameras()
    idx = [list(gt.frames).index(g) for g in clip.train_frames]
    model = SimpleNamespace(
        clip=clip, frames=clip.train_frames, c2w_train=torch.tensor(gt.c2w[idx])
    )
    al = alignment_of(model)
    assert al["s"] == pytest.approx(1.0, abs=1e-9) and al["rmse"] < 1e-9
    np.testing.assert_allclose(al["R"], np.eye(3), atol=1e-9)
    np.testing.assert_allclose(al["t"], 0.0, atol=1e-9)
    v = clip.load_view_cameras("large").c2w[0]
    np.testing.assert_allclose(truth_to_run(v, al["s"], al["R"], al["t"]), v, atol=1e-9)


def test_training_renders_the_held_out_views(tiny_clip_oracle, tmp_path, short_training):
    from m4dgs.training.pipeline import train

    run = train(
        tiny_clip_oracle, tmp_path / "run", preset="tiny", overrides=short_training, progress=False
    )
    clip = Clip.open(tiny_clip_oracle)
    al = read_json(run / "renders" / "views" / "alignment.json")
    assert al["n"] == len(clip.train_frames) and al["s"] > 0
    levels = list(clip.meta.exposures.observed) + list(clip.meta.exposures.novel)
    for v in clip.view_names():
        for g in clip.test_frames:
            base = run / "renders" / "views" / v
            hdr = read_exr(base / "hdr" / f"{g:05d}.exr")
            assert hdr.shape == (clip.height, clip.width, 3) and np.isfinite(hdr).all()
            assert np.isfinite(read_exr(base / "depth" / f"{g:05d}.exr")).all()
            for lv in levels:
                assert (base / "ldr" / f"{float(lv):g}" / f"{g:05d}.png").exists()
