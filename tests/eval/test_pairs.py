"""`m4dgs-eval pairs`: per-(scene, seed) differences row - ref from the runs CSV, their mean and
Student-t 95 % interval recomputed here with numpy / scipy."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from scipy import stats


def _rows(rng):
    rows = []
    for scene in ("b-scene", "a-scene", "c-scene"):
        for seed in (0, 1):
            base = 30 + rng.random()
            for row, lead in (("full", 0.0), ("no-reproj", 0.4)):
                if (scene, seed, row) == ("c-scene", 1, "no-reproj"):
                    continue  # a pair with one side only is left out
                rows.append(
                    dict(suite="paper-ablation", scene=scene, row=row, seed=seed, status="scored")
                    | dict(ldr_oe_psnr=base + lead + rng.normal(0, 0.2), hdr_tae=0.1 + seed / 100)
                )
    rows.append(
        dict(suite="paper-ablation", scene="a-scene", row="no-tlr", seed=0, status="missing")
    )
    return rows


def test_pairs_are_the_paired_differences(tmp_path):
    from eval.cli import main
    from eval.pairs import pair_differences, pairs_markdown
    from eval.results import read_runs_csv, write_runs_csv

    csv_path = tmp_path / "runs.csv"
    write_runs_csv(csv_path, _rows(np.random.default_rng(0)))
    rows = read_runs_csv(csv_path)
    d = pair_differences(rows, "paper-ablation", "no-reproj", "full", "ldr_oe_psnr")
    keys = [("a-scene", 0), ("a-scene", 1), ("b-scene", 0), ("b-scene", 1), ("c-scene", 0)]
    assert list(d) == keys
    by = {(r["scene"], r["seed"], r["row"]): r["ldr_oe_psnr"] for r in rows if r["row"] != "no-tlr"}
    want = np.array([by[(s, sd, "no-reproj")] - by[(s, sd, "full")] for s, sd in keys])
    assert np.allclose(list(d.values()), want)
    # the reference row defaults to the suite file's (paper-ablation: full)
    text = pairs_markdown(rows, "paper-ablation", metrics=["ldr_oe_psnr", "hdr_tae"])
    assert text.startswith("paper-ablation: no-reproj - full")
    line = next(ln for ln in text.splitlines() if ln.startswith("| LDR-OE PSNR |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    half = stats.t.ppf(0.975, len(want) - 1) * want.std(ddof=1) / np.sqrt(len(want))
    dag = "†" if abs(want.mean()) > half else ""
    assert cells[1] == f"{want.mean():+.2f} ± {half:.2f}{dag} (5)"
    # over scenes: each scene's seeds averaged first, the interval over the 3 scene means
    sm = np.array([want[:2].mean(), want[2:4].mean(), want[4]])
    sh = stats.t.ppf(0.975, 2) * sm.std(ddof=1) / np.sqrt(3)
    assert cells[2] == f"{sm.mean():+.2f} ± {sh:.2f}{'†' if abs(sm.mean()) > sh else ''} (3)"
    assert cells[3:] == [f"{x:+.2f}" for x in want]
    tae = next(ln for ln in text.splitlines() if ln.startswith("| HDR-TAE |"))
    assert "+0.0000 ± 0.0000 (5) | +0.0000 ± 0.0000 (3)" in tae  # equal in both rows
    # the command prints the same; bad names are usage errors naming the CSV
    r = CliRunner().invoke(
        main,
        ["pairs", "paper-ablation", "--csv", str(csv_path), "--metrics", "ldr_oe_psnr,hdr_tae"],
    )
    assert r.exit_code == 0 and r.output.strip() == text.strip()
    for args, needle in (
        (["nope"], "no scored run of suite 'nope'"),
        (["paper-ablation", "--rows", "no-tlr"], "no scored run of rows ['no-tlr']"),
        (["paper-ablation", "--ref", "x"], "no scored run of row 'x'"),
        (["paper-ablation", "--metrics", "psnr"], "unknown metrics ['psnr']"),
    ):
        r = CliRunner().invoke(main, ["pairs", *args, "--csv", str(csv_path)])
        assert r.exit_code == 2 and needle in r.output and str(csv_path) in r.output, r.output
    with pytest.raises(ValueError, match="no scored run"):
        pairs_markdown([], "paper-ablation")
