"""The denoiser of benchgen's HDR frames (benchgen.denoise): the exposure ladder against the single
OIDN pass, the ladder's scales and weights against their definitions, and the plain pass against
pyoidn's own high-level call."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pyoidn")

from benchgen.denoise import (  # noqa: E402
    LADDER_STEP,
    LADDER_TARGET,
    denoise_hdr,
    emitter_cap,
    ladder_scales,
    ladder_weights,
    oidn_passes,
)
from benchgen.groundtruth import BIAS_BANDS, render_bias  # noqa: E402


def _three_band_frame(seed: int, dark: float = 1e-4):
    """A frame with three brightness bands (columns at 1e3, 1 and `dark`) of smooth shading, 30 %
    multiplicative per-pixel noise, flat albedo and normal guides.

    Returns (noisy, truth, albedo, normal), each [96, 128, 3]."""
    rng = np.random.default_rng(seed)
    H, W = 96, 128
    yy, xx = np.mgrid[0:H, 0:W]
    shade = 0.6 + 0.4 * np.cos(xx / 9.0) * np.cos(yy / 7.0)
    band = np.where(xx < W // 3, 1e3, np.where(xx < 2 * W // 3, 1.0, dark))
    truth = (shade * band)[..., None] * np.array([1.0, 0.8, 0.6])
    noisy = truth * (1 + 0.3 * rng.standard_normal(truth.shape)).clip(0.05)
    alb = np.full(truth.shape, 0.5, np.float32)
    nrm = np.zeros(truth.shape, np.float32)
    nrm[..., 2] = 1.0
    return noisy.astype(np.float32), truth, alb, nrm


def _band_errors(out, truth):
    """Median per-pixel relative error in each of the three bands (2-px margins at the borders)."""
    W = truth.shape[1]
    e = np.abs(out - truth).mean(-1) / truth.mean(-1)
    cuts = ((2, W // 3 - 2), (W // 3 + 2, 2 * W // 3 - 2), (2 * W // 3 + 2, W - 2))
    return [float(np.median(e[:, a:b])) for a, b in cuts]


@pytest.mark.parametrize("seed", [0, 1])
def test_ladder_denoises_every_decade_as_well_as_the_middle_one(seed):
    """Seven decades in one frame: one pass at OIDN's automatic exposure leaves the 1e-4 band at
    ~3.5x the error of the middle band (measured 0.14 vs 0.04); the ladder keeps every band within
    25 % of the middle band's error, and the darkest well below the single pass."""
    noisy, truth, alb, nrm = _three_band_frame(seed)
    raw = _band_errors(noisy, truth)
    single = _band_errors(denoise_hdr(noisy, alb, nrm, ladder=False), truth)
    lad = _band_errors(denoise_hdr(noisy, alb, nrm), truth)
    assert all(x < 0.5 * r for x, r in zip(lad, raw)), (lad, raw)  # it does denoise
    assert single[2] > 2.0 * single[1], single  # the failure the ladder is for
    assert lad[2] < 0.5 * single[2], (lad, single)
    assert max(lad) < 1.25 * lad[1], lad


def test_ladder_result_scales_with_the_frame():
    """The ladder's scales come from the frame's own percentiles, so denoising k x frame gives k x
    the result (up to float rounding of OIDN's input scaling)."""
    noisy, _, alb, nrm = _three_band_frame(3, dark=1e-3)
    a = denoise_hdr(noisy, alb, nrm)
    k = 64.0  # a power of two: the scaled input is exact in float32
    b = denoise_hdr(noisy * k, alb, nrm)
    np.testing.assert_allclose(b / k, a, rtol=2e-3, atol=1e-9 * a.max())
    np.testing.assert_allclose(
        ladder_scales(noisy * k), ladder_scales(noisy) / k, rtol=1e-12, atol=0
    )


def test_ladder_scales_span_the_frames_percentiles():
    """Scales from target / P99.9 upwards in steps of LADDER_STEP until target / P1 is covered."""
    lum = np.geomspace(1e-3, 1e4, 200 * 100).reshape(200, 100)
    img = np.repeat(lum[..., None], 3, axis=-1)
    s = ladder_scales(img)
    lo, hi = np.percentile(lum, [1.0, 99.9])
    assert s[0] == pytest.approx(LADDER_TARGET / hi, rel=1e-12)
    np.testing.assert_allclose(s[1:] / s[:-1], LADDER_STEP, rtol=1e-12)
    assert s[-1] >= LADDER_TARGET / lo and s[-2] < LADDER_TARGET / lo
    assert len(s) == 1 + math.ceil(math.log(hi / lo) / math.log(LADDER_STEP))
    # a flat frame needs one pass, the darkest tenth alone (a factor ~5) two; pixels outside
    # `keep` do not count; an empty frame gets one scale
    assert len(ladder_scales(np.full((4, 4, 3), 2.0))) == 1
    keep = np.zeros(lum.shape, bool)
    keep[:20] = True  # the darkest tenth (rows 0-19): 1e-3 .. ~5e-3
    s_dark = ladder_scales(img, keep)
    assert len(s_dark) == 2 and s_dark[0] == pytest.approx(
        LADDER_TARGET / np.percentile(lum[:20], 99.9), rel=1e-12
    )
    assert list(ladder_scales(np.zeros((4, 4, 3)))) == [1.0]


def test_ladder_weights_place_each_pixel_in_log_scale():
    scales = np.array([0.01, 1.0, 100.0])
    lum = np.array([[1000.0, 100.0, 10.0, 1.0, 0.01, 1e-3, 1e-6]])
    i, w = ladder_weights(lum, scales, target=1.0)
    # wanted scale 1/lum: 1e-3 (below the ladder: clamped), 0.01, 0.1, 1, 100, 1e3 (above), 1e6
    # position on the ladder i + w (pass i weighted 1 - w, pass i + 1 weighted w)
    np.testing.assert_allclose((i + w)[0], [0, 0, 0.5, 1, 2, 2, 2], atol=1e-12)
    # the result is an interpolation between two passes: weights in [0, 1]
    r = np.random.default_rng(0).lognormal(0, 5, (50, 50))
    i, w = ladder_weights(r, scales)
    assert (i >= 0).all() and (i <= 1).all() and (w >= 0).all() and (w <= 1).all()
    i1, w1 = ladder_weights(r, np.array([3.0]))
    assert (i1 == 0).all() and (w1 == 0).all()


def test_single_automatic_pass_is_pyoidns_own_call():
    """oidn_passes with the automatic exposure reproduces pyoidn.denoise(hdr=True) bit for bit (the
    generator-5 denoiser), and the cap keeps pixels above it raw."""
    import pyoidn

    noisy, _, alb, nrm = _three_band_frame(4, dark=1e-2)
    ref = pyoidn.denoise(noisy, alb, nrm, hdr=True, quality="high")
    (ours,) = oidn_passes(noisy, alb, nrm, (None,))
    np.testing.assert_array_equal(ours, ref)
    emitter = np.zeros(noisy.shape[:2], bool)
    emitter[10:12, 10:12] = True
    frame = noisy.copy()
    frame[10:12, 10:12] = 1e7
    out = denoise_hdr(frame, alb, nrm, emitter)
    cap = emitter_cap(frame, emitter)
    over = frame.max(-1) > cap
    assert over[10:12, 10:12].all()
    np.testing.assert_array_equal(out[over], frame[over])
    assert np.isfinite(out).all() and (out >= 0).all()


def test_render_bias_reports_each_brightness_band():
    """A render off by a known relative error in each quarter of brightness quantiles reads those
    errors back as the band medians; masked pixels and a zero reference do not count."""
    rng = np.random.default_rng(0)
    ref = np.repeat(rng.lognormal(0, 3, (100, 100))[..., None], 3, axis=-1)
    lum = ref.mean(-1)
    q = np.quantile(lum, [0.1, 0.5, 0.9])
    band = np.digitize(lum, q)  # 0 .. 3
    err = np.array([0.4, 0.1, 0.02, 0.005])[band]
    sign = np.where(rng.random(lum.shape) < 0.5, -1.0, 1.0)
    img = ref * (1 + sign * err)[..., None]
    got = render_bias(img, ref)
    assert len(got["median_rel_error"]) == len(BIAS_BANDS)
    np.testing.assert_allclose(got["median_rel_error"], [0.4, 0.1, 0.02, 0.005], rtol=1e-9)
    assert got["mean_rel_error"] == pytest.approx(err.mean(), rel=1e-9)
    mask = band == 3
    only = render_bias(img, ref, mask)
    np.testing.assert_allclose(only["median_rel_error"], [0.005] * 4, rtol=1e-9)
    none = render_bias(img, np.zeros_like(ref))
    assert none["mean_rel_error"] is None


def test_ladder_is_closer_to_a_converged_render_in_the_shadows():
    """A real frame: tiny-lamp-box frame 0 at 72x40 rendered as benchgen renders it (64 spp + the
    adaptive samples, 16-spp guides), denoised both ways, against a raw 1,024-spp render. Measured:
    median relative error of the darkest tenth 0.052 with one pass, 0.020 with the ladder; the
    brighter bands move by < 0.003."""
    import dataclasses

    from benchgen.render import GUIDE_SPP, Renderer, RenderSettings
    from benchgen.scene import load_scene
    from benchgen.suite import builtin_scenes_dir

    W, H = 72, 40
    scene = load_scene(builtin_scenes_dir() / "tiny-lamp-box.yaml", band_limit=(W, H))
    st = scene.frame(0, W, H)
    settings = dataclasses.replace(
        RenderSettings.resolve("tiny"), denoise=False, emitter_sampling="power"
    )
    r = Renderer(st, W, H, settings)
    r.update(st)
    cast = r.cast_rays()
    emitter = r.emitter_pixels()
    guides = r._mi.load_dict({"type": "aov", "aovs": "albedo:albedo,nn:sh_normal"})
    aux = np.array(r._mi.render(r.scene, integrator=guides, seed=0, spp=GUIDE_SPP), np.float32)
    color = r.render_hdr(seed=0)
    ref = r.render_hdr(seed=5, spp=1024)
    use = cast.hit & ~emitter
    single = render_bias(
        denoise_hdr(color, aux[..., :3], aux[..., 3:], emitter, ladder=False), ref, use
    )["median_rel_error"]
    lad = render_bias(denoise_hdr(color, aux[..., :3], aux[..., 3:], emitter), ref, use)[
        "median_rel_error"
    ]
    assert lad[0] < 0.6 * single[0], (lad, single)
    assert all(abs(a - b) < 0.01 for a, b in zip(lad[1:], single[1:])), (lad, single)
