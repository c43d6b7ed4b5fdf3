"""Focused tests of the suite definitions (eval.records.suite), the runner's job list and run
names (eval.experiments.runner) and the run folder as the scorer reads it
(eval.experiments.run_files), without training anything."""

from __future__ import annotations

import json

import pytest

from eval.experiments.run_files import read_run_info, resolve_clip_dir
from eval.experiments.runner import job_list, seed_list, seed_run_name, split_run_name
from eval.records.suite import (
    SuiteError,
    builtin_suites,
    find_eval_suite,
    load_eval_suite,
    parse_suite,
)


def test_builtin_suites_are_found_by_name():
    names = builtin_suites()
    assert {"tiny", "paper-main", "paper-ablation", "crf"} <= set(names)
    assert names == sorted(names)
    for n in names:
        assert find_eval_suite(n).stem == n
        assert load_eval_suite(n).name == n


def test_shipped_suites_sit_in_group_folders_and_are_called_by_bare_name():
    from eval.records.suite import builtin_suite_path, suite_display_path

    assert builtin_suite_path("paper-main").parent.name == "paper"
    assert builtin_suite_path("control-tlr").parent.name == "controls"
    assert builtin_suite_path("tiny").parent.name == "extra"
    p = find_eval_suite("paper-main")
    assert suite_display_path(p) == "eval/suites/paper/paper-main.yaml"
    assert find_eval_suite(p) == p  # a path still works
    assert load_eval_suite(str(p)).name == "paper-main"


def test_two_shipped_suites_with_one_name_are_an_error_naming_both(tmp_path, monkeypatch):
    import eval.records.suite as suite_mod

    for group in ("paper", "extra"):
        (tmp_path / group).mkdir()
        (tmp_path / group / "twin.yaml").write_text("name: twin\n")
    monkeypatch.setattr(suite_mod, "suites_dir", lambda: tmp_path)
    with pytest.raises(SuiteError) as e:
        suite_mod.builtin_suites()
    msg = str(e.value)
    assert str(tmp_path / "paper" / "twin.yaml") in msg
    assert str(tmp_path / "extra" / "twin.yaml") in msg


def test_unknown_suite_names_the_shipped_ones():
    with pytest.raises(SuiteError) as e:
        find_eval_suite("no-such-suite")
    assert "tiny" in str(e.value)


@pytest.mark.parametrize(
    "d, key",
    [
        ([], "<root>"),
        ({"name": "x", "scenes": "tiny"}, "rows"),
        ({"name": "x/y", "scenes": "tiny", "rows": []}, "name"),
        ({"name": "x", "scenes": "tiny", "rows": [], "colour": 1}, "colour"),
    ],
)
def test_parse_suite_names_the_bad_key(d, key):
    with pytest.raises(SuiteError) as e:
        parse_suite(d, "s.yaml")
    assert key in str(e.value) and "s.yaml" in str(e.value)


@pytest.mark.parametrize("row, seed", [("full", 0), ("full", 2), ("no-tlr-seed-x", 0), ("a", 11)])
def test_run_names_round_trip(row, seed):
    assert split_run_name(seed_run_name(row, seed)) == (row, seed)
    assert seed_run_name(row, 0) == row


def test_job_list_covers_scenes_rows_and_seeds(tmp_path):
    s = load_eval_suite("tiny")
    one = job_list("tiny", tmp_path, "tiny")
    two = job_list("tiny", tmp_path, "tiny", seeds=2)
    assert len(one) * 2 == len(two)
    assert {j.row for j in one} == {r.name for r in s.rows}
    assert all(j.seed == 0 for j in one) and {j.seed for j in two} == {0, 1}
    seed1 = [j for j in two if j.seed == 1]
    assert all(j.run_dir.endswith(seed_run_name(j.row, 1)) for j in seed1)
    with pytest.raises(ValueError):
        job_list("tiny", tmp_path, "huge")


def test_job_list_takes_a_list_of_seeds(tmp_path):
    """seeds=[2, 3]: exactly the jobs of seeds 2 and 3 of seeds=4 (folders <row>-seed-2, trainer
    seed the row's + 2), for a confirmatory run at seeds no earlier run used."""
    four = job_list("tiny", tmp_path, "tiny", seeds=4)
    late = job_list("tiny", tmp_path, "tiny", seeds=[3, 2])
    assert [j.id for j in late] == [j.id for j in four if j.seed >= 2]
    assert {j.seed for j in late} == {2, 3}
    j = late[0]
    assert j.run_dir.endswith(seed_run_name(j.row, 2)) and j.overrides["seed"] == 2
    assert job_list("tiny", tmp_path, "tiny", seeds=[0, 1]) == job_list(
        "tiny", tmp_path, "tiny", seeds=2
    )
    assert seed_list(3) == [0, 1, 2] and seed_list((5,)) == [5]
    for bad in (0, -1, True, [], [1, 1], [-1], [1.5], "2", None):
        with pytest.raises(ValueError, match="seeds"):
            seed_list(bad)


def test_job_list_rows_subset(tmp_path):
    """--rows keeps the named rows of every scene and seed, in the suite's order; a row the suite
    lacks is named in the error, with the rows it has."""
    s = load_eval_suite("tiny")
    names = [r.name for r in s.rows]
    pick = [names[-1], names[0]]
    two = job_list("tiny", tmp_path, "tiny", seeds=2, rows=pick)
    every = job_list("tiny", tmp_path, "tiny", seeds=2)
    assert [j.id for j in two] == [j.id for j in every if j.row in pick]
    assert {j.row for j in two} == set(pick) and {j.seed for j in two} == {0, 1}
    with pytest.raises(ValueError, match="no-such-row") as e:
        job_list("tiny", tmp_path, "tiny", rows=["no-such-row"])
    assert names[0] in str(e.value)


def test_resolve_clip_dir(tmp_path):
    run, clip = tmp_path / "run", tmp_path / "clip"
    run.mkdir()
    clip.mkdir()
    (clip / "clip.json").write_text("{}")
    assert read_run_info(run) == {}
    with pytest.raises(FileNotFoundError):
        resolve_clip_dir(run)
    assert resolve_clip_dir(run, clip) == clip
    (run / "run.json").write_text(json.dumps({"clip": "../clip"}))
    assert resolve_clip_dir(run).resolve() == clip.resolve()
    (run / "run.json").write_text(json.dumps({"clip": str(clip)}))
    assert resolve_clip_dir(run) == clip


def test_suite_run_rows_option_filters_the_job_list(tmp_path):
    from click.testing import CliRunner

    from eval.cli import main

    rows = [r.name for r in load_eval_suite("tiny").rows]
    args = ["suite", "run", "tiny", "--root", str(tmp_path), "--preset", "tiny", "--list-jobs"]
    r = CliRunner().invoke(main, args + ["--rows", f"{rows[0]}, {rows[-1]}"])
    assert r.exit_code == 0, r.output
    got = [json.loads(line)["row"] for line in r.output.splitlines()]
    n_scenes = len({j.scene for j in job_list("tiny", tmp_path, "tiny")})
    assert got == [rows[0], rows[-1]] * n_scenes
    r = CliRunner().invoke(main, args + ["--rows", "nope"])
    assert r.exit_code != 0 and "nope" in r.output
