"""`m4dgs-eval repeats`: does one configuration's run repeat in another suite? Equality per
(scene, seed) over the quality columns (time, speed and memory left out), the differences B - A
recomputed here from the CSV values with numpy / scipy."""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner
from scipy import stats


def _cli(*args):
    from eval.cli import main

    return CliRunner().invoke(main, ["repeats", *map(str, args)])


def _csv(tmp_path):
    """Suite old (row full) and suite new (row base, the same configuration): a-scene/0 repeats
    exactly (only the cost columns differ), b-scene/0 and b-scene/1 move, c-scene/0 has one side
    only, and a missing row of new is ignored."""
    from eval.records.runs_csv import write_runs_csv

    rng = np.random.default_rng(7)
    rows = []
    for scene, seed in (("a-scene", 0), ("b-scene", 0), ("b-scene", 1), ("c-scene", 0)):
        q = dict(
            ldr_oe_psnr=30 + rng.random(),
            hdr_psnr=35 + rng.random(),
            hdr_tae=0.1 + rng.random() / 100,
            crf_error=0.2 + rng.random() / 10,
            track_epe=2 + rng.random(),
        )
        rows.append(
            dict(suite="old", scene=scene, row="full", seed=seed, status="scored", code="aaa")
            | q
            | dict(train_minutes=10.0, fps=20.0)
        )
        if scene == "c-scene":
            continue
        moved = dict(q)
        if scene == "b-scene":
            moved["ldr_oe_psnr"] += rng.normal(0, 0.4)
            moved["hdr_psnr"] += rng.normal(0, 1.0)
            moved["crf_error"] += 0.05
        rows.append(
            dict(suite="new", scene=scene, row="base", seed=seed, status="scored", code="bbb")
            | dict(host="AMD EPYC / AVX2")
            | moved
            | dict(train_minutes=12.5, fps=18.0)  # cost columns: never compared
        )
    rows.append(dict(suite="new", scene="a-scene", row="base", seed=1, status="missing"))
    path = tmp_path / "runs.csv"
    write_runs_csv(path, rows)
    return path


def test_repeats_counts_equal_pairs_and_gives_the_differences(tmp_path):
    from eval.records.runs_csv import read_runs_csv

    path = _csv(tmp_path)
    res = _cli("old:full", "new:base", "--csv", path)
    assert res.exit_code == 0, res.output
    lines = res.output.splitlines()
    assert lines[0].startswith("new:base against old:full")
    table = {
        (c[0], c[1]): c
        for c in ([x.strip() for x in ln.strip("|").split("|")] for ln in lines)
        if len(c) == 6 and c[0].endswith("-scene")
    }
    assert set(table) == {("a-scene", "0"), ("b-scene", "0"), ("b-scene", "1")}  # c: one side
    # the CSV's quality columns filled here: ldr_oe_psnr, hdr_psnr, hdr_tae, crf_error, track_epe
    assert table["a-scene", "0"][2] == "5 of 5" and table["a-scene", "0"][3] == "-"
    assert table["b-scene", "0"][2] == "2 of 5"
    assert table["a-scene", "0"][4] == "aaa / bbb"
    assert table["a-scene", "0"][5] == "not recorded / AMD EPYC / AVX2"
    got = read_runs_csv(path)
    val = {(r["suite"], r["scene"], r["seed"], r["status"]): r for r in got}
    d_oe = [
        val["new", "b-scene", sd, "scored"]["ldr_oe_psnr"]
        - val["old", "b-scene", sd, "scored"]["ldr_oe_psnr"]
        for sd in (0, 1)
    ]
    # the headline metrics lead each pair's differences, in order
    assert table["b-scene", "1"][3].startswith(f"ldr_oe_psnr {d_oe[1]:+.2f}, hdr_psnr ")
    assert "crf_error +0.05" in table["b-scene", "1"][3]
    assert "1 of 3 pairs equal in every quality column both fill." in res.output
    line = next(ln for ln in lines if ln.startswith("| LDR-OE PSNR |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    d = np.array(d_oe)
    half = stats.t.ppf(0.975, 1) * d.std(ddof=1) / np.sqrt(2)
    dag = "†" if abs(d.mean()) > half else ""
    assert cells[1] == f"{d.mean():+.2f} ± {half:.2f}{dag} (2)"
    assert cells[2] == f"{np.sqrt(np.mean(d**2)):.2f}"
    # HDR-TAE is equal in both moved pairs: its B - A is 0 over them
    line = next(ln for ln in lines if "TAE" in ln and ln.startswith("| "))
    assert "+0.0000 ± 0.0000 (2)" in line


def test_repeats_check_and_metric_choice(tmp_path):
    path = _csv(tmp_path)
    assert _cli("old:full", "new:base", "--csv", path, "--check").exit_code == 1
    # only columns that repeat everywhere: every pair equal, --check passes
    res = _cli("old:full", "new:base", "--csv", path, "--check", "--metrics", "hdr_tae,track_epe")
    assert res.exit_code == 0, res.output
    assert "3 of 3 pairs equal" in res.output and "2 of 2" in res.output


def test_repeats_names_what_is_wrong(tmp_path):
    path = _csv(tmp_path)
    for args, msg in (
        (("old", "new:base"), "give SUITE:ROW"),
        (("old:full", "new:nope"), "no scored run of new:nope in the CSV (rows of new: ['base'])"),
        (("old:full", "gone:base"), "no suite 'gone'"),
        (("old:full", "new:base", "--metrics", "psnr_x"), "unknown metrics ['psnr_x']"),
    ):
        res = _cli(*args, "--csv", path)
        assert res.exit_code == 2, res.output
        assert msg in res.output and str(path) in res.output
