"""`m4dgs-eval suite merge`: another runs CSV's rows merged into the runs CSV by export's rules,
checked row by row against hand-written CSVs (which row wins, which curves and floors end up
beside it, what is refused)."""

from __future__ import annotations

import csv

from click.testing import CliRunner


def _cli(*args):
    from eval.cli import main

    return CliRunner().invoke(main, ["suite", "merge", *map(str, args)])


def _row(suite, scene, row, seed, status, psnr=None, host=""):
    return dict(
        suite=suite,
        scene=scene,
        row=row,
        seed=seed,
        status=status,
        host=host,
        generator="7",
        ldr_oe_psnr=psnr,
    )


def _write(path, rows, curves=None, floors=None):
    """A runs CSV with its -crf.csv ({key: curve value}, flat curves) and -floors.csv."""
    from eval.records.runs_csv import (
        CRF_GRID,
        crf_csv_path,
        floors_csv_path,
        write_crf_csv,
        write_floors_csv,
        write_runs_csv,
    )

    write_runs_csv(path, rows)
    write_crf_csv(
        crf_csv_path(path),
        {
            k: {"crf": "hdrnerf", "log2_x": CRF_GRID, "learned": [v] * len(CRF_GRID)}
            for k, v in (curves or {}).items()
        },
    )
    if floors:
        write_floors_csv(floors_csv_path(path), floors)


def _floor(v):
    return {"hdr_tae_floor": v, "hdr_tae_floor_interior": v / 2}


def test_merge_takes_scored_rows_their_curves_and_new_floors(tmp_path):
    from eval.records.runs_csv import (
        crf_csv_path,
        floors_csv_path,
        read_crf_csv,
        read_floors_csv,
        read_runs_csv,
    )

    dest, src = tmp_path / "runs.csv", tmp_path / "staged.csv"
    _write(
        dest,
        [
            _row("nv", "a", "full", 0, "scored", 30.0, "AMD EPYC / AVX2"),
            _row("nv", "a", "static", 0, "missing"),
            _row("nv", "b", "static", 0, "scored", 25.0, "AMD EPYC / AVX2"),
            _row("other", "a", "full", 0, "scored", 20.0),
        ],
        curves={("nv", "a", "full", "0"): 0.1, ("nv", "b", "static", "0"): 0.2},
        floors={("a", "7"): _floor(0.117844)},
    )
    _write(
        src,
        [
            _row("nv", "a", "full", 0, "missing"),  # never replaces a scored row
            _row("nv", "a", "static", 0, "scored", 26.5, "AMD EPYC / AVX512"),
            _row("nv", "b", "static", 0, "scored", 24.0, "AMD EPYC / AVX512"),  # re-scored
            _row("nv", "c", "static", 1, "scored", 22.0, "AMD EPYC / AVX512"),
            _row("skip", "a", "full", 0, "scored", 1.0),
        ],
        curves={("nv", "a", "static", "0"): 0.7, ("nv", "c", "static", "1"): 0.9},
        floors={("a", "7"): _floor(0.1178434), ("c", "7"): _floor(0.3)},
    )
    res = _cli(src, "--csv", dest, "--suites", "nv")
    assert res.exit_code == 0, res.output
    assert "nv: 3 scored, 1 missing rows" in res.output
    assert "mixes hosts" in res.output  # the AVX2 and AVX512 rows of one suite

    got = {(r["suite"], r["scene"], r["row"], r["seed"]): r for r in read_runs_csv(dest)}
    assert got[("nv", "a", "full", 0)]["ldr_oe_psnr"] == 30.0  # kept
    assert got[("nv", "a", "static", 0)]["ldr_oe_psnr"] == 26.5  # missing -> scored
    assert got[("nv", "b", "static", 0)]["ldr_oe_psnr"] == 24.0  # scored -> re-scored
    assert got[("nv", "c", "static", 1)]["status"] == "scored"  # added
    assert got[("other", "a", "full", 0)]["ldr_oe_psnr"] == 20.0  # other suites stay
    assert ("skip", "a", "full", 0) not in got  # not among --suites
    assert len(got) == 5

    curves = read_crf_csv(crf_csv_path(dest))
    assert curves[("nv", "a", "full", 0)]["learned"][0] == 0.1
    assert curves[("nv", "a", "static", 0)]["learned"][0] == 0.7
    assert ("nv", "b", "static", 0) not in curves  # its re-scored row brought no curve
    assert curves[("nv", "c", "static", 1)]["learned"][0] == 0.9

    floors = read_floors_csv(floors_csv_path(dest))
    assert floors[("a", "7")]["hdr_tae_floor"] == 0.117844  # the destination's clip floor stays
    assert floors[("c", "7")]["hdr_tae_floor"] == 0.3  # a new clip's is added

    with open(dest, newline="") as f:  # still a valid runs CSV, sorted by key
        keys = [(r["suite"], r["scene"], r["row"], r["seed"]) for r in csv.DictReader(f)]
    assert keys == sorted(keys)


def test_merge_refuses_what_it_cannot_merge(tmp_path):
    dest = tmp_path / "runs.csv"
    _write(dest, [_row("nv", "a", "full", 0, "scored", 30.0)])
    res = _cli(tmp_path / "nope.csv", "--csv", dest)
    assert res.exit_code != 0 and "nope.csv: no such runs CSV" in res.output
    res = _cli(dest, "--csv", dest)
    assert res.exit_code != 0 and "the destination itself" in res.output
    src = tmp_path / "staged.csv"
    _write(src, [_row("nv", "a", "full", 0, "scored", 31.0)])
    res = _cli(src, "--csv", dest, "--suites", "paper-main")
    assert res.exit_code != 0 and "no rows of suite(s) paper-main" in res.output
    # a CSV of another kind (here a learned-CRF CSV, whose header has no status) is named, and
    # neither side is touched
    crf = tmp_path / "runs-crf.csv"
    crf.write_text("suite,scene,row,seed,crf,-10\nnv,a,full,0,hdrnerf,0.5\n")
    before = dest.read_bytes()
    res = _cli(crf, "--csv", dest)
    assert res.exit_code != 0 and "Traceback" not in res.output
    assert f"{crf}: not a runs CSV" in res.output and "lacks the column(s) status" in res.output
    assert dest.read_bytes() == before
