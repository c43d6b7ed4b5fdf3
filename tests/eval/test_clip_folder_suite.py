"""A suite whose scenes are existing clips (`scenes: {clips: FOLDER}`): `m4dgs-eval run` trains and
scores the rows on those clip folders as they are (nothing made, nothing copied) and `table` prints
them; a clip setting of how clips are made is refused for such a suite."""

from __future__ import annotations

import shutil

import pytest
import yaml
from click.testing import CliRunner

from eval.cli import main
from eval.experiments.runner import job_list
from eval.records.suite import SuiteError, load_eval_suite, scene_suite_names


def write_suite(path, folder="clips", short=None, **extra):
    d = {
        "name": "mine",
        "scenes": {"clips": folder},
        "rows": [
            {"name": "static-hdr", "variant": "static-hdr", "overrides": short or {}},
            {"name": "full", "variant": "full", "overrides": short or {}},
        ],
        "tables": [{"title": "my clips", "columns": "ablation"}],
        **extra,
    }
    path.write_text(yaml.safe_dump(d))
    return path


def test_a_suite_of_existing_clips_runs_and_tabulates(tiny_clip_oracle, tmp_path, short_training):
    clips = tmp_path / "clips"
    clips.mkdir()
    shutil.copytree(tiny_clip_oracle, clips / "flag-arm")
    (clips / "notes").mkdir()  # not a clip: ignored
    suite = write_suite(tmp_path / "mine.yaml", short=short_training)
    s = load_eval_suite(suite)
    assert scene_suite_names(s) == ["flag-arm"]
    jobs = job_list(s, tmp_path / "root", preset="tiny")
    assert {j.clip_dir for j in jobs} == {str(clips / "flag-arm")}
    r = CliRunner().invoke(
        main, ["run", str(suite), "--root", str(tmp_path / "root"), "--preset", "tiny"]
    )
    assert r.exit_code == 0, r.output
    assert not (tmp_path / "root" / "clips").exists()
    for row in ("static-hdr", "full"):
        assert (tmp_path / "root/runs/mine/flag-arm" / row / "metrics.json").exists()
    t = CliRunner().invoke(
        main, ["table", "--columns", "all", str(suite), "--root", str(tmp_path / "root")]
    )
    assert t.exit_code == 0, t.output
    assert "static-hdr" in t.output and "| full" in t.output


def test_clip_folder_suite_errors(tmp_path):
    (tmp_path / "empty").mkdir()
    s = load_eval_suite(write_suite(tmp_path / "a.yaml", folder="empty"))
    with pytest.raises(SuiteError, match="no clip folders"):
        scene_suite_names(s)
    with pytest.raises(SuiteError, match=r"'clips\.oracle'.*existing clips"):
        load_eval_suite(
            write_suite(tmp_path / "b.yaml", folder="empty", clips={"oracle": {"priors": "oracle"}})
        )
