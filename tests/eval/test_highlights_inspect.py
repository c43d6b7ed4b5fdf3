"""`m4dgs-eval inspect highlights`: the highlight scores on a run's training or test renders.

Renders are the ground truth times a factor chosen per exposure level, so on every frame with
highlight pixels the peak ratio is that factor and the error |log2 factor| stops, whatever pixels
the highlight mask holds: the expected figures are computed by hand from the factors."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from eval.cli import main
from eval.experiments.score_scene import true_response
from eval.inspect.highlights import run_highlights
from eval.metrics.scene_hdr import highlight_mask
from m4dgs.clip import Clip, frame_name
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError


def _renders(clip: Clip, run, split: str, factor):
    """A run folder whose `split` HDR renders are the ground truth times factor(g)."""
    frames = clip.train_frames if split == "train" else clip.test_frames
    for g in frames:
        h = (clip.load_gt_hdr(g) * factor(g)).astype(np.float32)
        mio.write_exr(run / f"renders/{split}/hdr" / frame_name(g, "exr"), h)
    return run


def _highlight_frames(clip: Clip, frames):
    crf, obs = true_response(clip), list(clip.meta.exposures.observed)
    return [g for g in frames if highlight_mask(clip.load_gt_hdr(g), crf, max(obs), min(obs)).any()]


def test_training_frames_scored_per_exposure_with_hand_computed_figures(
    tiny_clip_realistic, tmp_path
):
    clip = Clip.open(tiny_clip_realistic)
    shortest = min(clip.meta.exposures.observed)

    # 4x too bright on the shortest exposure's frames, half as bright on the others
    def factor(g):
        return 4.0 if clip.meta.train_dt_of(g) == shortest else 0.5

    hl = _highlight_frames(clip, clip.train_frames)
    assert hl, "the tiny clip needs training frames with highlight pixels for this test"
    got = run_highlights(_renders(clip, tmp_path / "run", "train", factor), clip, "train")

    factors = [factor(g) for g in hl]
    assert got["split"] == "train" and got["frames"] == len(clip.train_frames)
    assert got["highlight_frames"] == len(hl)
    assert got["highlight_stops"] == pytest.approx(np.mean([abs(math.log2(f)) for f in factors]))
    assert got["highlight_peak_ratio"] == pytest.approx(
        2.0 ** np.mean([math.log2(f) for f in factors]), rel=1e-5
    )
    levels = sorted({float(clip.meta.train_dt_of(g)) for g in hl})
    assert sorted(got["by_level"]) == levels
    for dt, v in got["by_level"].items():
        want = 4.0 if dt == shortest else 0.5
        assert v["frames"] == sum(clip.meta.train_dt_of(g) == dt for g in hl)
        assert v["peak_ratio"] == pytest.approx(want, rel=1e-5)
        assert v["stops"] == pytest.approx(abs(math.log2(want)), abs=1e-5)


def test_test_split_matches_the_scorer_and_has_no_levels(tiny_clip_realistic, tmp_path):
    from eval.experiments.score_scene import score_scene_hdr

    clip = Clip.open(tiny_clip_realistic)
    run = _renders(clip, tmp_path / "run", "test", lambda g: 3.0)
    got = run_highlights(run, clip)
    assert got["split"] == "test" and got["by_level"] == {}
    assert got["highlight_frames"] == len(_highlight_frames(clip, clip.test_frames)) > 0
    assert got["highlight_peak_ratio"] == pytest.approx(3.0, rel=1e-5)
    assert got["highlight_stops"] == pytest.approx(math.log2(3.0), abs=1e-5)

    # the scorer's figures for metrics.json, from the same renders
    class Job:
        test_hdr = True

        def render(self, sub, g, ext):
            return run / "renders" / sub / frame_name(g, ext)

    job = Job()
    job.clip = clip
    m: dict = {}
    score_scene_hdr(job, m)
    assert got["highlight_stops"] == pytest.approx(m["highlight_stops"], rel=1e-9)
    assert got["highlight_peak_ratio"] == pytest.approx(m["highlight_peak_ratio"], rel=1e-9)
    assert got["highlight_pixels"] == m["highlight_pixels"]


def test_missing_render_and_bad_split_are_named(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    run = _renders(clip, tmp_path / "run", "test", lambda g: 1.0)
    with pytest.raises(InputError, match=r"renders/train/hdr/.*missing"):
        run_highlights(run, clip, "train")
    with pytest.raises(InputError, match="split 'views'"):
        run_highlights(run, clip, "views")


def test_cli_prints_a_row_per_run_names_unread_ones_and_writes_json(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    a = _renders(clip, tmp_path / "a", "train", lambda g: 2.0)
    b = tmp_path / "b"
    b.mkdir()
    js = tmp_path / "h.json"
    r = CliRunner().invoke(
        main,
        ["inspect", "highlights", str(a), str(b), "--split", "train"]
        + ["--clip", str(tiny_clip_realistic), "--json", str(js)],
    )
    assert r.exit_code == 0, r.output
    rows = [line for line in r.output.splitlines() if line.startswith(f"| {a} ")]
    assert len(rows) == 1 and "| train |" in rows[0]
    assert "not read:" in r.output and str(b) in r.output
    got = json.loads(js.read_text())
    assert got["runs"][0]["highlight_peak_ratio"] == pytest.approx(2.0, rel=1e-5)
    assert all(isinstance(k, str) for k in got["runs"][0]["by_level"])
    # no readable run: exit status 1
    r = CliRunner().invoke(
        main, ["inspect", "highlights", str(b), "--clip", str(tiny_clip_realistic)]
    )
    assert r.exit_code == 1


def test_max_code_keeps_only_pixels_the_shortest_exposure_shows_at_or_below_it(
    tiny_clip_realistic, tmp_path
):
    from m4dgs.core.crf import tonemap_ldr

    clip = Clip.open(tiny_clip_realistic)
    crf, obs = true_response(clip), list(clip.meta.exposures.observed)
    run = _renders(clip, tmp_path / "run", "train", lambda g: 0.25)

    def count(code):  # the mask written out: saturated at the longest, <= code at the shortest
        n = 0
        for g in clip.train_frames:
            gt = clip.load_gt_hdr(g)
            long_ = tonemap_ldr(gt, max(obs), crf)
            short = tonemap_ldr(gt, min(obs), crf)
            n += int((np.any(long_ == 255, -1) & np.all(short <= code, -1)).sum())
        return n

    every = run_highlights(run, clip, "train")
    assert every["max_code"] == 254 and every["highlight_pixels"] == count(254) > 0
    codes = []
    for g in clip.train_frames:
        gt = clip.load_gt_hdr(g)
        m = highlight_mask(gt, crf, max(obs), min(obs))
        codes += list(tonemap_ldr(gt, min(obs), crf)[m].max(-1))
    cut = int(min(codes))  # keeps the pixels the shortest exposure shows lowest, drops the rest
    assert cut < max(codes), "the tiny clip's highlights need more than one code for this test"
    some = run_highlights(run, clip, "train", max_code=cut)
    assert some["highlight_pixels"] == count(cut)
    assert 0 < some["highlight_pixels"] < every["highlight_pixels"]
    assert some["highlight_peak_ratio"] == pytest.approx(0.25, rel=1e-5)
    with pytest.raises(InputError, match="max_code 255"):
        run_highlights(run, clip, "train", max_code=255)
    r = CliRunner().invoke(
        main,
        ["inspect", "highlights", str(run), "--split", "train", "--max-code", str(cut)]
        + ["--clip", str(tiny_clip_realistic)],
    )
    assert r.exit_code == 0, r.output
    assert f"| train, codes <= {cut} |" in r.output
