"""The paper's main table end to end on this CPU: `eval run paper-main --preset tiny`, then `eval
table` (the compact table and every table).

Slow (26 minutes on 2 cores, 2026-12-06: 9 scenes x 5 trained rows and 2 calibration rows); run with
`pytest -m slow`. Its own time limit replaces the 10 minutes the configuration gives a test
(pyproject.toml), which it would always exceed.
"""

from __future__ import annotations

import re

import pytest
from click.testing import CliRunner

# the first table's rows: the suite's five trained rows, then its two 2D calibration rows, which
# have no temporal or cost figures (docs/eval.md, "Calibration rows")
TRAINED, CALIBRATION = 5, 2


def check_first_table(text: str) -> None:
    """The first table of `eval table paper-main` on a complete tiny run of the suite: every row
    over the 9 scenes, every cell "mean ± CI half-width" (n/a only for LPIPS, which needs a
    weights file, and where a 2D row has no such figure), the differences against the full
    method."""
    first = text.split("**", 2)[2].split("\n\n")[1]  # the first table's Markdown body
    rows = [
        line
        for line in first.splitlines()
        if line.startswith("| ") and not line.startswith("| Method")
    ]
    assert len(rows) == TRAINED + CALIBRATION, first
    heads = [c.strip() for c in first.splitlines()[0].strip("|").split("|")]
    figures = [h for h in heads[2:] if not h.startswith("Δ")]
    assert any("PSNR" in h for h in figures) and any("TAE" in h for h in figures), heads
    for i, row in enumerate(rows):
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[1] == "9", row  # n = 9 scenes x 1 seed
        calibration = i >= TRAINED
        assert cells[0].startswith("2D:") == calibration, row
        values = dict((h, c) for h, c in zip(heads[2:], cells[2:]) if not h.startswith("Δ"))
        for h, c in values.items():
            if c == "n/a" and ("LPIPS" in h or calibration):
                assert "PSNR" not in h and "SSIM" not in h, row  # a 2D row has every image score
                continue
            assert re.fullmatch(r"\*{0,2}-?[0-9.]+\*{0,2} ± [0-9.]+", c), (h, row)
        diffs = [c for h, c in zip(heads[2:], cells[2:]) if h.startswith("Δ")]
        assert (
            all(c == "ref" for c in diffs)
            if cells[0].endswith("(full)")
            else all(re.fullmatch(r"([-+][0-9.]+ ± [0-9.]+†?|n/a)", c) for c in diffs)
        ), row
    assert "mu-law" in text and "HDR-TAE" in text  # conventions footnote
    assert "Student-t 95 %" in text


@pytest.mark.slow
@pytest.mark.timeout(2 * 3600)
def test_paper_main_tiny_complete_table(tmp_path):
    from eval.cli import main

    runner = CliRunner()
    res = runner.invoke(
        main, ["run", "paper-main", "--preset", "tiny", "--out", str(tmp_path), "--device", "cpu"]
    )
    assert res.exit_code == 0, res.output
    table = ["table", "paper-main", "--root", str(tmp_path), "--no-figures"]
    res = runner.invoke(main, table)
    assert res.exit_code == 0, res.output
    check_first_table(res.output)
    res = runner.invoke(main, [*table, "--columns", "all"])
    assert res.exit_code == 0, res.output
    check_first_table(res.output)
    assert "paper / ours / agree" in res.output  # the comparison with the paper's Table 1
