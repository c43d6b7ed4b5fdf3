"""Scores at the held-out views, against numpy by hand: a prediction equal to the truth, noise
only outside the co-visible pixels (masked scores perfect, unmasked not), and a missing file.
Every PSNR is capped at 100 dB per frame before the means."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from eval.experiments.view_scores import score_views
from m4dgs.clip import Clip, ClipError, frame_name, level_name
from m4dgs.core import io as mio


def _copy_truth(clip, root):
    for v in clip.view_names():
        shutil.copytree(clip.root / "gt" / "views" / v / "hdr", root / v / "hdr")
        shutil.copytree(clip.root / "gt" / "views" / v / "ldr", root / v / "ldr")


def test_scores_at_the_views(tiny_clip_oracle, tmp_path):
    clip = Clip.open(tiny_clip_oracle)
    pred = tmp_path / "views"
    _copy_truth(clip, pred)
    s = score_views(clip, pred)
    assert s["nv_ldr_oe_psnr"] == 100.0 and s["nv_hdr_mpsnr"] == 100.0
    assert s["nv_hdr_psnr_p99"] == 100.0
    assert s["nv_small_ldr_ne_ssim"] == pytest.approx(1.0)
    assert 0 < s["nv_covisible"] <= 1

    # noise outside the co-visible pixels only: masked scores stay perfect
    rng = np.random.default_rng(0)
    by_hand = []
    for v in clip.view_names():
        for g in clip.test_frames:
            covis = clip.load_view_covis(v, g)
            for lv in clip.meta.exposures.observed:
                p = pred / v / "ldr" / level_name(lv) / frame_name(g, "png")
                img = mio.read_png(p).astype(np.int16)
                noise = rng.integers(-20, 21, img.shape) * (~covis)[..., None]
                noisy = np.clip(img + noise, 0, 255).astype(np.uint8)
                mio.write_png(p, noisy)
                if v == "large":
                    gt = clip.load_view_ldr(v, lv, g).astype(np.float64) / 255
                    mse = np.mean((noisy / 255.0 - gt) ** 2)
                    by_hand.append(min(10 * np.log10(1 / mse), 100.0) if mse > 0 else 100.0)
    s = score_views(clip, pred)
    assert s["nv_ldr_oe_mpsnr"] == 100.0 and s["nv_ldr_oe_psnr"] < 60
    assert s["nv_large_ldr_oe_psnr"] == pytest.approx(np.mean(by_hand), rel=1e-9)
    assert s["nv_ldr_ne_psnr"] == 100.0  # the novel levels were left alone

    victim = pred / "medium" / "hdr" / frame_name(clip.test_frames[0], "exr")
    victim.unlink()
    with pytest.raises(ClipError, match="medium/hdr"):
        score_views(clip, pred)


def test_moving_pixel_scores_at_the_views(tiny_clip_oracle, tmp_path):
    """ldr_oe_dyn_mpsnr / hdr_dyn_mpsnr count only the co-visible pixels of moving objects: noise
    on every other pixel leaves them perfect; noise on those pixels gives the PSNR computed here by
    hand over them (frames without such pixels left out)."""
    clip = Clip.open(tiny_clip_oracle)
    pred = tmp_path / "views"
    _copy_truth(clip, pred)
    s = score_views(clip, pred)
    assert s["nv_ldr_oe_dyn_mpsnr"] == 100.0 and s["nv_hdr_dyn_mpsnr"] == 100.0

    rng = np.random.default_rng(1)
    by_hand = {}  # view -> per-(frame, level) PSNR over the moving co-visible pixels
    n_dyn = 0
    for v in clip.view_names():
        by_hand[v] = []
        for g in clip.test_frames:
            dyn = clip.load_view_covis(v, g) & clip.load_view_dynamic_mask(v, g)
            n_dyn += int(dyn.sum())
            for lv in clip.meta.exposures.observed:
                p = pred / v / "ldr" / level_name(lv) / frame_name(g, "png")
                img = mio.read_png(p).astype(np.int16)
                # "static" noise: everywhere but the moving co-visible pixels
                mio.write_png(p, np.clip(img + 30 * (~dyn)[..., None], 0, 255).astype(np.uint8))
            hp = pred / v / "hdr" / frame_name(g, "exr")
            h = mio.read_exr(hp)
            mio.write_exr(hp, (h * np.where(dyn, 1.0, 3.0)[..., None]).astype(np.float32))
    assert n_dyn > 0, "the tiny clip's views must show moving co-visible pixels"
    s = score_views(clip, pred)
    assert s["nv_ldr_oe_dyn_mpsnr"] == 100.0 and s["nv_hdr_dyn_mpsnr"] == 100.0
    assert s["nv_ldr_oe_mpsnr"] < 40 and s["nv_hdr_mpsnr"] < 60

    # now noise on the moving co-visible pixels only, against a by-hand PSNR over them
    pred2 = tmp_path / "views2"
    _copy_truth(clip, pred2)
    for v in clip.view_names():
        for g in clip.test_frames:
            dyn = clip.load_view_covis(v, g) & clip.load_view_dynamic_mask(v, g)
            for lv in clip.meta.exposures.observed:
                p = pred2 / v / "ldr" / level_name(lv) / frame_name(g, "png")
                img = mio.read_png(p).astype(np.int16)
                noisy = np.clip(
                    img + rng.integers(-25, 26, img.shape) * dyn[..., None], 0, 255
                ).astype(np.uint8)
                mio.write_png(p, noisy)
                if dyn.any():
                    gt = clip.load_view_ldr(v, lv, g).astype(np.float64) / 255
                    mse = np.mean((noisy[dyn] / 255.0 - gt[dyn]) ** 2)
                    by_hand[v].append(min(10 * np.log10(1 / mse), 100.0) if mse > 0 else 100.0)
    s = score_views(clip, pred2)
    for v in clip.view_names():
        want = np.mean(by_hand[v]) if by_hand[v] else None
        got = s[f"nv_{v}_ldr_oe_dyn_mpsnr"]
        assert (got is None) if want is None else got == pytest.approx(want, rel=1e-9)
    assert s["nv_ldr_oe_dyn_mpsnr"] < 60 and s["nv_ldr_oe_mpsnr"] > s["nv_ldr_oe_dyn_mpsnr"]
    assert s["nv_hdr_dyn_mpsnr"] == 100.0  # HDR left alone
