"""A walk over every command of the three tools (m4dgs, benchgen, m4dgs-eval): `--help` works and
explains every option, an unknown option is a usage error (exit 2, one line), `--version` prints
the package version."""

from __future__ import annotations

import click
import pytest
from click.testing import CliRunner

from benchgen.cli import main as benchgen_main
from eval.cli import main as eval_main
from m4dgs.cli import main as m4dgs_main
from m4dgs.core.errors import package_version

TOOLS = {"m4dgs": m4dgs_main, "benchgen": benchgen_main, "m4dgs-eval": eval_main}


def _commands(group: click.Group, path=()):
    """(path, command) of every command and sub-command of a group."""
    for name, cmd in group.commands.items():
        yield (*path, name), cmd
        if isinstance(cmd, click.Group):
            yield from _commands(cmd, (*path, name))


CASES = [(tool, path, cmd) for tool, g in TOOLS.items() for path, cmd in _commands(g)]


@pytest.mark.parametrize("tool", TOOLS)
def test_version(tool):
    r = CliRunner().invoke(TOOLS[tool], ["--version"], prog_name=tool)
    assert r.exit_code == 0 and r.output.strip() == f"{tool} (mono4dgs-hdr) {package_version()}"


@pytest.mark.parametrize("tool, path, cmd", CASES, ids=[" ".join((t, *p)) for t, p, _ in CASES])
def test_help_explains_every_option_and_unknown_options_are_usage_errors(tool, path, cmd):
    runner = CliRunner()
    r = runner.invoke(TOOLS[tool], [*path, "--help"], prog_name=tool)
    assert r.exit_code == 0 and "Usage:" in r.output, r.output
    assert (cmd.help or "").strip(), f"{tool} {' '.join(path)} has no description"
    undocumented = [
        p.opts[0]
        for p in cmd.params
        if isinstance(p, click.Option) and not p.hidden and not (p.help or "").strip()
    ]
    assert not undocumented, f"{tool} {' '.join(path)}: options without help {undocumented}"
    r = runner.invoke(TOOLS[tool], [*path, "--no-such-option"], prog_name=tool)
    assert r.exit_code == 2 and "No such option" in r.output and "Traceback" not in r.output


# bad arguments: (tool, arguments, a fragment of the one-line message); every one is a click usage
# error (exit 2) raised before any work
BAD_ARGUMENTS = [
    ("m4dgs", ["train", "--clip", "/nonexistent/clip", "--out", "x"], "does not exist"),
    ("m4dgs", ["train", "--clip", ".", "--preset", "huge"], "'huge' is not one of"),
    ("m4dgs", ["train", "--clip", ".", "--set", "no-equals-sign"], "expected KEY=VALUE"),
    ("m4dgs", ["export-ply", ".", "--frame", "ten", "--out", "a.ply"], "'ten' is not a valid"),
    ("m4dgs", ["variants", "--preset", "medium"], "'medium' is not one of"),
    ("benchgen", ["make", "--exposures", "5"], "'5' is not one of"),
    ("benchgen", ["make", "--schedule", "sometimes"], "'sometimes' is not one of"),
    ("benchgen", ["make", "--spp", "0"], "0 is not in the range"),
    ("m4dgs-eval", ["table", "tiny", "--format", "pdf"], "'pdf' is not one of"),
    ("m4dgs-eval", ["table", "tiny", "--seeds", "0"], "'0': expected a count N >= 1"),
    ("m4dgs-eval", ["table", "tiny", "--seeds", "2,2"], "list of distinct seeds >= 0"),
]


@pytest.mark.parametrize(
    "tool, args, needle", BAD_ARGUMENTS, ids=[" ".join((t, *a[:2])) for t, a, _ in BAD_ARGUMENTS]
)
def test_bad_arguments_are_one_line_usage_errors(tool, args, needle, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(TOOLS[tool], args, prog_name=tool)
    assert r.exit_code == 2, r.output
    assert needle in r.output and "Traceback" not in r.output
