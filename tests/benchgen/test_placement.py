"""Exposure placement (benchgen.placement): the HDR scale meets the targets it claims, checked with
an independent quantiser, and the statistics a clip records are recomputed independently from its
PNGs (PIL, not m4dgs.core.io)."""

import json

import numpy as np
import pytest
from PIL import Image

from benchgen.placement import choose_hdr_scale, level_roles, placement_failures

LEVELS = (0.125, 2.0, 32.0)


def _ldr_ref(hdr, dt):
    """Independent 8-bit quantiser: round half up of 255 * (x / (x + 1))^(1/2.2)."""
    x = np.asarray(hdr, np.float64) * dt
    return np.clip(np.floor(255.0 * (x / (x + 1.0)) ** (1.0 / 2.2) + 0.5), 0, 255).astype(np.uint8)


def _stats(ldr):
    px = ldr.reshape(-1, 3).astype(int)
    return (
        np.median(px.max(1)) / 255.0,
        [(px[:, c] >= 250).mean() for c in range(3)],
        [(px[:, c] <= 5).mean() for c in range(3)],
    )


def _scene_frames(rng, n=3, dark=True):
    """Log-normal 'scene' radiance with a few very bright pixels (lamps) and, optionally, a
    deep-shadow corner."""
    h = np.exp(rng.normal(0.0, 1.2, size=(n, 48, 64, 1))) * np.array([1.0, 0.85, 0.7])
    h[:, :2, :4] *= 400.0  # highlights: 8 px of 3072 per frame = 0.26 %
    if dark:
        h[:, -4:, -6:] *= 1e-4  # an unlit corner: 24 px = 0.78 %
    return h


def test_level_roles():
    assert level_roles(LEVELS) == {"short": 0.125, "middle": 2.0, "long": 32.0}
    assert level_roles([8.0, 0.5]) == {"short": 0.5, "middle": 0.5, "long": 8.0}


def test_scale_meets_every_target_by_the_independent_quantiser():
    rng = np.random.default_rng(3)
    fr = {lv: _scene_frames(rng) for lv in LEVELS}
    s, rep = choose_hdr_scale(fr, "hdrnerf")
    assert rep["feasible"] and rep["given_up"] == [] and rep["scale"] == s
    med, _, _ = _stats(_ldr_ref(fr[2.0] * s, 2.0))
    _, hi_s, lo_s = _stats(_ldr_ref(fr[0.125] * s, 0.125))
    _, hi_l, _ = _stats(_ldr_ref(fr[32.0] * s, 32.0))
    assert 0.35 <= med <= 0.65
    assert max(hi_s) <= 0.02 and min(hi_l) >= 0.005 and min(lo_s) >= 0.005
    # the prediction in the report is exactly what the quantiser gives
    assert rep["predicted"]["mid_median"]["value"] == pytest.approx(med)
    assert rep["predicted"]["short_dark"]["value"] == pytest.approx(min(lo_s))
    # nothing forces the aim away from 0.5 here: the middle-level median sits at the aim (one code
    # of slack)
    assert abs(med - 0.5) <= 1.0 / 255 + 1e-12


def test_scale_boundaries_are_tight():
    """Each interval end found by bisection is a real boundary: just outside it the target fails."""
    rng = np.random.default_rng(4)
    fr = {lv: _scene_frames(rng) for lv in LEVELS}
    _, rep = choose_hdr_scale(fr, "hdrnerf")
    lo_sat = rep["intervals"]["long_saturated"][0]
    _, hi_in, _ = _stats(_ldr_ref(fr[32.0] * lo_sat * 1.0001, 32.0))
    _, hi_out, _ = _stats(_ldr_ref(fr[32.0] * lo_sat * 0.999, 32.0))
    assert min(hi_in) >= 0.005 > min(hi_out)
    hi_dark = rep["intervals"]["short_dark"][1]
    _, _, lo_in = _stats(_ldr_ref(fr[0.125] * hi_dark * 0.9999, 0.125))
    _, _, lo_out = _stats(_ldr_ref(fr[0.125] * hi_dark * 1.001, 0.125))
    assert min(lo_in) >= 0.005 > min(lo_out)


def test_scene_without_range_gives_up_dark_and_says_so():
    rng = np.random.default_rng(5)
    fr = {lv: _scene_frames(rng, dark=False) for lv in LEVELS}
    s, rep = choose_hdr_scale(fr, "hdrnerf")
    assert not rep["feasible"] and rep["given_up"] == ["short_dark"]
    assert "short_dark" in rep["message"]
    med, _, _ = _stats(_ldr_ref(fr[2.0] * s, 2.0))
    _, _, lo_s = _stats(_ldr_ref(fr[0.125] * s, 0.125))
    assert 0.35 <= med <= 0.65 and min(lo_s) < 0.005
    assert (
        rep["predicted"]["short_dark"]["met"] is False
        and rep["predicted"]["mid_median"]["met"] is True
    )


def test_bad_frames_are_refused():
    with pytest.raises(ValueError, match="finite"):
        choose_hdr_scale(
            {
                0.125: np.full((1, 4, 4, 3), np.nan),
                2.0: np.ones((1, 4, 4, 3)),
                32.0: np.ones((1, 4, 4, 3)),
            }
        )


def test_clip_records_achieved_placement_recomputed_from_pngs(tiny_clip_oracle):
    tiny_clip = tiny_clip_oracle
    """clip.json gt.placement equals the statistics recomputed here with PIL from input/ldr."""
    meta = json.loads((tiny_clip / "clip.json").read_text())
    pl = meta["gt"]["placement"]
    by = {}
    for g, dt in zip(meta["split"]["train"], meta["exposures"]["train_dt"]):
        by.setdefault(float(dt), []).append(
            np.asarray(Image.open(tiny_clip / "input/ldr" / f"{g:05d}.png"))
        )
    for lv in LEVELS:
        med, hi, lo = _stats(np.stack(by[lv]))
        rec = pl["levels"][f"{lv:g}"]
        assert rec["num_frames"] == len(by[lv])
        assert rec["median"] == pytest.approx(med)
        assert rec["hi_fraction"] == pytest.approx(hi) and rec["lo_fraction"] == pytest.approx(lo)
    med, _, _ = _stats(np.stack(by[2.0]))
    assert pl["targets"]["mid_median"]["value"] == pytest.approx(med)
    assert pl["targets"]["mid_median"]["met"] == (0.35 <= med <= 0.65)
    assert pl["all_met"] == all(v["met"] for v in pl["targets"].values())
    assert meta["gt"]["hdr_scale_report"]["scale"] == pytest.approx(meta["hdr_scale"])


def test_failure_message_names_every_missed_target(tmp_path):
    from benchgen.make import PlacementError, check_clip_placement

    pl = {
        "targets": {
            "mid_median": {"value": 0.9, "wanted": "in [0.35, 0.65] at dt=2", "met": False},
            "short_dark": {"value": 0.0, "wanted": ">= 0.005 ...", "met": False},
            "long_saturated": {"value": 0.2, "wanted": ">= 0.005 ...", "met": True},
        }
    }
    assert len(placement_failures(pl)) == 2
    with pytest.raises(PlacementError) as e:
        check_clip_placement(tmp_path / "clipA", pl)
    msg = str(e.value)
    assert (
        "clipA" in msg
        and "mid_median: 0.9" in msg
        and "short_dark" in msg
        and "long_saturated" not in msg
    )
    assert "--allow-misplaced" in msg
    check_clip_placement(tmp_path / "clipA", pl, allow_misplaced=True)  # a warning only
    check_clip_placement(tmp_path / "clipA", {"targets": {}})
