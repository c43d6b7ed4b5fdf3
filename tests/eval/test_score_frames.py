"""`eval score-frames`: another method's frames scored without an m4dgs model. Predictions are made
from the clip's ground truth in every accepted file format, with metric values known in advance
(identical images: the PSNR cap; a one-code-value error everywhere: 20 log10 255 dB; the
ground-truth HDR sequence: the HDR-TAE floor benchgen recorded when it rendered the clip)."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
import tifffile
from click.testing import CliRunner

from eval.cli import main
from eval.experiments.frames import read_image, score_frames
from eval.experiments.score import PSNR_CAP_DB
from m4dgs.clip import Clip, frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError


def _png16(path, img8):
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), (img8.astype(np.uint16) * 257)[..., ::-1])


def make_pred(clip: Clip, root, train: bool = True):
    """A prediction folder from the ground truth: observed level 1 as 16-bit PNG, level 2 as float
    EXR, novel levels as 8-bit PNG with the lowest bit flipped (|error| = 1 code everywhere)."""
    ex = clip.meta.exposures
    obs, nov = list(ex.observed), list(ex.novel)
    for g in clip.test_frames:
        mio.write_exr(root / "test/hdr" / frame_name(g, "exr"), clip.load_gt_hdr(g))
        for i, lv in enumerate(obs):
            gt = clip.load_gt_ldr(lv, g)
            d = root / "test/ldr" / level_name(lv)
            if i == 0:
                _png16(d / frame_name(g, "png"), gt)
            else:
                mio.write_exr(d / frame_name(g, "exr"), gt.astype(np.float32) / 255.0)
        for lv in nov:
            mio.write_png(
                root / "test/ldr" / level_name(lv) / frame_name(g, "png"),
                clip.load_gt_ldr(lv, g) ^ 1,
            )
    if train:
        for g in clip.train_frames:
            mio.write_exr(root / "train/hdr" / frame_name(g, "exr"), clip.load_gt_hdr(g))
            p = root / "train/ldr" / frame_name(g, "tif")
            p.parent.mkdir(parents=True, exist_ok=True)
            tifffile.imwrite(p, clip.load_ldr(g))
    return root


def test_frames_from_the_ground_truth_score_the_known_values(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    pred = make_pred(clip, tmp_path / "pred")
    out = tmp_path / "runs" / "gt-copy"
    run_dir, m = score_frames(tiny_clip_realistic, pred, "gt-copy", out)
    assert (
        run_dir == out
        and json.loads((out / "metrics.json").read_text())["hdr_psnr"] == m["hdr_psnr"]
    )
    ex = clip.meta.exposures
    for lv in ex.observed:
        assert m["per_level"][level_name(lv)]["psnr"] == PSNR_CAP_DB
    one_code = 20 * math.log10(255.0)
    for lv in ex.novel:
        assert m["per_level"][level_name(lv)]["psnr"] == pytest.approx(one_code, abs=1e-6)
    assert m["ldr_oe_psnr"] == PSNR_CAP_DB and m["ldr_ne_psnr"] == pytest.approx(one_code, abs=1e-6)
    assert m["ldr_oe_ssim"] == pytest.approx(1.0) and m["ldr_train_psnr"] == PSNR_CAP_DB
    assert m["hdr_psnr"] == PSNR_CAP_DB and m["hdr_ssim"] == pytest.approx(1.0)
    assert m["hdr_train_psnr"] == PSNR_CAP_DB
    assert m["hdr_tae"] == pytest.approx(clip.meta.gt["hdr_tae_floor"], rel=1e-4)
    # the truth scored against itself: HDR-TAE is the clip's floor, HDR-TCE is zero
    assert m["hdr_tae"] > 0.01 and m["hdr_tce"] == pytest.approx(0.0, abs=1e-6)
    # nothing a model would give
    assert m["fps"] is None and m["crf_error"] is None and m["num_gaussians"] is None
    inp = m["options"]["input"]
    n_test = len(clip.test_frames)
    assert inp["ldr_uint16"] == n_test and inp["ldr_float"] == n_test * (len(ex.observed) - 1)
    assert inp["ldr_uint8"] == n_test * len(ex.novel) + len(clip.train_frames)
    assert inp["hdr_negative"] == 0 and m["run"]["external"] is True

    # the score folder joins `eval table RUNS_DIR` under its name
    res = CliRunner().invoke(
        main, ["table", "--columns", "all", str(tmp_path / "runs"), "--format", "csv"]
    )
    assert res.exit_code == 0, res.output
    assert "gt-copy" in res.output


def test_test_frames_alone_score_without_training_metrics(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    pred = make_pred(clip, tmp_path / "pred", train=False)
    _, m = score_frames(tiny_clip_realistic, pred, "test-only", tmp_path / "s")
    assert m["hdr_psnr"] == PSNR_CAP_DB
    assert m["hdr_tae"] is None and m["ldr_train_psnr"] is None and m["hdr_train_psnr"] is None


def test_missing_frames_are_listed_in_one_error(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    pred = make_pred(clip, tmp_path / "pred")
    g0, g1 = clip.test_frames[:2]
    lv = level_name(clip.meta.exposures.novel[0])
    gone = [
        pred / "test/hdr" / frame_name(g0, "exr"),
        pred / "test/ldr" / lv / frame_name(g0, "png"),
        pred / "test/ldr" / lv / frame_name(g1, "png"),
        pred / "train/hdr" / frame_name(clip.train_frames[3], "exr"),  # optional set given in part
    ]
    for p in gone:
        p.unlink()
    with pytest.raises(InputError, match=r"4 file\(s\) missing") as e:
        score_frames(tiny_clip_realistic, pred, "broken", tmp_path / "s")
    for p in gone:
        assert str(p.with_suffix("")) in str(e.value)
    assert not (tmp_path / "s" / "metrics.json").exists()


def test_bad_inputs_name_the_file(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    pred = make_pred(clip, tmp_path / "pred", train=False)
    g = clip.test_frames[0]
    p = pred / "test/hdr" / frame_name(g, "exr")
    mio.write_exr(p, np.zeros((clip.height + 1, clip.width, 3), np.float32))
    with pytest.raises(InputError, match=f"{p}.*pixels"):
        score_frames(tiny_clip_realistic, pred, "bad-size", tmp_path / "a")
    x = clip.load_gt_hdr(g).copy()
    x[0, 0, 0] = np.nan
    mio.write_exr(p, x)
    with pytest.raises(InputError, match=f"{p}: NaN"):
        score_frames(tiny_clip_realistic, pred, "nan", tmp_path / "b")
    with pytest.raises(InputError, match="--name"):
        score_frames(tiny_clip_realistic, pred, "a/b", tmp_path / "c")


def test_read_image_keeps_16_bit_and_channel_names(tmp_path):
    rng = np.random.default_rng(0)
    a = rng.integers(0, 65536, (5, 7, 3), dtype=np.uint16)
    cv2.imwrite(str(tmp_path / "a.png"), a[..., ::-1])
    px, kind = read_image(tmp_path / "a.png")
    assert kind == "uint16" and px.dtype == np.uint16 and np.array_equal(px, a)
    grey = rng.integers(0, 256, (5, 7), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "g.png"), grey)
    px, kind = read_image(tmp_path / "g.png")
    assert kind == "uint8" and np.array_equal(px, np.repeat(grey[..., None], 3, -1))


def test_cli_score_frames_and_force(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    pred = make_pred(clip, tmp_path / "pred", train=False)
    args = ["score-frames", "--clip", str(tiny_clip_realistic), "--pred", str(pred)]
    args += ["--name", "mine", "--out", str(tmp_path / "s")]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert json.loads(r.output.strip().splitlines()[-1])["hdr_psnr"] == PSNR_CAP_DB
    r = CliRunner().invoke(main, args)
    assert r.exit_code != 0 and "--force" in r.output
    r = CliRunner().invoke(main, args + ["--force"])
    assert r.exit_code == 0, r.output
