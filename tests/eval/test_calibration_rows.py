"""Calibration rows as a suite row kind (`calibration: ROW`): parsed and checked like other rows,
carried into the job list, and run by the runner as a prediction scored like another method's
frames, not a training. The copy-nearest run is checked against the clip itself: each test frame's
HDR is the nearest training frame's radiance through the run's own estimated response, and its
LDR-OE PSNR is the mean PSNR of its LDR files computed here with numpy."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from eval.calibration import ROWS, SEED_FREE_ROWS, TEMPORAL_ROWS
from eval.experiments.runner import job_list, run_job
from eval.records.suite import SuiteError, load_eval_suite
from m4dgs.clip import Clip, frame_name, level_name
from m4dgs.core import io as mio


def _suite(path, rows, folder="clips"):
    d = {
        "name": "cal",
        "scenes": {"clips": folder},
        "rows": rows,
        "tables": [{"title": "t", "columns": "ablation"}],
    }
    path.write_text(yaml.safe_dump(d))
    return path


def _suite_of_one_clip(tmp_path, rows):
    """The loaded suite `cal` of ROWS on one (empty) clip folder, tmp_path/clips/a."""
    (tmp_path / "clips" / "a").mkdir(parents=True)
    (tmp_path / "clips" / "a" / "clip.json").write_text("{}")
    return load_eval_suite(_suite(tmp_path / "s.yaml", rows))


def test_calibration_rows_parse_and_train_nothing(tmp_path):
    s = _suite_of_one_clip(
        tmp_path,
        [
            {"name": "full", "variant": "full"},
            {"calibration": "copy-nearest", "label": "2D copy"},
            {"name": "warp", "calibration": "flow-merge"},
        ],
    )
    assert [r.name for r in s.rows] == ["full", "copy-nearest", "warp"]
    assert [r.calibration for r in s.rows] == [None, "copy-nearest", "flow-merge"]
    assert s.rows[1].variant == "calibration" and s.rows[1].label == "2D copy"
    assert s.variants == ["full"]  # what the trainer must know
    jobs = job_list(s, tmp_path / "root", preset="tiny", seeds=2)
    assert [(j.row, j.seed, j.calibration) for j in jobs][:3] == [
        ("full", 0, None),
        ("copy-nearest", 0, "copy-nearest"),
        ("warp", 0, "flow-merge"),
    ]
    assert jobs[-1].calibration == "flow-merge" and jobs[-1].seed == 1
    assert set(ROWS) == {"copy-nearest", "flow-merge", "dibr"}
    # the tables count a seed-free row's scene once: the entries of both sources say which rows
    # those are (copy-nearest and flow-merge predict the same frames for every seed; dibr's camera
    # initialisation is seeded)
    from eval.experiments.collect import collect_suite
    from eval.records.suite_data import suite_data

    seed_free = {"full": False, "copy-nearest": True, "warp": True}
    ent = collect_suite(s, tmp_path / "root", preset="tiny", seeds=2)
    assert {e["row"]: e["same_every_seed"] for e in ent} == seed_free
    csv_rows = [
        {"suite": "cal", "scene": "a", "row": r, "seed": k, "status": "scored", "ldr_oe_psnr": 20.0}
        for r in seed_free
        for k in (0, 1)
    ]
    ent = suite_data("cal", csv_rows, definitions={"cal": s}).entries
    assert {e["row"]: e["same_every_seed"] for e in ent} == seed_free
    # the table counts their scene once and says so; with one seed there is nothing to say
    from eval.records.suite_data import build_tables

    text = build_tables(ent, s.tables, "markdown", "full")
    assert "| 2D copy | 1 |" in text and "| full | 2 |" in text
    assert "2D copy, warp: 2D calibration rows" in text
    assert "where they have values; one prediction for every trainer seed" in text
    text = build_tables([e for e in ent if e["seed"] == 0], s.tables, "markdown", "full")
    assert "| 2D copy | 1 |" in text and "one prediction for every trainer seed" not in text
    assert SEED_FREE_ROWS == TEMPORAL_ROWS


@pytest.mark.parametrize(
    "row, match",
    [
        ({"calibration": "nearest"}, "unknown calibration row 'nearest'"),
        ({"calibration": "dibr", "variant": "full"}, r"rows\[0\]\.variant.*trains nothing"),
        ({"calibration": "dibr", "overrides": {"seed": 1}}, r"rows\[0\]\.overrides"),
    ],
)
def test_calibration_row_errors_name_the_key(tmp_path, row, match):
    with pytest.raises(SuiteError, match=match):
        load_eval_suite(_suite(tmp_path / "s.yaml", [row]))


def _psnr(a, b):
    mse = float(np.mean((a / 255.0 - b / 255.0) ** 2))  # 8-bit images, data range 1
    return min(100.0, 10 * math.log10(1.0 / mse)) if mse > 0 else 100.0


def test_runner_predicts_and_scores_a_calibration_row(tiny_clip_oracle, tmp_path):
    clips = tmp_path / "clips"
    clips.mkdir()
    shutil.copytree(tiny_clip_oracle, clips / "flag")
    s = load_eval_suite(
        _suite(tmp_path / "s.yaml", [{"calibration": r} for r in TEMPORAL_ROWS], "clips")
    )
    jobs = job_list(s, tmp_path / "root", preset="tiny")
    res = run_job(jobs[0])
    assert res["steps"] == ["predict", "score"]
    run = tmp_path / "root/runs/cal/flag/copy-nearest"
    m = mio.read_json(run / "metrics.json")
    info = mio.read_json(run / "run.json")
    assert info["external"] and info["variant"] == "copy-nearest"
    # filed at the preset of the runs it is compared with (the runs CSV's preset column)
    assert info["preset"] == "tiny" and m["run"]["preset"] == "tiny"
    g_resp = np.asarray(mio.read_json(run / "response.json")["g"])  # [3, 256] natural log
    assert g_resp.shape == (3, 256)

    clip = Clip.open(clips / "flag")
    train = list(clip.train_frames)
    dts = clip.meta.exposures
    for g in clip.test_frames:
        j = int(np.argmin([abs(t - g) + 1e-9 * (t > g) for t in train]))
        # the nearest training frame's radiance through the run's response, written here:
        # codes -> exp(g[code]) / dt
        codes = np.asarray(clip.load_ldr(train[j]), np.int64)
        ref = np.stack([np.exp(g_resp[c][codes[..., c]]) for c in range(3)], -1)
        ref /= float(clip.train_dt[j])
        pred = mio.read_exr(run / "renders/test/hdr" / frame_name(g, "exr"))
        assert np.allclose(pred, ref, rtol=1e-4), g
    vals = [
        _psnr(
            mio.read_png(run / "renders/test/ldr" / level_name(lv) / frame_name(g, "png")),
            clip.load_gt_ldr(lv, g),
        )
        for lv in dts.observed
        for g in clip.test_frames
    ]
    assert m["ldr_oe_psnr"] == pytest.approx(float(np.mean(vals)), abs=1e-6)
    assert m["ldr_oe_psnr"] > 15  # a copy of the neighbour, not noise
    assert m["hdr_tae"] is None and m["train_minutes"] is None  # no training frames, no training

    # done once: a second call scores nothing again
    assert run_job(jobs[0])["steps"] == []
    # flow-merge as well
    assert run_job(jobs[1])["steps"] == ["predict", "score"]
    assert (tmp_path / "root/runs/cal/flag/flow-merge/metrics.json").exists()


def test_calibration_command_writes_test_frames_and_the_same_images_at_the_views(
    tiny_clip_oracle, tmp_path
):
    from click.testing import CliRunner

    from eval.cli import main

    out = tmp_path / "pred"
    r = CliRunner().invoke(
        main, ["calibration", str(tiny_clip_oracle), "copy-nearest", "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    assert "score-frames" in r.output
    clip = Clip.open(tiny_clip_oracle)
    views = clip.view_names()
    assert views  # generator 7 clips carry held-out views
    g = clip.test_frames[0]
    lv = clip.meta.exposures.observed[0]
    a = (out / "test/hdr" / frame_name(g, "exr")).read_bytes()
    for v in views:
        # a 2D row has no viewpoint: the view's image is its test frame's
        assert (out / "views" / v / "hdr" / frame_name(g, "exr")).read_bytes() == a
        assert (out / "views" / v / "ldr" / level_name(lv) / frame_name(g, "png")).read_bytes() == (
            out / "test/ldr" / level_name(lv) / frame_name(g, "png")
        ).read_bytes()
    assert mio.read_json(out / "response.json")["row"] == "copy-nearest"
    bad = CliRunner().invoke(main, ["calibration", str(tiny_clip_oracle), "nearest", "--out", "x"])
    assert bad.exit_code == 2 and "copy-nearest" in bad.output


def test_a_seed_free_row_predicts_once_and_copies_for_the_other_seeds(
    tiny_clip_oracle, tmp_path, monkeypatch
):
    """copy-nearest at two trainer seeds: seed 0 is predicted and scored, seed 1 is a copy of it
    (metrics, response, run.json naming its source; renders linked), with no second prediction."""
    import eval.experiments.calibration_rows as cr

    clips = tmp_path / "clips"
    clips.mkdir()
    shutil.copytree(tiny_clip_oracle, clips / "flag")
    s = load_eval_suite(_suite(tmp_path / "s.yaml", [{"calibration": "copy-nearest"}], "clips"))
    made = []
    real = cr.make_calibration_run
    monkeypatch.setattr(cr, "make_calibration_run", lambda *a, **k: made.append(a) or real(*a, **k))
    jobs = job_list(s, tmp_path / "root", preset="tiny", seeds=2)
    assert [j.seed for j in jobs] == [0, 1]
    assert run_job(jobs[0])["steps"] == ["predict", "score"]
    assert run_job(jobs[1])["steps"] == ["copy"]
    assert len(made) == 1
    first, other = (Path(j.run_dir) for j in jobs)
    assert other.name == "copy-nearest-seed-1"
    for f in ("metrics.json", "response.json"):
        assert (other / f).read_bytes() == (first / f).read_bytes()
    info = mio.read_json(other / "run.json")
    assert info["same_as"] == "../copy-nearest" and info["calibration"] == "copy-nearest"
    assert (other / "renders").is_symlink()
    assert sorted(p.name for p in (other / "renders").iterdir()) == sorted(
        p.name for p in (first / "renders").iterdir()
    )
    # done: run again, nothing happens; without seed 0's run a seed is predicted as before
    assert run_job(jobs[1])["steps"] == []
    shutil.rmtree(first)
    (other / "metrics.json").unlink()
    assert run_job(jobs[1])["steps"] == ["predict", "score"] and len(made) == 2
    assert not (other / "renders").is_symlink()


def test_the_provenance_of_a_2d_row_is_no_code_not_an_unrecorded_one():
    """The results page's provenance line: a calibration row trains nothing, so its m4dgs code and
    torch threads read "none (2D rows)", not "not recorded" (a run that should have said)."""
    from eval.records.suite_data import suite_data

    base = {"suite": "nv-main", "scene": "lamp-room-orbit", "seed": 0, "status": "scored"}
    rows = [
        {**base, "row": "full", "variant": "full", "code": "abcdef012345", "torch_threads": "1"},
        {**base, "row": "copy-nearest", "variant": "calibration", "code": "", "generator": "7"},
        {**base, "row": "world-only", "variant": "world-only", "code": ""},
    ]
    d = suite_data("nv-main", rows)
    assert d.provenance("code") == {
        "abcdef012345": 1,
        "none (2D rows)": 1,
        "not recorded": 1,
    }
    assert d.provenance("torch_threads") == {"1": 1, "none (2D rows)": 1, "not recorded": 1}
    assert d.provenance("host") == {"not recorded": 3}
    assert d.provenance("generator") == {"7": 1, "not recorded": 2}


def test_a_2d_row_appears_only_in_the_tables_where_it_has_values(tmp_path):
    """A calibration row has no training time, cameras or training-frame renders: a table of those
    leaves it out (a trained row without values stays, as n/a: its missing value is news), and the
    footnote naming the 2D rows follows the rows the table shows. Both entry sources (a suite's
    definition, a CSV without one) know which rows are 2D."""
    from eval.records.suite import TableDef
    from eval.records.suite_data import build_tables, suite_data

    s = _suite_of_one_clip(
        tmp_path,
        [
            {"name": "full", "variant": "full"},
            {"name": "no-tlr", "variant": "no-tlr"},
            {"name": "copy-nearest", "label": "2D copy", "calibration": "copy-nearest"},
        ],
    )
    base = {"suite": "cal", "status": "scored"}
    rows = []
    for sc, k in [("a", 0), ("a", 1), ("b", 0), ("b", 1)]:
        psnr = {"full": 30.0 + k, "no-tlr": 29.0, "copy-nearest": 28.0}
        for rn in psnr:
            r = {**base, "scene": sc, "seed": k, "row": rn, "ldr_oe_psnr": psnr[rn]}
            r["variant"] = "calibration" if rn == "copy-nearest" else rn
            if rn == "full":
                r["train_minutes"] = 10.0
            rows.append(r)
    defs = [TableDef("frames", ["ldr_oe_psnr"]), TableDef("cost", ["train_minutes"])]
    for ent in (
        suite_data("cal", rows, definitions={"cal": s}).entries,
        suite_data("cal", rows, definitions={}).entries,
    ):
        assert {e["row"]: bool(e["calibration"]) for e in ent} == {
            "full": False,
            "no-tlr": False,
            "copy-nearest": True,
        }
        frames, cost = build_tables(ent, defs, "markdown", "full").split("**cost**")
        label = next(e["label"] for e in ent if e["row"] == "copy-nearest")
        assert f"| {label} |" in frames and "2D calibration rows" in frames
        assert f"| {label} |" not in cost and "2D calibration rows" not in cost
        assert "| no-tlr |" in cost and "n/a" in cost.split("| no-tlr |")[1].split("\n")[0]
        # its Δ in the frames table pairs it with the reference's runs: 28 - mean(30, 31)
        cells = frames.split(f"| {label} |")[1].split("|")
        assert cells[2].strip().startswith("-2.50")
    # a 2D row without any scored run yet stays in every table, n/a, like a trained row
    ent = suite_data("cal", [r for r in rows if r["row"] != "copy-nearest"], {"cal": s}).entries
    cost = build_tables(ent, defs, "markdown", "full").split("**cost**")[1]
    assert "| 2D copy |" in cost and "2D calibration rows" not in cost
