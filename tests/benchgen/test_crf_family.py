"""The clip family of camera responses (m4dgs.core.crf.CLIP_CRFS), the trainer's generic
pre-training target, crf_error (eval.metrics.crf) and the response as a clip setting (benchgen make,
eval suites)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from m4dgs.core.crf import (
    C0_HDRNERF,
    CLIP_CRFS,
    clip_crf,
    get_crf,
    log_logistic,
    reinhard_anchored,
    tonemap_ldr,
)

NEW = [n for n in CLIP_CRFS if n != "hdrnerf"]
# f(1) of every clip curve, from the closed forms: the pre-scaled shapes reproduce HDR-NeRF's
# 0.5^(1/2.2)
F1 = {
    "hdrnerf": 0.5 ** (1 / 2.2),
    "srgb-shoulder": 0.5 ** (1 / 2.2),
    "aces-filmic": 0.5 ** (1 / 2.2),
    "hdrnerf-g1.8": 0.5 ** (1 / 1.8),
    "hdrnerf-g2.4": 0.5 ** (1 / 2.4),
    "hdrnerf-rgb": 0.5 ** (1 / 2.2),
}
# largest log2 x where f < 1 - 1e-9 in float64 (the exponential shoulder reaches 1.0 in floating
# point near x = 30)
TOP = {n: 20.0 for n in CLIP_CRFS}
TOP["srgb-shoulder"] = 4.5


def _channels(name):
    f = get_crf(name)
    return [f.channel(c) for c in range(3)]


def _srgb_oetf(v):
    v = np.asarray(v, np.float64)
    return np.where(
        v <= 0.0031308, 12.92 * v, 1.055 * np.maximum(v, 0.0031308) ** (1 / 2.4) - 0.055
    )


# --------------------------------------------------------------------------------------------------
# the family
def test_family_is_registered_and_other_curves_are_refused():
    assert CLIP_CRFS[0] == "hdrnerf" and len(set(CLIP_CRFS)) == len(CLIP_CRFS) >= 6
    for n in CLIP_CRFS:
        f = clip_crf(n)
        meta = f.metadata()
        assert (
            meta["name"] == n
            and meta["source"]
            and meta["description"]
            and isinstance(meta["params"], dict)
        )
    # display encodings: f(1) = 1, no use as a scale anchor
    for n in ("gamma", "srgb", "linear", "mulog"):
        with pytest.raises(ValueError, match="not a clip response"):
            clip_crf(n)


@pytest.mark.parametrize("name", CLIP_CRFS)
def test_unit_exposure_value_zero_and_range(name):
    f = get_crf(name)
    assert f.unit_exposure_value == pytest.approx(F1[name], abs=1e-12)
    # per-channel: one anchor for all
    assert f.unit_exposure_values == pytest.approx((F1[name],) * 3, abs=1e-12)
    assert 0.6 < f.unit_exposure_value < 0.8
    x = np.exp2(np.linspace(-30, 30, 601))
    for fc in _channels(name):
        assert fc(0.0) == 0.0 and fc.inverse(0.0) == 0.0
        y = fc(x)
        assert (y >= 0).all() and (y <= 1).all()
        assert math.isinf(fc.inverse(1.0))  # never clips: only infinite exposure gives 1


@pytest.mark.parametrize("name", CLIP_CRFS)
def test_strictly_increasing(name):
    x = np.exp2(np.linspace(-30, TOP[name], 4001))
    for fc in _channels(name):
        y = fc(x)
        assert (np.diff(y) > 0).all()
        assert y[-1] < 1.0


@pytest.mark.parametrize("name", CLIP_CRFS)
def test_inverse_round_trip_numpy_and_torch(name):
    x = np.exp2(np.linspace(-25, TOP[name], 500))
    for fc in _channels(name):
        assert fc.inverse(fc(x)) == pytest.approx(x, rel=1e-9)
        y = np.linspace(0.0, 0.999, 400)
        assert fc(fc.inverse(y)) == pytest.approx(y, abs=1e-12)
        xt = torch.tensor(x, dtype=torch.float64)
        yt = fc(xt)
        assert isinstance(yt, torch.Tensor) and yt.dtype == torch.float64
        assert yt.numpy() == pytest.approx(fc(x), abs=1e-15)
        assert fc.inverse(yt).numpy() == pytest.approx(x, rel=1e-9)
        # float32: up to 8-bit white (x = 8 for the exponential shoulder, whose 1 - f underflows
        # soon after)
        top32 = 3.0 if name == "srgb-shoulder" else 8.0
        x32 = torch.tensor(np.exp2(np.linspace(-12, top32, 50)), dtype=torch.float32)
        assert fc.inverse(fc(x32)).numpy() == pytest.approx(x32.numpy(), rel=2e-3)


def test_closed_forms():
    x = np.exp2(np.linspace(-15, 4, 60))
    a = -math.log(1 - ((C0_HDRNERF + 0.055) / 1.055) ** 2.4)
    assert get_crf("srgb-shoulder")(x) == pytest.approx(_srgb_oetf(1 - np.exp(-a * x)), abs=1e-12)
    # ACES fit (Narkowicz) divided by its asymptote 2.51 / 2.43, pre-scale solved for f(1) = C0
    f = get_crf("aces-filmic")
    u = f.params["a"] * x
    aces = u * (2.51 * u + 0.03) / (u * (2.43 * u + 0.59) + 0.14) * 2.43 / 2.51
    assert f(x) == pytest.approx(_srgb_oetf(aces), abs=1e-12)
    for g in (1.8, 2.4):
        assert get_crf(f"hdrnerf-g{g:g}")(x) == pytest.approx((x / (x + 1)) ** (1 / g), abs=1e-14)
    rgb = get_crf("hdrnerf-rgb")
    for c, g in enumerate((2.0, 2.2, 2.4)):
        k = C0_HDRNERF ** (-g) - 1
        assert rgb.channel(c)(x) == pytest.approx((x / (x + k)) ** (1 / g), abs=1e-14)
    assert rgb.channel(1)(x) == pytest.approx(
        get_crf("hdrnerf")(x), abs=1e-14
    )  # green is HDR-NeRF's curve


def test_per_channel_curve_tonemaps_each_channel():
    f = get_crf("hdrnerf-rgb")
    h = np.exp2(np.linspace(-12, 6, 24)).reshape(2, 4, 3)
    ldr = tonemap_ldr(h, 0.5, f)
    for c in range(3):
        exp = np.floor(255 * f.channel(c)(h[..., c] * 0.5) + 0.5).astype(np.uint8)
        assert np.array_equal(ldr[..., c], exp)
    assert np.array_equal(tonemap_ldr(torch.tensor(h), 0.5, f).numpy(), ldr)
    # the channels really differ: the R and B curves straddle G below unit exposure
    x = np.exp2(np.linspace(-10, -1, 10))
    assert (f.channel(0)(x) < f.channel(1)(x)).all() and (f.channel(2)(x) > f.channel(1)(x)).all()
    with pytest.raises(ValueError, match="last axis"):
        f.rgb(np.ones(4))


def test_family_members_are_distinct():
    """Each pair of clip curves differs by at least 4 8-bit codes somewhere in the recorded
    range."""
    x = np.exp2(np.linspace(-12, 8, 801))
    for i, a in enumerate(CLIP_CRFS):
        for b in CLIP_CRFS[i + 1 :]:
            d = max(
                np.abs(get_crf(a).channel(c)(x) - get_crf(b).channel(c)(x)).max() for c in range(3)
            )
            assert 255 * d > 4, (a, b)


# ---------------------------------------------------------------------------------------- the
# pre-training target
def test_pretrain_default_is_generic_and_far_from_every_clip_curve():
    from m4dgs.training.config import ToneMapConfig
    from m4dgs.training.stage1 import pretrain_curve

    assert ToneMapConfig().pretrain_crf == "log-logistic"
    z = np.linspace(-10, 10, 2001)
    x = np.exp2(z)
    for c0 in (get_crf(n).unit_exposure_value for n in CLIP_CRFS):
        g = pretrain_curve("log-logistic", c0)
        gx = g(x)
        assert g(1.0) == pytest.approx(c0, abs=1e-12)  # anchored at f(1) = C0 only
        for n in CLIP_CRFS:
            for fc in _channels(n):
                # stated margin (docs/exposure.md): >= 0.09 LDR (23 codes) somewhere in the
                # pre-training range
                assert np.abs(gx - fc(x)).max() >= 0.09, n
    # it is a logistic in log2 x: sigmoid(0.5 ln2 z + logit C0)
    c0 = C0_HDRNERF
    assert log_logistic(c0)(x) == pytest.approx(
        1 / (1 + np.exp(-(0.5 * np.log(2) * z + np.log(c0 / (1 - c0))))), abs=1e-12
    )
    # the former default, kept as "reinhard-c0" (alias "auto"), IS the HDR-NeRF curve at C0 = 0.73
    for name in ("reinhard-c0", "auto"):
        assert pretrain_curve(name, c0)(x) == pytest.approx(get_crf("hdrnerf")(x), abs=1e-12)
    assert reinhard_anchored(0.5)(1.0) == pytest.approx(0.5)
    t = pretrain_curve("log-logistic", c0)(torch.exp2(torch.linspace(-10, 10, 5)))
    assert isinstance(t, torch.Tensor) and t.dtype == torch.float32


# --------------------------------------------------------------------------------------------------
# crf_error
def test_crf_error_zero_for_the_true_curve_and_analytic_offset():
    from eval.metrics import crf_error, observed_exposure_range

    f = get_crf("hdrnerf-rgb")
    ranges = [(2.0**-8, 2.0**3)] * 3

    def true_curve(z):
        return f.rgb(np.repeat(np.exp2(z)[:, None], 3, 1))

    r = crf_error(true_curve, f, ranges)
    assert r["crf_error"] == pytest.approx(0.0, abs=1e-9) and r["units"] == "8-bit codes"
    # a constant offset d in LDR units reads 255 d codes
    r = crf_error(lambda z: true_curve(z) + 0.01, f, ranges)
    assert r["crf_error"] == pytest.approx(2.55, abs=1e-9)
    # a learned curve equal to HDR-NeRF's on every channel: the error is the R / B channels' mean
    # distance
    learned = lambda z: np.repeat(get_crf("hdrnerf")(np.exp2(z))[:, None], 3, 1)  # noqa: E731
    zz = np.linspace(-8, 3, 256)
    exp = [
        255 * np.mean(np.abs(get_crf("hdrnerf")(np.exp2(zz)) - f.channel(c)(np.exp2(zz))))
        for c in range(3)
    ]
    r = crf_error(learned, f, ranges)
    assert r["per_channel"] == pytest.approx(exp, abs=1e-9) and r["per_channel"][
        1
    ] == pytest.approx(0, abs=1e-12)
    assert r["crf_error"] == pytest.approx(np.mean(exp), abs=1e-9)
    # ranges: percentiles of the exposures recorded between codes 1 and 254
    g = get_crf("srgb-shoulder")
    frames = [np.full((4, 4, 3), v) for v in (1e-6, 0.01, 0.1, 1.0, 100.0)]
    rng = observed_exposure_range(frames, [1.0] * 5, g, percentiles=(0, 100))
    assert rng[0] == pytest.approx((0.01, 1.0))  # 1e-6 records code 0, 100 saturates
    assert observed_exposure_range([np.zeros((2, 2, 3))], [1.0], g) == [None] * 3
    assert crf_error(learned, f, [None] * 3)["crf_error"] is None


# ----------------------------------------------------------------------------------- the response
# as a clip setting
def test_make_clip_records_the_response(tmp_path):
    from functools import partial

    from benchgen.make import make_clip

    # a smoke-test scene (placement: test_placement.py)
    make_clip = partial(make_clip, allow_misplaced=True)
    from benchgen.suite import builtin_scenes_dir
    from m4dgs.clip import Clip, frame_name
    from m4dgs.core import io as mio

    scene = builtin_scenes_dir() / "tiny-lamp-box.yaml"
    out = make_clip(
        scene,
        tmp_path / "c",
        preset="tiny",
        priors="oracle",
        seed=0,
        progress=False,
        max_frames=3,
        spp=4,
        crf="hdrnerf-rgb",
    )
    clip = Clip.open(out)
    m = clip.meta
    f = get_crf("hdrnerf-rgb")
    assert m.crf == "hdrnerf-rgb" and m.generator["crf"] == "hdrnerf-rgb"
    assert m.unit_exposure_value == pytest.approx(f.unit_exposure_value)
    assert m.gt["crf"]["params"]["gammas"] == [2.0, 2.2, 2.4] and m.gt["crf"]["source"]
    assert m.gt["hdr_scale_report"]["crf"] == "hdrnerf-rgb"
    g, dt = clip.train_frames[0], m.exposures.train_dt[0]
    hdr = mio.read_exr(out / "gt/hdr" / frame_name(g, "exr"))
    assert np.array_equal(clip.load_ldr(g), tonemap_ldr(hdr, dt, f))
    # the same folder with another response is never resumed as the old one
    with pytest.raises(FileExistsError, match="other settings"):
        make_clip(
            scene,
            out,
            preset="tiny",
            priors="oracle",
            seed=0,
            progress=False,
            max_frames=3,
            spp=4,
            crf="hdrnerf",
        )
    with pytest.raises(ValueError, match="not a clip response"):
        make_clip(
            scene,
            tmp_path / "bad",
            preset="tiny",
            priors="oracle",
            progress=False,
            max_frames=3,
            crf="srgb",
        )


def test_benchgen_cli_and_eval_suite_pass_the_response(tmp_path, monkeypatch):
    from click.testing import CliRunner

    import benchgen.make as bm
    from benchgen.cli import main as benchgen_main
    from eval.experiments.runner import job_list, make_job_clip
    from eval.records.suite import SuiteError, load_eval_suite, parse_suite

    seen = []
    monkeypatch.setattr(bm, "make_suite", lambda *a, **kw: seen.append(kw["crf"]) or [])
    assert (
        CliRunner()
        .invoke(benchgen_main, ["make", "--suite", "tiny", "--crf", "aces-filmic"])
        .exit_code
        == 0
    )
    assert seen == ["aces-filmic"]
    r = CliRunner().invoke(benchgen_main, ["make", "--suite", "tiny", "--crf", "gamma"])
    assert r.exit_code != 0 and "not a clip response" in r.output

    s = load_eval_suite("crf")
    crfs = {c.crf or "hdrnerf" for c in s.clips.values()}
    assert len(crfs) >= 3 and "hdrnerf" in crfs and set(s.variants) == {"full"}
    assert any(t.columns == "crf" for t in s.tables)
    made = []
    monkeypatch.setattr(bm, "make_clip", lambda *a, **kw: made.append((a[1], kw["crf"])))
    jobs = job_list("crf", tmp_path, "tiny", ["lamp-room-orbit"])
    for j in jobs:
        make_job_clip(j)
    by_dir = {str(d): c for d, c in made}
    assert (
        by_dir[str(tmp_path.resolve() / "clips/syn-exp-3-crf-aces-filmic/lamp-room-orbit")]
        == "aces-filmic"
    )
    # shared with syn-exp-3
    assert by_dir[str(tmp_path.resolve() / "clips/syn-exp-3/lamp-room-orbit")] == "hdrnerf"
    with pytest.raises(SuiteError, match="crf"):
        parse_suite(
            {
                "name": "x",
                "scenes": "tiny",
                "clips": {"a": {"crf": "srgb"}},
                "rows": [{"clip": "a"}],
            }
        )
