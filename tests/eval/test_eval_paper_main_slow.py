"""The paper's main table end to end on this CPU: `eval run paper-main --preset tiny`, then `eval
table`.

Slow (about 40-50 minutes on 2 cores: 9 scenes x 5 methods); run with `pytest -m slow`.
"""

from __future__ import annotations

import re

import pytest
from click.testing import CliRunner


@pytest.mark.slow
def test_paper_main_tiny_complete_table(tmp_path):
    from eval.cli import main

    runner = CliRunner()
    res = runner.invoke(
        main, ["run", "paper-main", "--preset", "tiny", "--out", str(tmp_path), "--device", "cpu"]
    )
    assert res.exit_code == 0, res.output
    res = runner.invoke(main, ["table", "paper-main", "--root", str(tmp_path), "--no-figures"])
    assert res.exit_code == 0, res.output
    text = res.output
    first = text.split("**", 2)[2].split("\n\n")[1]  # the first table's Markdown body
    rows = [
        line
        for line in first.splitlines()
        if line.startswith("| ") and not line.startswith("| Method")
    ]
    assert len(rows) == 5, first
    heads = [c.strip() for c in first.splitlines()[0].strip("|").split("|")]
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[1] == "9", row  # n = 9 scenes x 1 seed
        values = [c for h, c in zip(heads[2:], cells[2:]) if not h.startswith("Δ")]
        # every PSNR/SSIM/TAE cell is "mean ± CI half-width" (LPIPS is n/a without a weights file)
        numeric = [c for c in values if c != "n/a"]
        assert len(numeric) >= 7, row
        assert all(re.fullmatch(r"\*{0,2}-?[0-9.]+\*{0,2} ± [0-9.]+", c) for c in numeric), row
        diffs = [c for h, c in zip(heads[2:], cells[2:]) if h.startswith("Δ")]
        assert (
            all(c == "ref" for c in diffs)
            if cells[0].endswith("(full)")
            else all(re.fullmatch(r"([-+][0-9.]+ ± [0-9.]+†?|n/a)", c) for c in diffs)
        ), row
    assert "mu-law" in text and "HDR-TAE" in text  # conventions footnote
    assert "Student-t 95 %" in text and "paper / ours / agree" in text
