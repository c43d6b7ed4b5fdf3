"""Table formatting tests: means over scenes, bold placement (ties), n/a handling,
Markdown/LaTeX/CSV shape."""

from __future__ import annotations

import csv
import io
import math

import pytest

from eval import tables
from eval.tables import Column, TableSpec

CONV = {"psnr": "PSNR convention", "hdr_tae": "TAE convention", "ldr_float": "float images"}


def _rows():
    return [
        {"method": "Ours", "scene": "a", "psnr": 30.0, "tae": 0.050, "lp": None},
        {"method": "Ours", "scene": "b", "psnr": 32.0, "tae": 0.070, "lp": None},
        {"method": "MoSca", "scene": "a", "psnr": 29.0, "tae": 0.060, "lp": 0.2},
        {"method": "MoSca", "scene": "b", "psnr": 33.0, "tae": 0.0600004, "lp": 0.1},
        {"method": "Splines", "scene": "a", "psnr": 20.0, "tae": float("nan"), "lp": 0.3},
        {"method": "Splines", "scene": "b", "psnr": 21.0, "tae": 0.09, "lp": 0.4},
    ]


def _spec(**kw):
    cols = [
        Column("psnr", "PSNR", True, ".2f", "LDR-OE", "psnr"),
        Column("lp", "LPIPS", False, ".3f", "LDR-OE"),
        Column("tae", "HDR-TAE", False, ".3f", None, "hdr_tae"),
    ]
    return TableSpec(columns=cols, conventions=["ldr_float", "a literal note"], **kw)


def test_aggregate_means_and_missing():
    agg = tables.aggregate(_rows(), _spec())
    by = {r["method"]: r for r in agg}
    assert [r["method"] for r in agg] == ["Ours", "MoSca", "Splines"]
    assert by["Ours"]["psnr"] == pytest.approx(31.0)
    assert by["MoSca"]["psnr"] == pytest.approx(31.0)
    assert by["MoSca"]["lp"] == pytest.approx(0.15)
    assert by["Ours"]["lp"] is None
    assert by["Splines"]["tae"] is None  # NaN in one scene -> n/a
    assert by["Ours"]["n_scenes"] == 2
    part = {r["method"]: r for r in tables.aggregate(_rows(), _spec(partial_means=True))}
    assert part["Splines"]["tae"] == pytest.approx(0.09)
    only_a = {r["method"]: r for r in tables.aggregate(_rows(), _spec(scenes=["a"]))}
    assert only_a["Ours"]["psnr"] == pytest.approx(30.0)


def test_bold_ties_and_direction():
    spec = _spec()
    agg = tables.aggregate(_rows(), spec)
    flags = tables.best_flags(agg, spec)
    # PSNR: Ours and MoSca tie at 31.00 -> both bold; LPIPS: only MoSca has a value (lower better);
    # TAE: Ours 0.060 and MoSca 0.060 tie at the displayed precision
    assert flags == [[True, False, True], [True, True, True], [False, False, False]]


def test_markdown_shape():
    md = tables.render_markdown(_rows(), _spec(title="T"), conventions=CONV)
    lines = md.splitlines()
    assert lines[0] == "**T**"
    head = lines[2]
    assert head == "| Method | LDR-OE PSNR↑ | LDR-OE LPIPS↓ | HDR-TAE↓ |"
    assert lines[3].count("|") == 5
    assert lines[4] == "| Ours | **31.00** | n/a | **0.060** |"
    assert lines[5] == "| MoSca | **31.00** | **0.150** | **0.060** |"
    assert lines[6] == "| Splines | 20.50 | 0.350 | n/a |"
    notes = [ln for ln in lines if ln.startswith("- ")]
    assert notes[:4] == [
        "- PSNR convention",
        "- TAE convention",
        "- float images",
        "- a literal note",
    ]


def test_latex_shape():
    tex = tables.render_latex(_rows(), _spec(), conventions=CONV)
    lines = tex.splitlines()
    assert lines[0] == "\\begin{tabular}{lrrr}"
    assert "\\toprule" in lines and "\\midrule" in lines and "\\bottomrule" in lines
    assert lines[2] == " & \\multicolumn{2}{c}{LDR-OE} &  \\\\"
    assert lines[3] == "\\cmidrule(lr){2-3}"
    assert lines[4] == "Method & PSNR$\\uparrow$ & LPIPS$\\downarrow$ & HDR-TAE$\\downarrow$ \\\\"
    body = lines[lines.index("\\midrule") + 1 : lines.index("\\bottomrule")]
    assert body[0] == "Ours & \\textbf{31.00} & n/a & \\textbf{0.060} \\\\"
    for row in body:
        assert row.count("&") == 3
    assert "\\par\\footnotesize" in lines
    esc = tables.render_latex(
        [{"method": "a_b&c", "scene": "s", "psnr": 1.0, "lp": 1.0, "tae": 1.0}],
        _spec(),
        conventions=CONV,
    )
    assert "a\\_b\\&c" in esc


def test_csv_shape_no_bold():
    text = tables.render_csv(_rows(), _spec(), conventions=CONV)
    rows = list(csv.reader(io.StringIO(text)))
    assert rows[0] == ["Method", "n_scenes", "LDR-OE PSNR", "LDR-OE LPIPS", "HDR-TAE"]
    assert rows[1] == ["Ours", "2", "31.00", "n/a", "0.060"]
    assert len(rows) == 4 and all(len(r) == 5 for r in rows)
    assert "**" not in text and "textbf" not in text
    with_notes = tables.render_csv(_rows(), _spec(), conventions=CONV, notes=True)
    assert with_notes.splitlines()[4] == "# PSNR convention"


def test_inf_and_spec_from_dict_and_paper_layout():
    spec = TableSpec.from_dict(
        {"columns": [{"key": "psnr", "header": "PSNR", "higher_is_better": True, "fmt": ".1f"}]}
    )
    rows = [
        {"method": "A", "scene": "s", "psnr": math.inf},
        {"method": "B", "scene": "s", "psnr": 40.0},
    ]
    md = tables.render(rows, spec, "md", conventions={})
    assert "| A | **inf** |" in md and "| B | 40.0 |" in md
    paper = tables.paper_table_spec(lpips_available=False)
    assert len(paper.columns) == 10
    notes = tables.footnotes(paper)  # real conventions from eval.metrics
    assert any("mu-law" in n for n in notes) and any("n/a" in n for n in notes)
    with pytest.raises(ValueError):
        tables.render(rows, spec, "html")


def test_a_seed_free_row_counts_each_scene_once_and_pairs_every_seed():
    """A calibration row repeated for two trainer seeds (copy-nearest: one prediction) is one
    sample per scene in its n and interval; its paired difference still uses every seed's pair. The
    reference: scipy's Student-t interval on the values written out by hand."""
    from scipy import stats as sst

    ours = {("a", 0): 30.0, ("a", 1): 31.0, ("b", 0): 32.0, ("b", 1): 32.5, ("c", 0): 28.0}
    ours[("c", 1)] = 29.5
    copy = {"a": 29.0, "b": 33.0, "c": 27.0}
    rows = [{"method": "Ours", "scene": s, "seed": k, "psnr": v} for (s, k), v in ours.items()]
    rows += [
        {"method": "Copy", "scene": s, "seed": k, "psnr": copy[s]} for s in copy for k in (0, 1)
    ]
    cols = [Column("psnr", "PSNR", True, ".2f", "LDR-OE", None)]

    def half(values):
        v = list(values)
        return sst.t.ppf(0.975, len(v) - 1) * sst.sem(v)

    for seed_free in (frozenset(), frozenset({"Copy"})):
        spec = TableSpec(columns=cols, intervals=True, reference="Ours", seed_free=seed_free)
        agg = {a["method"]: a for a in tables.aggregate(rows, spec)}
        st = dict(
            zip([a["method"] for a in tables.aggregate(rows, spec)], tables.cell_stats(rows, spec))
        )
        assert agg["Copy"]["psnr"] == pytest.approx(sum(copy.values()) / 3)
        samples = list(copy.values()) if seed_free else [v for v in copy.values() for _ in (0, 1)]
        assert agg["Copy"]["n_runs"] == len(samples)
        assert st["Copy"][0].ci.half == pytest.approx(half(samples))
        # the reference row is not seed-free: six runs
        assert agg["Ours"]["n_runs"] == 6
        assert st["Ours"][0].ci.half == pytest.approx(half(ours.values()))
        # Δ pairs Copy with every seed of Ours, either way
        diffs = [copy[s] - v for (s, _), v in ours.items()]
        assert st["Copy"][0].diff.mean == pytest.approx(sum(diffs) / 6)
        assert st["Copy"][0].diff.half == pytest.approx(half(diffs))
    text = tables.render_markdown(rows, spec, conventions=CONV)
    assert "Copy: one prediction for every trainer seed" in text
    assert "| Copy | 3 |" in text
