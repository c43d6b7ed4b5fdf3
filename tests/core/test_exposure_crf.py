"""CRF registry (m4dgs.core.crf) and exposure settings / schedules (benchgen.exposure) against
analytic values, an independent sRGB implementation (colour-science) and hand-written formulas."""

import math

import numpy as np
import pytest
import torch
from scipy import stats

from benchgen.exposure import (
    ExposureSettings,
    exposure_gap_ev,
    exposure_preset,
    parse_levels,
    schedule_train_dt,
    test_levels,
)
from m4dgs.core.crf import available_crfs, get_crf, quantize_ldr, tonemap_ldr


def _hdrnerf_ref(x):
    x = np.asarray(x, np.float64)
    return (x / (x + 1.0)) ** (1.0 / 2.2)


def _ldr_ref(hdr, dt):
    """Independent quantiser: round half up of 255 * hdrnerf(H dt)."""
    return np.clip(
        np.floor(255.0 * _hdrnerf_ref(np.asarray(hdr, np.float64) * dt) + 0.5), 0, 255
    ).astype(np.uint8)


# --------------------------------------------------------------------------------------------------
# CRF
def test_registry_names_and_default():
    assert {"hdrnerf", "gamma", "srgb", "mulog", "linear"} <= set(available_crfs())
    assert get_crf().name == "hdrnerf"
    assert get_crf(None).name == "hdrnerf"
    f = get_crf("gamma")
    assert get_crf(f) is f
    with pytest.raises(KeyError, match="unknown CRF"):
        get_crf("nope")


def test_hdrnerf_unit_exposure_and_hand_values():
    f = get_crf("hdrnerf")
    assert f.unit_exposure_value == pytest.approx(0.5 ** (1 / 2.2), abs=1e-12)
    assert f.unit_exposure_value == pytest.approx(0.72974, abs=1e-5)
    # hand-computed: f(3) = 0.75^(1/2.2), f(1/3) = 0.25^(1/2.2), f(0) = 0
    assert f(3.0) == pytest.approx(math.pow(0.75, 1 / 2.2), abs=1e-12)
    assert f(1.0 / 3.0) == pytest.approx(math.pow(0.25, 1 / 2.2), abs=1e-12)
    assert f(0.0) == 0.0
    assert f(-5.0) == 0.0  # negatives count as 0
    assert f.inverse(1.0) == math.inf


@pytest.mark.parametrize("dtype", [np.float64, torch.float64])
def test_hdrnerf_round_trip_wide_range(dtype):
    f = get_crf("hdrnerf")
    x = np.logspace(-4, 4, 2001)
    if dtype is torch.float64:
        x = torch.tensor(x, dtype=torch.float64)
        y = f(x)
        assert isinstance(y, torch.Tensor) and y.dtype == torch.float64
        back = f.inverse(y).numpy()
        x = x.numpy()
    else:
        back = f.inverse(f(x))
    np.testing.assert_allclose(back, x, rtol=1e-8)
    np.testing.assert_allclose(f(x), _hdrnerf_ref(x), rtol=1e-14)


def test_hdrnerf_torch_float32_matches_numpy():
    f = get_crf("hdrnerf")
    x = np.logspace(-3, 3, 101)
    yt = f(torch.tensor(x, dtype=torch.float32))
    assert yt.dtype == torch.float32
    np.testing.assert_allclose(yt.numpy(), _hdrnerf_ref(x), rtol=1e-5)
    back = f.inverse(yt).numpy()
    np.testing.assert_allclose(back, x, rtol=2e-3)


def test_srgb_matches_the_standard():
    """IEC 61966-2-1 encoding, written out here: 12.92 x up to 0.0031308, else 1.055 x^(1/2.4) -
    0.055 (the colour-science package's sRGB cctf_encoding gives the same; it is not a test
    dependency)."""
    f = get_crf("srgb")
    x = np.concatenate([np.linspace(0, 0.01, 50), np.linspace(0.01, 1, 200)])
    ref = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    # mid grey and one half, worked out from the formula: 0.18 -> 0.4613561, 0.5 -> 0.7353570
    assert f(0.18) == pytest.approx(0.46135612950044164, abs=1e-7)
    assert f(0.5) == pytest.approx(0.7353569830524495, abs=1e-7)
    np.testing.assert_allclose(f(x), ref, atol=1e-7)
    np.testing.assert_allclose(f(torch.tensor(x)).numpy(), ref, atol=1e-7)
    assert f(2.0) == pytest.approx(1.0)  # clipping curve


@pytest.mark.parametrize("name", ["gamma", "srgb", "mulog", "linear"])
def test_clipping_curves_round_trip(name):
    f = get_crf(name)
    x = np.logspace(-4, 0, 400)
    np.testing.assert_allclose(f.inverse(f(x)), x, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(f.inverse(f(torch.tensor(x))).numpy(), x, rtol=1e-9, atol=1e-12)
    assert f.unit_exposure_value == pytest.approx(1.0)
    assert np.all(np.diff(f(x)) > 0)  # strictly increasing on (0, 1]


def test_gamma_and_mulog_hand_values():
    assert get_crf("gamma")(0.5) == pytest.approx(0.5 ** (1 / 2.2))
    assert get_crf("mulog")(0.5) == pytest.approx(math.log(1 + 2500.0) / math.log(5001.0))


def test_quantize_rounds_half_up_and_clips():
    v = np.array(
        [0.0, 0.5 / 255 - 1e-9, 0.5 / 255 + 1e-9, 100.4 / 255, 100.6 / 255, 1.0, 1.3, -0.2]
    )
    np.testing.assert_array_equal(quantize_ldr(v), [0, 0, 1, 100, 101, 255, 255, 0])
    np.testing.assert_array_equal(
        quantize_ldr(torch.tensor(v)).numpy(), [0, 0, 1, 100, 101, 255, 255, 0]
    )


def test_tonemap_ldr_known_values_and_reference():
    # H dt = 1 -> 255 * 0.72974 = 186.08 -> 186; 0 -> 0; 1e6 -> 255 * (1 - 1e-6)^(1/2.2) = 254.9999
    # -> 255
    out = tonemap_ldr(np.array([[1.0, 0.0, 1e6]]), 1.0)
    np.testing.assert_array_equal(out, [[186, 0, 255]])
    assert out.dtype == np.uint8
    assert tonemap_ldr(np.array([0.5]), 2.0)[0] == 186  # exposure scales the irradiance
    rng = np.random.default_rng(0)
    hdr = np.exp(rng.uniform(-12, 6, size=(32, 32, 3)))
    for dt in (0.125, 2.0, 32.0):
        np.testing.assert_array_equal(tonemap_ldr(hdr, dt), _ldr_ref(hdr, dt))
        t = tonemap_ldr(torch.tensor(hdr), dt)
        assert t.dtype == torch.uint8
        np.testing.assert_array_equal(t.numpy(), _ldr_ref(hdr, dt))
    with pytest.raises(ValueError):
        tonemap_ldr(hdr, 0.0)


# --------------------------------------------------------------------------------------------------
# settings
def test_presets_and_overrides():
    s3 = exposure_preset(3)
    assert (
        s3.observed == (0.125, 2.0, 32.0)
        and s3.novel == (0.5, 8.0)
        and s3.schedule == "alternating"
    )
    assert s3.middle == pytest.approx(2.0) and s3.num_levels == 3
    assert test_levels(s3) == [0.125, 0.5, 2.0, 8.0, 32.0]
    s2 = exposure_preset(2)
    assert s2.observed == (0.5, 8.0) and s2.novel == (0.125, 2.0, 32.0)
    assert s2.middle == pytest.approx(2.0)
    o = exposure_preset(3, observed=parse_levels("0.25, 2, 8"))
    assert o.observed == (0.25, 2.0, 8.0) and o.novel == (0.5,)  # 8 left the novel set
    assert exposure_preset(3, novel=[]).novel == ()
    with pytest.raises(ValueError):
        ExposureSettings(observed=(1.0, 1.0))
    with pytest.raises(ValueError):
        ExposureSettings(observed=(1.0, -2.0))
    with pytest.raises(ValueError):
        ExposureSettings(observed=(1.0, 2.0), novel=(2.0,))
    with pytest.raises(ValueError):
        ExposureSettings(schedule="zigzag")
    assert exposure_gap_ev(0.125, 32) == pytest.approx(8.0)


def test_alternating_schedule_pattern():
    dts = schedule_train_dt(8, exposure_preset(3), seed=123)
    assert dts == [0.125, 2.0, 32.0, 0.125, 2.0, 32.0, 0.125, 2.0]
    assert schedule_train_dt(5, exposure_preset(2)) == [0.5, 8.0, 0.5, 8.0, 0.5]


def test_random_order_schedule_balanced_permutation():
    s = exposure_preset(3, schedule="random-order")
    dts = schedule_train_dt(30, s, seed=7)
    assert sorted(dts) == sorted([0.125, 2.0, 32.0] * 10)  # a permutation of the balanced multiset
    assert dts != [0.125, 2.0, 32.0] * 10
    assert dts == schedule_train_dt(30, s, seed=7)
    assert dts != schedule_train_dt(30, s, seed=8)
    odd = schedule_train_dt(31, s, seed=1)
    counts = [odd.count(v) for v in s.observed]
    assert sum(counts) == 31 and max(counts) - min(counts) <= 1


def test_random_values_schedule_log_uniform():
    s = exposure_preset(3, schedule="random-values")
    dts = np.array(schedule_train_dt(3000, s, seed=3))
    assert dts.min() >= 0.125 and dts.max() <= 32.0
    lo, hi = math.log(0.125), math.log(32.0)
    ks = stats.kstest(np.log(dts), "uniform", args=(lo, hi - lo))
    assert ks.pvalue > 0.01
    # not uniform in linear space (mean of log-uniform on [0.125, 32] is (32 - 0.125) / ln(256) =
    # 5.75)
    assert dts.mean() == pytest.approx((32 - 0.125) / math.log(256.0), rel=0.1)
    assert schedule_train_dt(10, s, seed=3) == list(dts[:10])
    assert schedule_train_dt(10, s, seed=4) != list(dts[:10])


def test_random_values_banded_schedule():
    """Each value lies within half a stop of the level random-order gives that frame (same seed),
    inside the observed range; the offsets are uniform on [-0.5, 0.5] stops around the middle level
    and, reflected at the ends, uniform on [0, 0.5] inward from the end levels."""
    n = 3000
    s = exposure_preset(3, schedule="random-values-banded")
    dts = np.array(schedule_train_dt(n, s, seed=5))
    order = np.array(schedule_train_dt(n, exposure_preset(3, schedule="random-order"), seed=5))
    assert dts.min() >= 0.125 and dts.max() <= 32.0
    off = np.log2(dts) - np.log2(order)
    assert np.abs(off).max() <= 0.5 + 1e-12
    assert not np.isin(dts, [0.125, 2.0, 32.0]).any()  # every value is off the levels
    assert [int((order == v).sum()) for v in (0.125, 2.0, 32.0)] == [1000, 1000, 1000]
    mid = off[order == 2.0]
    assert stats.kstest(mid, "uniform", args=(-0.5, 1.0)).pvalue > 0.01
    assert stats.kstest(off[order == 0.125], "uniform", args=(0.0, 0.5)).pvalue > 0.01
    assert stats.kstest(-off[order == 32.0], "uniform", args=(0.0, 0.5)).pvalue > 0.01
    # the ends are covered as in the alternating schedule: a third of the frames within half a stop
    # of the shortest exposure (random-values: one sixteenth)
    assert (np.log2(dts) <= -2.5).mean() == pytest.approx(1 / 3, abs=1e-9)
    assert schedule_train_dt(30, s, seed=5) == schedule_train_dt(30, s, seed=5)
    assert schedule_train_dt(30, s, seed=5) != schedule_train_dt(30, s, seed=6)


def test_schedule_names_agree():
    """eval validates suite files without importing benchgen's numerics: its list must match."""
    from benchgen.exposure import SCHEDULES
    from eval.records.suite import SCHEDULES as EVAL_SCHEDULES

    assert EVAL_SCHEDULES == SCHEDULES
