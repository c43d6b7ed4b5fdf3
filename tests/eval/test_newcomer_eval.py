"""What a new user of `m4dgs-eval table` met: an empty or missing experiment root must name the
folder searched, linked run and scene folders must count like real ones, and every --root option's
help must say ROOT. Fake run folders (run.json + metrics.json with known values), no training."""

from __future__ import annotations

import csv
import io
import json
import os
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from eval.cli import main

ROWS = ("static-hdr", "world-only", "full")


def _tiny_scenes():
    from eval.experiments.runner import job_list

    return list(dict.fromkeys(j.scene for j in job_list("tiny", "unused", "tiny")))


def _write_run(d: Path, row: str, scene: str, psnr: float) -> Path:
    """A scored run folder: run.json and a metrics.json whose three PSNRs are `psnr`."""
    d.mkdir(parents=True, exist_ok=True)
    (d / "run.json").write_text(json.dumps({"variant": row, "preset": "tiny"}))
    m = {
        "ldr_oe_psnr": psnr,
        "ldr_ne_psnr": psnr,
        "hdr_psnr": psnr,
        "hdr_ssim": 0.9,
        "hdr_tae": 0.1,
        "ldr_convention": "ldr_png",
        "run": {"variant": row, "preset": "tiny", "clip_name": scene},
    }
    (d / "metrics.json").write_text(json.dumps(m))
    return d


def _store(top: Path, scenes) -> dict:
    """Scored runs top/<scene>/<row> of every scene and row; their LDR-OE PSNR per row and scene:
    20 + 10 * scene index + row index."""
    vals = {}
    for i, sc in enumerate(scenes):
        for j, row in enumerate(ROWS):
            vals[(sc, row)] = 20.0 + 10 * i + j
            _write_run(top / sc / row, row, sc, vals[(sc, row)])
    return vals


def _first_table(text: str) -> dict:
    """Row name -> CSV record of the first table of `table --format csv` output."""
    lines = []
    for ln in text.splitlines():
        if ln.startswith("Method,"):
            lines = [ln]
        elif lines:
            if not ln.strip() or ln.startswith("#"):
                break
            lines.append(ln)
    return {r["Method"]: r for r in csv.DictReader(io.StringIO("\n".join(lines)))}


def _error_line(r) -> str:
    assert r.exit_code == 1, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), r.output
    return lines[0]


# --------------------------------------------------------------------------------------------------
# 1. an empty or missing root names the folder searched


def test_table_of_a_suite_under_a_missing_or_empty_root_names_the_folder_searched(
    tmp_path, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    cli = CliRunner()
    where = str(tmp_path / "out" / "runs" / "tiny")  # absolute, though --root was relative

    line = _error_line(
        cli.invoke(main, ["table", "--columns", "all", "tiny", "--root", "out", "--no-figures"])
    )
    assert f"no runs of suite 'tiny' under {where} " in line
    assert "metrics.json" in line and "the experiment root does not exist" in line
    assert "`m4dgs-eval run tiny --root out`" in line

    (tmp_path / "out").mkdir()  # the root exists, its runs folder does not
    line = _error_line(
        cli.invoke(main, ["table", "--columns", "all", "tiny", "--root", "out", "--no-figures"])
    )
    assert f"under {where} " in line and "that folder does not exist" in line

    Path(where).mkdir(parents=True)  # the suite's runs folder exists and is empty
    line = _error_line(
        cli.invoke(main, ["table", "--columns", "all", "tiny", "--root", "out", "--no-figures"])
    )
    assert f"no runs of suite 'tiny' under {where} " in line and "does not exist" not in line
    assert "`m4dgs-eval run tiny --root out`" in line

    # run folders without metrics.json: how many, where, and what to run
    scene = _tiny_scenes()[0]
    (Path(where) / scene / "full").mkdir(parents=True)
    line = _error_line(
        cli.invoke(main, ["table", "--columns", "all", "tiny", "--root", "out", "--no-figures"])
    )
    assert f"1 of the 12 run folder(s) of suite 'tiny' exist under {where} " in line
    assert "none has a metrics.json yet" in line and "m4dgs-eval run tiny --root out" in line


def test_table_of_an_empty_or_missing_runs_folder_names_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cli = CliRunner()
    (tmp_path / "runs" / "tiny" / "a-scene" / "full").mkdir(parents=True)  # no metrics.json
    line = _error_line(cli.invoke(main, ["table", "--columns", "all", "runs", "--no-figures"]))
    assert f"no scored runs under {tmp_path / 'runs'} " in line and "metrics.json" in line

    line = _error_line(
        cli.invoke(main, ["table", "--columns", "all", "nope/runs/tiny", "--no-figures"])
    )
    assert f"nope/runs/tiny: no such folder of runs ({tmp_path / 'nope' / 'runs' / 'tiny'})" in line


# --------------------------------------------------------------------------------------------------
# 2. linked run and scene folders count like real ones


def test_table_counts_linked_run_and_scene_folders(tmp_path):
    scenes = _tiny_scenes()
    assert len(scenes) == 2
    store = tmp_path / "elsewhere" / "store"
    vals = _store(store, scenes)
    root = tmp_path / "proj" / "exp"
    runs = root / "runs" / "tiny"
    # scene 0: each run folder a link (one of them relative); scene 1: the scene folder a link
    (runs / scenes[0]).mkdir(parents=True)
    for row in ROWS:
        target = store / scenes[0] / row
        if row == "full":
            target = Path(os.path.relpath(target, runs / scenes[0]))
        (runs / scenes[0] / row).symlink_to(target, target_is_directory=True)
    (runs / scenes[1]).symlink_to(store / scenes[1], target_is_directory=True)
    # a link back up the tree (a loop) and a second link to a run already linked: read once
    (runs / scenes[1] / "loop").symlink_to(runs, target_is_directory=True)
    (runs / scenes[0] / "full-again").symlink_to(store / scenes[0] / "full")

    def check(r, labels=None):  # labels: row -> its label in the table (the suite's)
        assert r.exit_code == 0, r.output
        t = _first_table(r.output)
        labels = labels or {row: row for row in ROWS}
        assert set(t) == set(labels.values()), r.output
        for row in ROWS:
            mean = sum(vals[(sc, row)] for sc in scenes) / len(scenes)
            got = t[labels[row]]
            assert got["n_runs"] == "2" and float(got["LDR-OE PSNR"]) == pytest.approx(mean)

    cli = CliRunner()
    check(
        cli.invoke(
            main, ["table", "--columns", "all", str(runs), "--format", "csv", "--no-figures"]
        )
    )
    from eval.records.suite import load_eval_suite

    labels = {r.name: r.label for r in load_eval_suite("tiny").rows}
    args = [
        "table",
        "--columns",
        "all",
        "tiny",
        "--root",
        str(root),
        "--format",
        "csv",
        "--no-figures",
    ]
    check(cli.invoke(main, args), labels)

    # a runs folder that is itself a link: its figures go beside the link, not beside its target
    link = tmp_path / "proj" / "linked-runs"
    link.symlink_to(runs, target_is_directory=True)
    r = cli.invoke(main, ["table", "--columns", "all", str(link), "--format", "csv"])
    check(r)
    assert f"figure(s) to {tmp_path / 'proj' / 'figures' / 'linked-runs'}\n" in r.output


# --------------------------------------------------------------------------------------------------
# 3. every --root option's help says ROOT


def _root_commands():
    return sorted(
        name
        for name, cmd in main.commands.items()
        if any("--root" in getattr(p, "opts", ()) for p in cmd.params)
    )


def test_the_commands_with_a_root_option_are_found():
    assert {"table", "run", "job", "export", "campaign", "region-pairs"} <= set(_root_commands())


@pytest.mark.parametrize("name", _root_commands())
def test_root_option_help_says_root_not_out(name):
    r = CliRunner().invoke(main, [name, "--help"], terminal_width=100)
    assert r.exit_code == 0, r.output
    assert re.search(r"^\s+--root(, --out)? ROOT\s", r.output, re.M), r.output
    assert not re.search(r"\bOUT\b", r.output), r.output


def test_out_stays_an_older_name_of_root(tmp_path):
    r = CliRunner().invoke(main, ["run", "tiny", "--out", str(tmp_path / "x"), "--list-jobs"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.output.splitlines()[0])["out"] == str((tmp_path / "x").resolve())
