"""Whole-scene HDR PSNR and the highlight scores on hand-made frames with known answers: one lamp
pixel no longer sets the scale (an all-black or constant prediction scores low, a 24x too bright
lamp costs), and the highlight pixels are the ones only exposure fusion recovers."""

from __future__ import annotations

import numpy as np
import pytest

from eval.metrics.hdr import hdr_psnr
from eval.metrics.scene_hdr import (
    code_bin_span,
    hdr_psnr_p99,
    highlight_mask,
    highlight_scores,
    resolved_short_code,
)
from m4dgs.core.crf import clip_crf, tonemap_ldr

CRF = clip_crf("hdrnerf")


def _room(seed=0):
    """A dim textured room (0.2-1.4) with one lamp pixel at 1,170: the scale of lamp-room-orbit."""
    rng = np.random.default_rng(seed)
    h = 0.2 + 1.2 * rng.random((40, 60, 1)) * np.array([[[1.0, 0.9, 0.8]]])
    h[20, 30] = 1170.0
    return h


def _psnr_by_hand(pred, gt, unit):
    t = lambda x: np.log(1 + 5000 * np.maximum(x, 0) / unit) / np.log(5001)  # noqa: E731
    return 10 * np.log10(1 / np.mean((t(pred) - t(gt)) ** 2))


def test_one_lamp_pixel_does_not_set_the_scale():
    gt = _room()
    unit = np.percentile(gt @ np.array([0.2126, 0.7152, 0.0722]), 99)
    black, const = np.zeros_like(gt), np.full_like(gt, gt.mean())
    good = gt * (1 + 0.05 * np.random.default_rng(1).standard_normal(gt.shape))
    assert hdr_psnr_p99(black, gt) == pytest.approx(_psnr_by_hand(black, gt, unit), rel=1e-9)
    # the paper's convention: an all-black frame still scores ~16 dB here; the whole-scene one not
    assert hdr_psnr(black, gt) > 12 and hdr_psnr_p99(black, gt) < 3
    assert hdr_psnr_p99(const, gt) < hdr_psnr_p99(good, gt) - 20
    assert hdr_psnr_p99(good, gt) > 35
    # a lamp 24 x too bright: the clipped paper metric does not move, the whole-scene one does
    bright = gt.copy()
    bright[20, 30] *= 24
    assert hdr_psnr(bright, gt) > 60  # clipped at the truth's max: no error at all
    assert hdr_psnr_p99(bright, gt) < hdr_psnr_p99(good, gt)  # one pixel in 2,400, as 5 % noise


def test_highlights_are_saturated_long_and_measured_short():
    # values picked by where the response saturates: dark, highlight (only the long exposure
    # clips), and blinding (both clip)
    dark, highlight, blinding = 0.001, 20.0, 1e6
    assert (tonemap_ldr(np.full((1, 1, 3), highlight), 32.0, CRF) == 255).all()
    assert (tonemap_ldr(np.full((1, 1, 3), highlight), 0.125, CRF) < 255).all()
    assert (tonemap_ldr(np.full((1, 1, 3), blinding), 0.125, CRF) == 255).all()
    gt = np.full((4, 6, 3), dark)
    gt[1, 1] = gt[2, 3] = highlight
    gt[0, 5] = blinding
    m = highlight_mask(gt, CRF, 32.0, 0.125)
    assert m.sum() == 2 and m[1, 1] and m[2, 3] and not m[0, 5]
    pred = gt.copy()
    pred[1, 1] *= 2.0  # one stop too bright
    pred[2, 3] *= 0.5  # one stop too dark
    s = highlight_scores(pred, gt, CRF, 32.0, 0.125)
    assert s["highlight_stops"] == pytest.approx(1.0)
    assert s["highlight_peak_ratio"] == pytest.approx(2.0)
    assert s["highlight_pixels"] == 2
    none = highlight_scores(gt, np.full((4, 6, 3), dark), CRF, 32.0, 0.125)
    assert np.isnan(none["highlight_stops"]) and none["highlight_pixels"] == 0


def _bins_by_sweep(crf):
    """{code: (smallest, largest) HDR value reaching it} at exposure 1, from a dense sweep through
    tonemap_ldr: an estimate that never inverts the curve."""
    h = np.exp(np.linspace(np.log(1e-3), np.log(1e4), 2_000_000))
    codes = tonemap_ldr(np.repeat(h[:, None], 3, 1), 1.0, crf)[:, 0]
    return {c: (h[codes == c].min(), h[codes == c].max()) for c in range(240, 255)}


@pytest.mark.parametrize(
    "name, code", [("hdrnerf", 253), ("srgb-shoulder", 254), ("aces-filmic", 253)]
)
def test_code_bins_and_the_resolved_code_match_a_dense_sweep(name, code):
    crf = clip_crf(name)
    bins = _bins_by_sweep(crf)
    for c in (245, 250, 253, 254):
        lo, hi = bins[c]
        assert code_bin_span(crf, c) == pytest.approx(hi / lo, rel=1e-3), c
    # the largest code whose bin spans at most 2x, by the sweep
    assert resolved_short_code(crf) == max(c for c, (lo, hi) in bins.items() if hi / lo <= 2)
    assert resolved_short_code(crf) == code
    assert code_bin_span(crf, 0) == float("inf") and code_bin_span(crf, 255) == float("inf")


def test_the_resolved_peak_leaves_out_pixels_just_under_clipping():
    # two highlights: one the shortest exposure shows at code 254 (its bin spans 3x), one at 240
    bins = _bins_by_sweep(CRF)
    dt = 0.125
    at254 = np.sqrt(bins[254][0] * bins[254][1]) / dt
    at240 = np.sqrt(bins[240][0] * bins[240][1]) / dt
    gt = np.full((4, 6, 3), 0.001)
    gt[1, 1], gt[2, 3] = at254, at240
    assert tonemap_ldr(gt[1:2, 1:2], dt, CRF).max() == 254
    assert tonemap_ldr(gt[2:3, 3:4], dt, CRF).max() == 240
    pred = gt.copy()
    pred[1, 1] *= 4.0  # 4x too bright where one code spans 3x: two codes off at most
    pred[2, 3] *= 1.25
    every = highlight_scores(pred, gt, CRF, 32.0, dt)
    fine = highlight_scores(pred, gt, CRF, 32.0, dt, max_short_code=resolved_short_code(CRF))
    assert every["highlight_pixels"] == 2 and fine["highlight_pixels"] == 1
    assert every["highlight_peak_ratio"] == pytest.approx(4.0)
    assert fine["highlight_peak_ratio"] == pytest.approx(1.25)
