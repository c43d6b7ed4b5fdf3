"""The paper's main table end to end on this CPU: `eval run paper-main --preset tiny`, then `eval table`.

Slow (about 30-40 minutes on 2 cores: 9 scenes x 4 methods); run with `pytest -m slow`.
"""
from __future__ import annotations

import re

import pytest
from click.testing import CliRunner


@pytest.mark.slow
def test_paper_main_tiny_complete_table(tmp_path):
    from eval.cli import main

    runner = CliRunner()
    res = runner.invoke(main, ["run", "paper-main", "--preset", "tiny", "--out", str(tmp_path), "--device", "cpu"])
    assert res.exit_code == 0, res.output
    res = runner.invoke(main, ["table", "paper-main", "--root", str(tmp_path), "--no-figures"])
    assert res.exit_code == 0, res.output
    text = res.output
    first = text.split("**", 2)[2].split("\n\n")[1]  # the first table's Markdown body
    rows = [line for line in first.splitlines() if line.startswith("| ") and not line.startswith("| Method")]
    assert len(rows) == 4, first
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        # every PSNR/SSIM/TAE cell is a number (LPIPS is n/a without a weights file)
        numeric = [c for c in cells[1:] if c != "n/a"]
        assert len(numeric) >= 7, row
        assert all(re.fullmatch(r"\*{0,2}-?[0-9.]+\*{0,2}", c) for c in numeric), row
    assert "mu-law" in text and "HDR-TAE" in text  # conventions footnote
