"""`m4dgs-eval`'s grouped commands (suite, report, inspect beside score and score-frames) and the
flat names of before as hidden aliases: each old name runs the grouped command with the same
options, `--help` lists only the groups, and the names the Makefile and the docs use resolve."""

from __future__ import annotations

import re
from pathlib import Path

import click
from click.testing import CliRunner

from eval.cli import OLD_NAMES, main

ROOT = Path(__file__).resolve().parents[2]

# every flat subcommand of `m4dgs-eval` before the groups (eval/cli.py at 09b9f97)
FLAT_BEFORE = [
    "score",
    "score-frames",
    "suites",
    "run",
    "job",
    "table",
    "campaign",
    "export",
    "pairs",
    "repeats",
    "regions",
    "peaks",
    "crf",
    "region-pairs",
    "error-maps",
    "results",
]


def _get(path):
    ctx = click.Context(main)
    cmd = main
    for name in path:
        cmd = cmd.get_command(ctx, name)
        assert cmd is not None, f"no command {' '.join(path)}"
    return cmd


def test_every_flat_name_still_resolves():
    for name in FLAT_BEFORE:
        assert _get([name]) is not None


def test_old_names_are_hidden_aliases_of_the_grouped_commands():
    for old, (group, name) in OLD_NAMES.items():
        alias, grouped = _get([old]), _get([group, name])
        assert alias.hidden and not grouped.hidden
        assert alias.callback is grouped.callback
        assert [p.name for p in alias.params] == [p.name for p in grouped.params]
    assert set(OLD_NAMES) | {"score", "score-frames"} == set(FLAT_BEFORE)


def test_top_level_help_lists_the_groups_one_line_each():
    out = CliRunner().invoke(main, ["--help"], prog_name="m4dgs-eval").output
    listed = re.findall(r"^  (\S+)\s{2,}\S", out.split("Commands:")[1], flags=re.M)
    assert listed == ["calibration", "inspect", "report", "score", "score-frames", "suite"]
    assert len(out.split("Commands:")[1].strip().splitlines()) == len(listed)


def test_alias_and_grouped_command_print_the_same(tmp_path):
    """An old name and its grouped command give the same output (here: a listing and a usage
    error naming the command as it was typed)."""
    r = CliRunner()
    a = r.invoke(main, ["suites"], prog_name="m4dgs-eval")
    b = r.invoke(main, ["suite", "list"], prog_name="m4dgs-eval")
    assert a.exit_code == b.exit_code == 0 and a.output == b.output
    a = r.invoke(main, ["table", "--format", "html", "tiny"], prog_name="m4dgs-eval")
    assert a.exit_code == 2 and "Usage: m4dgs-eval table" in a.output


def test_makefile_and_campaign_files_use_names_that_resolve():
    text = (ROOT / "Makefile").read_text()
    text += "".join(p.read_text() for p in (ROOT / "eval" / "campaigns").glob("*.yaml"))
    used = set(re.findall(r"m4dgs-eval ([a-z][a-z-]*)", text))
    assert {"suite", "report"} <= used
    for name in used:
        _get([name])
