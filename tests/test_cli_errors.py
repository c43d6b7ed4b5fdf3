"""Every tool reports the project's own errors in one line (exit 1), usage errors through click
(exit 2), and shows the traceback only with --debug (m4dgs.core.errors.ReportingGroup)."""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from benchgen.cli import main as benchgen_main
from eval.cli import main as eval_main
from m4dgs.cli import main as m4dgs_main
from m4dgs.clip import ClipError


@pytest.fixture
def not_a_clip(tmp_path):
    d = tmp_path / "not-a-clip"
    d.mkdir()
    return d


def test_data_error_is_one_line_exit_1(not_a_clip, tmp_path):
    r = CliRunner().invoke(
        m4dgs_main, ["train", "--clip", str(not_a_clip), "--out", str(tmp_path / "r")]
    )
    assert r.exit_code == 1
    assert "Traceback" not in r.output
    lines = [ln for ln in r.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error: ") and "clip.json" in lines[0]


def test_debug_shows_the_exception(not_a_clip, tmp_path):
    r = CliRunner().invoke(
        m4dgs_main, ["--debug", "train", "--clip", str(not_a_clip), "--out", str(tmp_path / "r")]
    )
    assert r.exit_code != 0 and isinstance(r.exception, ClipError)


def test_usage_error_exit_2(not_a_clip):
    r = CliRunner().invoke(m4dgs_main, ["train", "--clip", str(not_a_clip), "--preset", "huge"])
    assert r.exit_code == 2 and "huge" in r.output


@pytest.mark.parametrize(
    "main, args, needle",
    [
        (
            benchgen_main,
            ["make", "--suite", "/nonexistent/suite.yaml", "--out", "OUT"],
            "suite.yaml",
        ),
        (eval_main, ["table", "no-such-suite"], "no-such-suite"),
    ],
)
def test_other_tools_report_in_one_line(main, args, needle, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 1, r.output
    assert "Traceback" not in r.output and needle in r.output


HOLD = """
import sys, time
from m4dgs.core.lock import FolderLock
with FolderLock(sys.argv[1]):
    print("locked", flush=True)
    time.sleep(60)
"""


def test_second_writer_of_a_run_is_refused(tiny_clip_oracle, tmp_path):
    """A run folder another live process writes is refused by train (also with --force, which
    must not delete it) and by the renderer, naming that process. (A real clip: a folder that is
    no clip is refused before any run folder is looked at.)"""
    import subprocess
    import sys

    from m4dgs.core.errors import RunInUseError
    from m4dgs.outputs.render import render_run

    run = tmp_path / "run"
    p = subprocess.Popen([sys.executable, "-c", HOLD, str(run)], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "locked"
        for extra in ([], ["--force"]):
            r = CliRunner().invoke(
                m4dgs_main, ["train", "--clip", str(tiny_clip_oracle), "--out", str(run), *extra]
            )
            assert r.exit_code == 1 and f"process {p.pid}" in r.output, r.output
            assert run.exists()
        with pytest.raises(RunInUseError, match=str(p.pid)):
            render_run(run, progress=False)
    finally:
        p.kill()
        p.wait()


def test_train_threads_option(not_a_clip, tmp_path):
    """--threads is checked by click, and a training command leaves the process's thread counts
    as they were (it holds its split only while it trains)."""
    import torch

    from m4dgs.core import threads

    r = CliRunner().invoke(m4dgs_main, ["train", "--clip", str(not_a_clip), "--threads", "0"])
    assert r.exit_code == 2 and "--threads" in r.output
    before = (torch.get_num_threads(), threads.kernel_threads())
    r = CliRunner().invoke(
        m4dgs_main,
        ["train", "--clip", str(not_a_clip), "--out", str(tmp_path / "r"), "--threads", "3"],
    )
    assert r.exit_code == 1 and "clip.json" in r.output
    assert (torch.get_num_threads(), threads.kernel_threads()) == before
