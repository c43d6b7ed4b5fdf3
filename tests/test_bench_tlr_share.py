"""bench/tlr_share.py on frames whose TLR quantity is known by hand (a global flicker with zero
motion, and an integer shift with its exact flow), and bench/stage_probe.py's override parser."""

from __future__ import annotations

import numpy as np
import pytest

from m4dgs.core.io import write_exr


def _frames(tmp_path, frames):
    d = tmp_path / "hdr"
    d.mkdir()
    for g, x in frames.items():
        write_exr(d / f"{g:05d}.exr", x.astype(np.float32))
    return d


def test_flicker_value_and_gradient_by_hand(load_bench, tmp_path):
    b = load_bench("tlr_share")
    rng = np.random.default_rng(0)
    a = rng.uniform(0.01, 2.0, size=(6, 8, 3))
    r = 1.5
    d = _frames(tmp_path, {0: a, 2: r * a})
    flows = {
        "pairs": np.array([[0, 2]]),
        "flow": np.zeros((1, 6, 8, 2), np.float32),
        "valid": np.ones((1, 6, 8), bool),
    }
    v, g, lum = b.pixel_values(d, flows)
    assert v.shape == (48,)
    np.testing.assert_allclose(v, (r - 1) / (r + 1), rtol=1e-5)
    np.testing.assert_allclose(g, (1.0 / ((1 + r) * a)).mean(-1).ravel(), rtol=1e-5)
    np.testing.assert_allclose(lum, a.mean(-1).ravel(), rtol=1e-6)


def test_exact_shift_is_zero_and_invisible_pixels_are_left_out(load_bench, tmp_path):
    b = load_bench("tlr_share")
    rng = np.random.default_rng(1)
    a = rng.uniform(0.1, 1.0, size=(6, 8, 3))
    nb = np.zeros_like(a)
    nb[:, 2:] = a[:, :-2]  # content moved 2 px to the right
    d = _frames(tmp_path, {0: a, 2: nb})
    flow = np.zeros((1, 6, 8, 2), np.float32)
    flow[..., 0] = 2.0
    valid = np.ones((1, 6, 8), bool)
    valid[0, 0, 0] = False
    v, _, _ = b.pixel_values(d, {"pairs": np.array([[0, 2]]), "flow": flow, "valid": valid})
    # columns 0-5 land inside the image (6 x 6 = 36 pixels), one of them masked
    assert v.shape == (35,)
    np.testing.assert_allclose(v, 0.0, atol=1e-6)


def test_stage_probe_overrides(load_bench):
    sp = load_bench("stage_probe")
    assert sp.parse_overrides("a.b=0.1, c.d=true,e=x") == {"a.b": 0.1, "c.d": True, "e": "x"}
    assert sp.parse_overrides("") == {}
    with pytest.raises(SystemExit, match="not KEY=VALUE"):
        sp.parse_overrides("a.b")


def test_report_shares_of_the_darkest_and_brightest_pixels(load_bench, capsys):
    """report(): the value's and the gradient's shares on the darkest / brightest fractions, by
    hand on four pixels (luminances 1, 2, 3, 4)."""
    b = load_bench("tlr_share")
    v = np.array([0.1, 0.2, 0.3, 0.4])
    g = np.array([4.0, 3.0, 2.0, 1.0])
    lum = np.array([1.0, 2.0, 3.0, 4.0])
    b.report("x", v, g, lum, dark=[0.25], truth=False, bright=[0.25])
    out = capsys.readouterr().out
    # darkest quarter: pixel 1 (value 0.1 of 1.0, gradient 4 of 10); brightest: pixel 4
    assert "darkest 25% (<= 1.75): 0.10 of the value, 0.40 of the gradient" in out
    assert "brightest 25% (>= 3.25): 0.40 of the value, 0.1000 of the gradient" in out
