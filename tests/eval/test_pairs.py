"""`m4dgs-eval pairs`: per-(scene, seed) differences row - ref from the runs CSV, their mean and
Student-t 95 % interval recomputed here with numpy / scipy."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from scipy import stats


def _pairs_cli(csv_path, suite, metrics, *flags):
    """`m4dgs-eval pairs SUITE --csv CSV --metrics M [flags]` through click's test runner."""
    from eval.cli import main

    args = ["pairs", suite, "--csv", str(csv_path), "--metrics", metrics, *flags]
    return CliRunner().invoke(main, args)


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


def test_pairs_name_the_failed_runs_they_leave_out(tmp_path):
    """A failed run's pair is not among the differences, and the output says which run failed and
    why; a failed run of a row not compared is not named."""
    from eval.inspect.pairs import pair_differences, pairs_markdown

    rows = _rows(np.random.default_rng(0))
    fail = dict(suite="paper-ablation", scene="b-scene", row="no-reproj", seed=1, status="failed")
    fail["error"] = "training: stage2: step 2038: the tone mapper's input ... inf"
    rows = [r for r in rows if (r["scene"], r["seed"], r["row"]) != ("b-scene", 1, "no-reproj")]
    rows += [fail, dict(fail, row="no-tlr", scene="a-scene", seed=1)]
    assert ("b-scene", 1) not in pair_differences(
        rows, "paper-ablation", "no-reproj", "full", "ldr_oe_psnr"
    )
    text = pairs_markdown(rows, "paper-ablation", metrics=["ldr_oe_psnr"], row_names=["no-reproj"])
    assert "(4)" in text  # 5 pairs less the failed one
    assert (
        "Failed runs (their (scene, seed) pairs are not in the differences above): "
        "paper-ablation:no-reproj on b-scene seed 1 (training: stage2: step 2038:" in text
    )
    assert "no-tlr on a-scene" not in text


def test_pairs_are_the_paired_differences(tmp_path):
    from eval.cli import main
    from eval.inspect.pairs import pair_differences, pairs_markdown
    from eval.records.runs_csv import read_runs_csv, write_runs_csv

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
    assert cells[3] == f"{int((want > 0).sum())} of 5"
    assert cells[4:] == [f"{x:+.2f}" for x in want]
    tae = next(ln for ln in text.splitlines() if ln.startswith("| HDR-TAE |"))
    assert "+0.0000 ± 0.0000 (5) | +0.0000 ± 0.0000 (3)" in tae  # equal in both rows
    # the command prints the same; bad names are usage errors naming the CSV
    r = _pairs_cli(csv_path, "paper-ablation", "ldr_oe_psnr,hdr_tae")
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


def test_a_ratio_shown_in_stops_differs_in_stops():
    """highlight_peak_ratio (a `log2` column: "peak (stops)") differs as log2(row / ref), not as
    row - ref: a runaway of 128x against 1x is 7 stops, not 127; a non-positive ratio has no
    stops and its pair is left out."""
    from eval.inspect.pairs import pair_differences, pairs_markdown

    rows = []
    for scene, (a, b) in {"a": (128.0, 1.0), "b": (0.5, 2.0), "c": (0.0, 1.0)}.items():
        for row, v in (("full", b), ("no-reproj", a)):
            rows.append(
                dict(suite="paper-ablation", scene=scene, row=row, seed=0, status="scored")
                | dict(highlight_peak_ratio=v)
            )
    d = pair_differences(rows, "paper-ablation", "no-reproj", "full", "highlight_peak_ratio")
    assert d == {("a", 0): 7.0, ("b", 0): -2.0}
    text = pairs_markdown(rows, "paper-ablation", metrics=["highlight_peak_ratio"])
    assert "| +7.00 | -2.00 |" in text


def test_scene_heterogeneity_is_the_one_way_anova_across_scenes():
    from eval.stats import scene_heterogeneity

    rng = np.random.default_rng(4)
    # four scenes, two or three seeds each, one scene with one seed only
    d = {(sc, sd): float(rng.normal(i * 0.3, 0.2)) for i, sc in enumerate("abcd") for sd in (0, 1)}
    d[("b", 2)] = 0.5
    d[("e", 0)] = 1.0
    groups = [[v for k, v in d.items() if k[0] == sc] for sc in "abcde"]
    want = stats.f_oneway(*groups)
    h = scene_heterogeneity(d)
    assert (h.df_between, h.df_within) == (4, 10 - 5)
    assert h.f == pytest.approx(want.statistic) and h.p == pytest.approx(want.pvalue)
    # a scene-independent effect plus seed noise: no evidence of scene differences
    flat = {(sc, sd): 0.4 + (0.1 if sd else -0.1) for sc in "abc" for sd in (0, 1)}
    assert scene_heterogeneity(flat).p == pytest.approx(1.0)
    # no within-scene spread: F is infinite when the scene means differ
    exact = {(sc, sd): float(i) for i, sc in enumerate("ab") for sd in (0, 1)}
    assert scene_heterogeneity(exact).f == float("inf") and scene_heterogeneity(exact).p == 0.0
    # one seed per scene, or one scene: nothing to compare with
    assert scene_heterogeneity({("a", 0): 1.0, ("b", 0): 2.0}) is None
    assert scene_heterogeneity({("a", 0): 1.0, ("a", 1): 2.0}) is None


def test_pairs_by_seed(tmp_path):
    from eval.inspect.pairs import pairs_markdown
    from eval.records.runs_csv import read_runs_csv, write_runs_csv

    csv_path = tmp_path / "runs.csv"
    write_runs_csv(csv_path, _rows(np.random.default_rng(0)))
    rows = read_runs_csv(csv_path)
    text = pairs_markdown(rows, "paper-ablation", metrics=["ldr_oe_psnr"], by_seed=True)
    head = next(ln for ln in text.splitlines() if ln.startswith("| metric |"))
    assert "| over scenes (n) | > 0 | seed 0 (n) | seed 1 (n) | scenes differ (F-test) |" in head
    line = next(ln for ln in text.splitlines() if ln.startswith("| LDR-OE PSNR |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    by = {(r["scene"], r["seed"], r["row"]): r["ldr_oe_psnr"] for r in rows if r["row"] != "no-tlr"}
    keys = [("a-scene", 0), ("a-scene", 1), ("b-scene", 0), ("b-scene", 1), ("c-scene", 0)]
    d = {k: by[(*k, "no-reproj")] - by[(*k, "full")] for k in keys}
    for col, seed in ((4, 0), (5, 1)):
        v = np.array([x for k, x in d.items() if k[1] == seed])
        half = stats.t.ppf(0.975, len(v) - 1) * v.std(ddof=1) / np.sqrt(len(v))
        dag = "†" if abs(v.mean()) > half else ""
        assert cells[col] == f"{v.mean():+.2f} ± {half:.2f}{dag} ({len(v)})"
    a = stats.f_oneway([d[keys[0]], d[keys[1]]], [d[keys[2]], d[keys[3]]], [d[keys[4]]])
    assert cells[6] == f"F(2, 2) = {a.statistic:.2f}, p = {a.pvalue:.3f}"
    assert cells[7:] == [f"{d[k]:+.2f}" for k in keys]
    r = _pairs_cli(csv_path, "paper-ablation", "ldr_oe_psnr", "--by-seed")
    assert r.exit_code == 0 and r.output.strip() == text.strip()


OWN_SUITE = """name: my-idea
description: full with and without my idea
scenes: tiny
reference: base
rows:
  - {name: base, label: "full", variant: full}
  - {name: idea, label: "full + idea", variant: full, overrides: {stage2.loss.lambda_tlr: 0.1}}
"""


def _own_rows():
    rows = []
    for scene in ("tiny-lamp-box", "tiny-flag-arm"):
        for seed in (0, 1):
            for row, lead in (("base", 0.0), ("idea", 0.25 + seed / 10)):
                rows.append(
                    dict(suite="my-idea", scene=scene, row=row, seed=seed, status="scored")
                    | dict(ldr_oe_psnr=30 + lead, hdr_tae=0.1)
                )
    return rows


def test_pairs_of_a_suite_that_is_not_built_in(tmp_path):
    """Your own suite: its YAML file as SUITE gives its reference row; its name alone needs --ref
    and says so."""
    from eval.cli import main
    from eval.records.runs_csv import write_runs_csv

    csv_path, yml = tmp_path / "ideas.csv", tmp_path / "my-idea.yaml"
    write_runs_csv(csv_path, _own_rows())
    yml.write_text(OWN_SUITE)
    base = ["--csv", str(csv_path), "--metrics", "ldr_oe_psnr"]
    r = CliRunner().invoke(main, ["pairs", str(yml), *base])
    assert r.exit_code == 0, r.output
    assert r.output.startswith("my-idea: idea - base")
    line = next(ln for ln in r.output.splitlines() if ln.startswith("| LDR-OE PSNR |"))
    assert line.split("|")[2].strip().startswith("+0.30 ± ")  # (0.25 + 0.35) / 2
    r2 = CliRunner().invoke(main, ["pairs", "my-idea", "--ref", "base", *base])
    assert r2.exit_code == 0 and r2.output == r.output
    r3 = CliRunner().invoke(main, ["pairs", "my-idea", *base])
    assert r3.exit_code == 2 and "not built in: give its YAML file as SUITE" in r3.output


def test_results_page_of_your_own_suite(tmp_path):
    """`results --suite FILE`: the section of a suite that is not built in shows its definition and
    reference row; a CSV of only such suites gets no findings or controls sections."""
    from eval.cli import main
    from eval.records.runs_csv import write_runs_csv

    csv_path, yml, out = tmp_path / "ideas.csv", tmp_path / "my-idea.yaml", tmp_path / "p.md"
    write_runs_csv(csv_path, _own_rows())
    yml.write_text(OWN_SUITE)
    args = ["results", "--csv", str(csv_path), "--out", str(out), "--no-readme", "--no-figures"]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    text = out.read_text()
    assert "(no suite definition found)" in text and "reference row: `n/a`" in text
    assert "## Findings" not in text and "## Controls" not in text
    assert "are not evaluated here" in text and "Suites without runs" not in text
    r = CliRunner().invoke(main, args + ["--suite", str(yml)])
    assert r.exit_code == 0, r.output
    text = out.read_text()
    assert "full with and without my idea" in text and "reference row: `base`" in text
    assert "Definition: [" in text and "(my-idea.yaml)" in text
    assert f"--suite {yml}" in text  # the stated command makes the page as it is
    # the rows in the suite's order, with the idea's paired difference to its reference
    body = [ln for ln in text.splitlines() if ln.startswith("| full")]
    assert [ln.split("|")[1].strip() for ln in body[:2]] == ["full", "full + idea"]
    assert "+0.30 ± " in body[1]


def test_pairs_holm_marks_what_the_sequential_procedure_rejects(tmp_path):
    """--holm: each comparison's adjusted p-value is marked † exactly where Holm's procedure, run
    here as a sequence of tests on scipy's paired t-test p-values, rejects at 5 %."""
    from eval.records.runs_csv import write_runs_csv

    rng = np.random.default_rng(7)
    effects = {"no-video-init": 1.0, "no-occlusion": 0.35, "no-reproj": 0.15, "no-tlr": 0.0}
    rows = []
    for scene in ("s1", "s2", "s3", "s4"):
        for seed in (0, 1):
            base = 30 + rng.normal(0, 1)
            for row, eff in [("full", 0.0)] + list(effects.items()):
                v = base + eff + rng.normal(0, 0.2)
                rows.append(
                    dict(suite="paper-ablation", scene=scene, row=row, seed=seed, status="scored")
                    | dict(ldr_oe_psnr=v, hdr_tae=0.1 + rng.normal(0, 0.001))
                )
    csv_path = tmp_path / "runs.csv"
    write_runs_csv(csv_path, rows)
    r = _pairs_cli(csv_path, "paper-ablation", "ldr_oe_psnr,hdr_tae", "--holm")
    assert r.exit_code == 0, r.output
    family, pvals = [], []
    for row in effects:
        for m in ("ldr_oe_psnr", "hdr_tae"):
            a = {(x["scene"], x["seed"]): x[m] for x in rows if x["row"] == row}
            b = {(x["scene"], x["seed"]): x[m] for x in rows if x["row"] == "full"}
            keys = sorted(a)
            family.append((row, m))
            pvals.append(stats.ttest_rel([a[k] for k in keys], [b[k] for k in keys]).pvalue)
    from tests.eval.test_results import holm_rejects

    want = dict(zip(family, holm_rejects(pvals)))
    got, current = {}, None
    header = {"ldr_oe_psnr": "| LDR-OE PSNR |", "hdr_tae": "| HDR-TAE |"}
    for ln in r.output.splitlines():
        if ln.startswith("paper-ablation: "):
            current = ln.split(": ")[1].split(" - ")[0]
        for m, h in header.items():
            if ln.startswith(h):
                cell = [c.strip() for c in ln.strip("|").split("|")][2]
                got[(current, m)] = cell.endswith("†")
                p = float(cell.rstrip("†"))
                # never below the raw p (printed to 3 decimals)
                assert p >= pvals[family.index((current, m))] - 0.0005
    assert got == want and any(want.values()) and not all(want.values())
    assert (
        f"over the 8 comparisons printed (rows x metrics): {sum(want.values())} exclude" in r.output
    )


def test_pairs_against_another_suites_effect_is_the_difference_in_differences(tmp_path):
    """`pairs SUITE --against BASE:REF:ROW`: per (scene, seed) pair both suites have, (row - ref)
    minus BASE's (ROW - REF), recomputed here from the CSV values with numpy / scipy; a pair only
    one suite has is left out; unknown suites or rows and a malformed spec are named."""
    from eval.records.runs_csv import read_runs_csv, write_runs_csv

    rng = np.random.default_rng(3)
    rows = _rows(rng)  # paper-ablation: no-reproj - full, 5 pairs (c-scene / 1 has one side only)
    for scene in ("a-scene", "b-scene", "c-scene"):
        for seed in (0, 1):
            if (scene, seed) == ("b-scene", 1):
                continue  # the base lacks this pair: it drops out of the change
            base = 31 + rng.random()
            for row, lead in (("full", 0.0), ("no-reproj", 0.1 + rng.normal(0, 0.3))):
                rows.append(
                    dict(suite="control-reproj", scene=scene, row=row, seed=seed, status="scored")
                    | dict(ldr_oe_psnr=base + lead, hdr_tae=0.1)
                )
    csv_path = tmp_path / "runs.csv"
    write_runs_csv(csv_path, rows)
    got = read_runs_csv(csv_path)
    val = {(r["suite"], r["scene"], r["seed"], r["row"]): r["ldr_oe_psnr"] for r in got}
    keys = [("a-scene", 0), ("a-scene", 1), ("b-scene", 0), ("c-scene", 0)]
    want = np.array(
        [
            (val["paper-ablation", s, sd, "no-reproj"] - val["paper-ablation", s, sd, "full"])
            - (val["control-reproj", s, sd, "no-reproj"] - val["control-reproj", s, sd, "full"])
            for s, sd in keys
        ]
    )
    res = _pairs_cli(
        csv_path, "paper-ablation", "ldr_oe_psnr", "--rows", "no-reproj",
        "--against", "control-reproj:full:no-reproj",
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert res.output.startswith(
        "change: (paper-ablation: no-reproj - full) - (control-reproj: no-reproj - full)"
    )
    line = next(ln for ln in res.output.splitlines() if ln.startswith("| LDR-OE PSNR |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    half = stats.t.ppf(0.975, len(want) - 1) * want.std(ddof=1) / np.sqrt(len(want))
    dag = "†" if abs(want.mean()) > half else ""
    assert cells[1] == f"{want.mean():+.2f} ± {half:.2f}{dag} (4)"
    assert cells[4:] == [f"{v:+.2f}" for v in want]  # a-scene / 0, a-scene / 1, b-scene / 0, c / 0
    for spec, msg in (
        ("control-reproj:full", "SUITE:REF:ROW"),
        ("nope:full:no-reproj", "no scored run of suite 'nope'"),
        ("control-reproj:full:no-such-row", "no-such-row"),
    ):
        bad = _pairs_cli(csv_path, "paper-ablation", "ldr_oe_psnr", "--against", spec)
        assert bad.exit_code != 0 and msg in bad.output, (spec, bad.output)


def _ls_rss(y, design):
    """Residual sum of squares of the least-squares fit of y on the design's columns."""
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    return float(((y - design @ coef) ** 2).sum())


def test_rows_differ_is_the_two_way_anova_of_rows_in_blocks():
    """Checked against the F-test of nested linear models fitted by least squares (blocks alone
    against blocks + rows), and for two rows against the paired t-test; a block that one row lacks
    is left out of every row."""
    from eval.stats import rows_differ

    rng = np.random.default_rng(7)
    blocks = [(sc, sd) for sc in "abcd" for sd in (0, 1)]
    level = {b: rng.normal(0, 1.0) for b in blocks}  # the block's own level cancels
    rows = {
        name: {b: level[b] + shift + rng.normal(0, 0.3) for b in blocks}
        for name, shift in (("draw-0", 0.0), ("draw-1", 0.2), ("draw-2", 0.5))
    }
    rows["draw-2"].pop(("d", 1))  # a failed run: its block leaves every row
    rows["draw-1"][("e", 0)] = 3.0  # a block only one row has
    kept = [b for b in blocks if b != ("d", 1)]
    y = np.array([rows[n][b] for b in kept for n in rows])
    nb, k = len(kept), len(rows)
    block_cols = np.kron(np.eye(nb), np.ones((k, 1)))
    row_cols = np.kron(np.ones((nb, 1)), np.eye(k))[:, 1:]
    rss_reduced = _ls_rss(y, block_cols)
    rss_full = _ls_rss(y, np.hstack([block_cols, row_cols]))
    df1, df2 = k - 1, (nb - 1) * (k - 1)
    f_want = ((rss_reduced - rss_full) / df1) / (rss_full / df2)
    h = rows_differ(rows)
    assert (h.df_between, h.df_within) == (2, 12)
    assert h.f == pytest.approx(f_want) and h.p == pytest.approx(stats.f.sf(f_want, df1, df2))
    # two rows: the paired t-test's t squared and its p
    two = {n: rows[n] for n in ("draw-0", "draw-1")}
    common = [b for b in blocks if b in two["draw-0"] and b in two["draw-1"]]
    t = stats.ttest_rel([two["draw-1"][b] for b in common], [two["draw-0"][b] for b in common])
    h2 = rows_differ(two)
    assert h2.f == pytest.approx(t.statistic**2) and h2.p == pytest.approx(t.pvalue)
    # rows that differ by constants within every block: no residual, F infinite
    exact = {n: {b: level[b] + i for b in blocks} for i, n in enumerate(("x", "y", "z"))}
    assert rows_differ(exact).f == float("inf") and rows_differ(exact).p == 0.0
    # one row, or one common block: nothing to test
    assert rows_differ({"x": exact["x"]}) is None
    assert rows_differ({"x": {("a", 0): 1.0}, "y": {("a", 0): 2.0, ("b", 0): 1.0}}) is None


def test_pairs_rows_differ(tmp_path):
    """--rows-differ: one F-test per metric below the per-row tables, on the differences to the
    reference (the same F as on the rows' own values); one row is a usage error."""
    from eval.inspect.pairs import pairs_markdown
    from eval.records.runs_csv import read_runs_csv, write_runs_csv
    from eval.stats import rows_differ

    rng = np.random.default_rng(3)
    rows = []
    for scene in ("a-scene", "b-scene", "c-scene"):
        for seed in (0, 1):
            base = 30 + rng.random()
            for row, lead in (("full", 0.0), ("no-reproj", 0.4), ("no-tlr", 0.1)):
                rows.append(
                    dict(suite="paper-ablation", scene=scene, row=row, seed=seed, status="scored")
                    | dict(ldr_oe_psnr=base + lead + rng.normal(0, 0.2), hdr_tae=0.1)
                )
    csv_path = tmp_path / "runs.csv"
    write_runs_csv(csv_path, rows)
    rows = read_runs_csv(csv_path)
    text = pairs_markdown(rows, "paper-ablation", metrics=["ldr_oe_psnr"], differ=True)
    assert "Do the rows differ from one another? (no-reproj, no-tlr:" in text
    line = next(ln for ln in text.splitlines() if ln.startswith("| LDR-OE PSNR | F("))
    own = {
        n: {(r["scene"], r["seed"]): r["ldr_oe_psnr"] for r in rows if r["row"] == n}
        for n in ("no-reproj", "no-tlr")
    }
    h = rows_differ(own)
    assert line == f"| LDR-OE PSNR | F(1, 5) = {h.f:.2f}, p = {h.p:.3f} | 6 |"
    r = _pairs_cli(csv_path, "paper-ablation", "ldr_oe_psnr", "--rows-differ")
    assert r.exit_code == 0 and r.output.strip() == text.strip()
    r = _pairs_cli(csv_path, "paper-ablation", "ldr_oe_psnr", "--rows", "no-tlr", "--rows-differ")
    assert r.exit_code != 0 and "--rows-differ compares two or more rows" in r.output


def test_pairs_compare_the_trained_rows_unless_a_2d_row_is_named(tmp_path):
    """By default `pairs` compares every trained row with the reference, so a suite's Holm family
    and --rows-differ stay the study's; a 2D calibration row (CSV variant "calibration") is
    compared, and joins the family, only when named."""
    from eval.inspect.pairs import pairs_markdown

    rows = _rows(np.random.default_rng(0))
    rng = np.random.default_rng(1)
    for scene in ("a-scene", "b-scene", "c-scene"):
        v = 31 + rng.random()
        for seed in (0, 1):
            rows.append(
                dict(suite="paper-ablation", scene=scene, row="flow-merge", seed=seed)
                | dict(status="scored", variant="calibration", ldr_oe_psnr=v)
            )
    text = pairs_markdown(rows, "paper-ablation", metrics=["ldr_oe_psnr"], holm=True)
    assert "no-reproj - full" in text and "flow-merge" not in text
    assert "Holm's correction over the 1 comparisons" in text
    text = pairs_markdown(
        rows,
        "paper-ablation",
        metrics=["ldr_oe_psnr"],
        holm=True,
        row_names=["no-reproj", "flow-merge"],
    )
    assert "paper-ablation: flow-merge - full" in text
    assert "Holm's correction over the 2 comparisons" in text
