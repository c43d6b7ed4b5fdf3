"""The learned camera response against the true one (`m4dgs-eval crf`): the best exposure shift, the
signed error per band, and the command.

Learned curves are the true response slid along log x by known amounts or offset in known bands, so
every figure has a hand-computed answer."""

from __future__ import annotations

import json
import sys
import types

import numpy as np
import pytest
import torch
from click.testing import CliRunner

from eval.cli import main
from eval.inspect.responses import clip_ranges, response_report
from eval.metrics.crf import crf_error, crf_error_bands, crf_error_shifted
from m4dgs.clip import Clip
from m4dgs.core import io as mio
from m4dgs.core.crf import get_crf

F = get_crf("hdrnerf")
RANGES = [(2.0**-12, 2.0**3), (2.0**-11, 2.0**2.5), (2.0**-13, 2.0**2)]


def slid(shifts, crf=F):
    """A learned curve: channel c is the true response needing shifts[c] EV more exposure."""

    def curve(z):
        z = np.asarray(z, np.float64)
        return np.stack([crf.channel(c)(np.exp2(z - s)) for c, s in enumerate(shifts)], axis=1)

    return curve


def test_a_slid_curve_is_all_shift_and_no_shape():
    out = crf_error_shifted(slid([0.3, 0.3, 0.3]), F, RANGES)
    assert out["shift"] == pytest.approx(0.3, abs=1e-9)
    assert out["crf_error"] < 0.01  # the grid holds the shift exactly: only float error is left
    assert out["per_channel_shift"] == pytest.approx([0.3] * 3, abs=1e-9)
    assert crf_error(slid([0.3] * 3), F, RANGES)["crf_error"] > 1.0  # unshifted it is an error

    # a darker curve needs more exposure: the sign
    assert crf_error_shifted(slid([-0.45] * 3), F, RANGES)["shift"] == pytest.approx(
        -0.45, abs=1e-9
    )


def test_a_shift_per_channel_is_a_white_balance():
    out = crf_error_shifted(slid([0.2, -0.1, 0.4]), F, RANGES)
    assert out["per_channel_shift"] == pytest.approx([0.2, -0.1, 0.4], abs=1e-9)
    assert out["crf_error_per_channel_shift"] < 0.01
    assert -0.1 < out["shift"] < 0.4  # one shared shift cannot fit all three
    assert out["crf_error"] > 0.5


def test_the_shifted_error_is_zero_shift_when_the_curve_is_true_and_none_without_ranges():
    out = crf_error_shifted(slid([0.0] * 3), F, RANGES)
    assert out["shift"] == 0.0 and out["crf_error"] < 1e-9
    none = crf_error_shifted(slid([0.0] * 3), F, [None, None, None])
    assert none["crf_error"] is None and none["shift"] == 0.0


def test_bands_read_a_constant_offset_everywhere_and_a_bump_only_where_it_is():
    d = 0.01
    const = crf_error_bands(lambda z: slid([0.0] * 3)(z) + d, F, RANGES, bands=4)
    assert const["bands"] == pytest.approx([255 * d] * 4, abs=1e-9)
    assert len(const["edges_log2"][0]) == 5

    # +d only in the top quarter of each channel's range (by the channel's own edges)
    edges = [np.linspace(np.log2(lo), np.log2(hi), 5) for lo, hi in RANGES]

    def bump(z):
        y = slid([0.0] * 3)(z)
        for c in range(3):
            y[:, c] += d * (np.asarray(z) > edges[c][3])
        return y

    b = crf_error_bands(bump, F, RANGES, bands=4, n=256)
    assert b["bands"][:3] == pytest.approx([0.0] * 3, abs=1e-9)
    assert b["bands"][3] == pytest.approx(255 * d, abs=1e-9)
    # equal bands: their mean is crf_error's mean when the sign does not change
    assert np.mean(b["bands"]) == pytest.approx(crf_error(bump, F, RANGES)["crf_error"], rel=0.02)
    with pytest.raises(ValueError, match="bands"):
        crf_error_bands(bump, F, RANGES, bands=0)


def test_report_on_a_clip_against_its_own_response(tiny_clip_realistic):
    clip = Clip.open(tiny_clip_realistic)
    f = get_crf(clip.meta.crf)
    ranges = clip_ranges(clip)[1]
    true = response_report(slid([0.0] * 3, f), clip, bands=3)
    assert true["crf_error"] < 1e-9 and true["crf_error_shifted"] < 1e-9
    assert true["bands"] == pytest.approx([0.0] * 3, abs=1e-9)
    assert max(abs(v) for v in true["plot"]["difference_codes"]) < 1e-9
    off = response_report(slid([0.25] * 3, f), clip, bands=3, ranges=ranges)
    assert off["shift"] == pytest.approx(0.25, abs=1e-9)
    assert off["crf_error"] == pytest.approx(crf_error(slid([0.25] * 3, f), f, ranges)["crf_error"])
    # slid to the right: darker everywhere in the recorded range
    assert all(v < 0 for v in off["bands"])


class _FakeModel:
    def __init__(self, crf, shift):
        self.crf, self.shift = crf, shift

    def tonemap_curve(self, log2_x):
        assert isinstance(log2_x, torch.Tensor)
        return torch.as_tensor(slid([self.shift] * 3, self.crf)(log2_x.double().numpy()))


def test_the_command_reads_runs_names_the_unreadable_and_draws(
    tiny_clip_realistic, tmp_path, monkeypatch
):
    clip = Clip.open(tiny_clip_realistic)
    f = get_crf(clip.meta.crf)
    shifts = {"a": 0.2, "b": -0.3}
    mod = types.ModuleType("m4dgs.model.trained")
    mod.load_model = lambda run_dir, device="cpu", clip=None: _FakeModel(f, shifts[run_dir.name])
    monkeypatch.setitem(sys.modules, "m4dgs.model.trained", mod)
    for name in ("a", "b", "failed"):
        run = tmp_path / name
        (run / "model").mkdir(parents=True)
        mio.write_json(run / "run.json", {"clip": str(tiny_clip_realistic)})
        if name != "failed":
            (run / "model" / "final.pt").write_bytes(b"")
    png, js = tmp_path / "crf.png", tmp_path / "crf.json"
    res = CliRunner().invoke(
        main,
        [
            "crf",
            str(tmp_path / "a"),
            str(tmp_path / "b"),
            str(tmp_path / "failed"),
            "--plot",
            str(png),
            "--json",
            str(js),
            "--bands",
            "3",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "+0.20" in res.output and "-0.30" in res.output
    assert "not read" in res.output and "failed" in res.output
    assert png.read_bytes()[:4] == b"\x89PNG"
    data = json.loads(js.read_text())
    got = {r["run"].split("/")[-1]: r["shift"] for r in data["runs"]}
    assert got == pytest.approx(shifts, abs=1e-9)
    assert len(data["not_read"]) == 1 and len(data["runs"][0]["bands"]) == 3

    none = CliRunner().invoke(main, ["crf", str(tmp_path / "failed")])
    assert none.exit_code == 1 and "none of the 1 run(s)" in none.output


def test_a_clip_without_a_true_response_is_named(tiny_clip_realistic, tmp_path):
    import shutil

    from m4dgs.core.errors import InputError

    real = tmp_path / "real"
    shutil.copytree(tiny_clip_realistic, real)
    meta = json.loads((real / "clip.json").read_text())
    meta["crf"] = None  # a real clip: no true response to compare with
    (real / "clip.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"clip\.json: field 'crf'"):
        clip_ranges(Clip.open(real))
