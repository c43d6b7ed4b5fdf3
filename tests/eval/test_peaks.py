"""`m4dgs-eval peaks`: the largest HDR value of a run's test renders against the ground truth's.

Renders are the ground truth with planted runaways, so every figure has a hand-computed answer."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from eval.cli import main
from eval.inspect.peaks import run_peaks
from m4dgs.clip import Clip, frame_name
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError


def _renders(clip: Clip, run, plant=None):
    """A run folder whose test HDR renders are the ground truth, with plant(g, h) applied."""
    for g in clip.test_frames:
        h = clip.load_gt_hdr(g).astype(np.float32).copy()
        if plant is not None:
            plant(g, h)
        mio.write_exr(run / "renders/test/hdr" / frame_name(g, "exr"), h)
    return run


def test_a_faithful_run_reads_one_and_a_planted_runaway_its_size(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    gt_max = max(float(np.max(clip.load_gt_hdr(g))) for g in clip.test_frames)
    n_values = sum(clip.load_gt_hdr(g).size for g in clip.test_frames)

    same = run_peaks(_renders(clip, tmp_path / "same"), clip)
    assert same["gt_max"] == pytest.approx(gt_max, rel=1e-6)
    assert same["ratio"] == pytest.approx(1.0, rel=1e-6)
    assert same["share_above"] == 0.0 and same["nonfinite"] == 0
    assert same["frames"] == len(clip.test_frames)

    # one test frame: a 3 x 4 block of one channel at 5,000 x the truth's largest value, and one
    # NaN (left out of the maximum, counted)
    g0 = clip.test_frames[1]

    def plant(g, h):
        if g == g0:
            h[2:5, 3:7, 1] = 5000.0 * gt_max
            h[0, 0, 0] = np.nan

    bad = run_peaks(_renders(clip, tmp_path / "bad", plant), clip)
    assert bad["ratio"] == pytest.approx(5000.0, rel=1e-5)
    assert bad["render_max"] == pytest.approx(5000.0 * gt_max, rel=1e-5)
    assert bad["share_above"] == pytest.approx(12 / n_values)
    assert bad["nonfinite"] == 1

    # an overflowed value: an infinite ratio, counted as non-finite
    def inf(g, h):
        if g == g0:
            h[1, 1, 2] = np.inf

    assert run_peaks(_renders(clip, tmp_path / "inf", inf), clip)["ratio"] == np.inf
    # ... which the JSON file holds as null (standard JSON)
    js = tmp_path / "inf.json"
    r = CliRunner().invoke(
        main,
        ["peaks", str(tmp_path / "inf"), "--clip", str(tiny_clip_realistic), "--json", str(js)],
    )
    assert r.exit_code == 0, r.output
    got = json.loads(js.read_text(), parse_constant=lambda c: pytest.fail(f"non-standard {c}"))
    assert got["runs"][0]["ratio"] is None and got["runs"][0]["nonfinite"] == 1


def test_cli_prints_a_row_per_run_and_names_the_runs_it_cannot_read(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    gt_max = max(float(np.max(clip.load_gt_hdr(g))) for g in clip.test_frames)

    def double(g, h):
        h *= 2.0

    a, b = _renders(clip, tmp_path / "a"), _renders(clip, tmp_path / "b", double)
    js = tmp_path / "peaks.json"
    args = ["peaks", str(a), str(b), "--clip", str(tiny_clip_realistic), "--json", str(js)]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    rows = [ln for ln in r.output.splitlines() if ln.startswith(f"| {tmp_path}")]
    assert len(rows) == 2 and rows[0].split("|")[6].strip() == "1"
    assert rows[1].split("|")[6].strip() == "2"
    got = json.loads(js.read_text())["runs"]
    assert [x["gt_max"] for x in got] == pytest.approx([gt_max, gt_max], rel=1e-6)

    (b / "renders/test/hdr" / frame_name(clip.test_frames[0], "exr")).unlink()
    r = CliRunner().invoke(main, ["peaks", str(b), "--clip", str(tiny_clip_realistic)])
    assert r.exit_code == 1 and frame_name(clip.test_frames[0], "exr") in r.output
    assert "none of the 1 run(s) could be read" in r.output
    with pytest.raises(InputError, match="missing"):
        run_peaks(b, clip)

    # a failed run (no renders, failure.json) beside a good one: named with its error, the good
    # one's row printed, exit 0
    from eval.experiments.runner import record_failure

    failed = tmp_path / "failed"
    failed.mkdir()
    record_failure(failed, "training: stage2: step 7: the HDR render holds NaN")
    r = CliRunner().invoke(main, ["peaks", str(a), str(failed), "--clip", str(tiny_clip_realistic)])
    assert r.exit_code == 0, r.output
    assert sum(ln.startswith(f"| {tmp_path}") for ln in r.output.splitlines()) == 1
    assert f"not read: {failed}: no test renders; its last attempt failed: training: stage2" in (
        r.output
    )
