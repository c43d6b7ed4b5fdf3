"""`m4dgs-eval table`'s compact default (the demo's table): LDR-OE PSNR, HDR PSNR, HDR-TAE and
training time, `full` labelled as the method, columns without any value dropped; `--columns all`
prints every table as before."""

from __future__ import annotations

import json

from click.testing import CliRunner

from eval.cli import main


def _runs(tmp_path):
    """A folder of runs: two scenes x rows full and static-hdr, no training time recorded."""
    for scene, bump in (("a", 0.0), ("b", 1.0)):
        for row, psnr in (("full", 30.0), ("static-hdr", 28.0)):
            d = tmp_path / "runs" / scene / row
            d.mkdir(parents=True)
            m = {
                "ldr_oe_psnr": psnr + bump,
                "hdr_psnr": psnr + 5 + bump,
                "hdr_tae": 0.1 + bump / 100,
                "train_minutes": None,
                "ate": 0.01,
                "run": {"variant": row, "clip_name": scene},
            }
            (d / "metrics.json").write_text(json.dumps(m))
    return tmp_path / "runs"


def test_compact_by_default(tmp_path):
    r = CliRunner().invoke(main, ["table", str(_runs(tmp_path)), "--no-figures"])
    assert r.exit_code == 0, r.output
    head = next(ln for ln in r.output.splitlines() if ln.startswith("| Method"))
    assert "LDR-OE PSNR" in head and "HDR PSNR" in head and "HDR-TAE" in head
    assert "Train" not in head  # no run recorded its training time: the column is dropped
    assert "SSIM" not in head and "ATE" not in head
    assert "| Mono4DGS-HDR (full) |" in r.output and "| static-hdr |" in r.output
    assert "Training frames" not in r.output and "Geometry" not in r.output


def test_columns_all_prints_every_table(tmp_path):
    r = CliRunner().invoke(
        main, ["table", str(_runs(tmp_path)), "--no-figures", "--columns", "all"]
    )
    assert r.exit_code == 0, r.output
    assert "Training frames" in r.output and "Geometry" in r.output and "| full |" in r.output
