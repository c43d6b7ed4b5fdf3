"""Table statistics: t-intervals and paired differences against scipy.stats, the agreement with the
paper's direction, trainer seeds in the job list, the paper-values file, and tables rendered from
synthetic rows."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as sps

from eval import stats, tables
from eval.tables import Column, TableSpec


# --------------------------------------------------------------------------------------------------
# intervals
# --------------------------------------------------------------------------------------------------
def test_mean_ci_matches_scipy_t():
    x = [1.0, 2.0, 3.0, 4.0, 5.0]
    iv = stats.mean_ci(x)
    assert iv.n == 5 and iv.mean == pytest.approx(3.0)
    # t_{0.975, 4} = 2.776445..., s = sqrt(2.5): h = 2.776445 * 1.581139 / sqrt(5) = 1.963243
    assert iv.half == pytest.approx(sps.t.ppf(0.975, 4) * math.sqrt(2.5) / math.sqrt(5), rel=1e-12)
    assert iv.half == pytest.approx(1.963243, abs=1e-6)
    lo, hi = sps.t.interval(0.95, 4, loc=3.0, scale=sps.sem(x))
    assert (iv.low, iv.high) == (pytest.approx(lo, rel=1e-12), pytest.approx(hi, rel=1e-12))
    rng = np.random.default_rng(3)
    for n in (2, 3, 7, 18):
        y = rng.normal(30, 2, n)
        iv = stats.mean_ci(y, level=0.9)
        lo, hi = sps.t.interval(0.9, n - 1, loc=y.mean(), scale=sps.sem(y))
        assert iv.half == pytest.approx((hi - lo) / 2, rel=1e-10)
    # n < 2: no interval; NaN / None are dropped
    assert stats.mean_ci([4.0]) == stats.Interval(4.0, None, 1)
    assert stats.mean_ci([]) == stats.Interval(None, None, 0)
    assert stats.mean_ci([1.0, None, float("nan"), 3.0]).n == 2
    assert stats.t_quantile(0.975, 10) == pytest.approx(2.228139, abs=1e-6)


def test_scene_paired_diff_is_a_t_interval_over_scene_means():
    rng = np.random.default_rng(5)
    a, b = {}, {}
    for i, sc in enumerate(["s0", "s1", "s2"]):
        for seed in range(3):
            b[(sc, seed)] = rng.normal(30, 1)
            a[(sc, seed)] = b[(sc, seed)] + [0.5, 1.5, -0.2][i] + rng.normal(0, 0.1)
    del a[("s2", 2)]  # an unpaired run is dropped, the scene stays
    iv = stats.scene_paired_diff(a, b)
    means = [np.mean([a[k] - b[k] for k in a if k[0] == sc]) for sc in ("s0", "s1", "s2")]
    lo, hi = sps.ttest_1samp(means, 0.0).confidence_interval(0.95)
    assert iv.n == 3 and iv.mean == pytest.approx(np.mean(means))
    assert iv.half == pytest.approx((hi - lo) / 2)
    # many seeds on each scene do not narrow it: the scenes disagree
    assert not iv.excludes_zero and stats.paired_diff(a, b).excludes_zero
    one = stats.scene_paired_diff(
        {("s0", 0): 1.0, ("s0", 1): 2.0}, {("s0", 0): 0.0, ("s0", 1): 0.0}
    )
    assert one.n == 1 and one.mean == 1.5 and one.half is None


def test_paired_diff_matches_ttest_rel():
    a = [30.1, 31.4, 29.8, 33.0, 28.7, 30.9]
    b = [29.5, 31.0, 29.9, 32.1, 28.0, 30.2]
    keys = [("s0", 0), ("s1", 0), ("s2", 0), ("s0", 1), ("s1", 1), ("s2", 1)]
    iv = stats.paired_diff(dict(zip(keys, a)), dict(zip(keys, b)))
    res = sps.ttest_rel(a, b)
    ci = res.confidence_interval(0.95)
    assert iv.n == 6 and iv.mean == pytest.approx(np.mean(np.subtract(a, b)))
    assert iv.low == pytest.approx(ci.low, rel=1e-10) and iv.high == pytest.approx(
        ci.high, rel=1e-10
    )
    assert iv.excludes_zero == (res.pvalue < 0.05)
    # only the keys both have are paired
    iv2 = stats.paired_diff({**dict(zip(keys, a)), ("s9", 0): 99.0}, dict(zip(keys[:4], b[:4])))
    ci2 = sps.ttest_rel(a[:4], b[:4]).confidence_interval(0.95)
    assert iv2.n == 4 and (iv2.low, iv2.high) == (pytest.approx(ci2.low), pytest.approx(ci2.high))


def test_agreement_logic():
    sig_neg = stats.Interval(-0.9, 0.3, 6)  # [-1.2, -0.6]
    sig_pos = stats.Interval(0.5, 0.2, 6)
    ns = stats.Interval(-0.1, 0.3, 6)
    assert stats.agreement(-1.13, sig_neg) == ("-", "-", "agree")
    assert stats.agreement(-1.13, sig_pos) == ("-", "+", "disagree")
    assert stats.agreement(0.014, sig_pos) == ("+", "+", "agree")
    assert stats.agreement(-1.13, ns) == ("-", "n.s.", "not significant")
    assert stats.agreement(0.0, sig_neg) == ("0", "-", "paper tie")
    assert stats.agreement(0.057 - 0.057, ns) == ("0", "n.s.", "not significant")
    assert stats.agreement(None, sig_neg) == ("n/a", "-", "n/a")
    assert stats.agreement(-1.0, stats.Interval(-1.0, None, 1)) == ("-", "n/a", "n/a")
    assert stats.agreement(-1.0, None) == ("-", "n/a", "n/a")


# --------------------------------------------------------------------------------------------------
# rendered tables
# --------------------------------------------------------------------------------------------------
def _synthetic_rows():
    """3 scenes x 2 seeds; (a) loses ~1 dB PSNR, (e) raises TAE; values chosen by hand."""
    psnr = {
        "full": [30.0, 30.2, 32.0, 31.8, 28.0, 28.4],
        "(a)": [29.0, 29.1, 31.0, 30.9, 27.1, 27.2],
        "(e)": [30.1, 30.0, 32.1, 31.7, 28.2, 28.3],
    }
    tae = {
        "full": [0.10, 0.11, 0.12, 0.12, 0.09, 0.10],
        "(a)": [0.10, 0.12, 0.12, 0.11, 0.09, 0.10],
        "(e)": [0.13, 0.13, 0.14, 0.15, 0.11, 0.12],
    }
    keys = [(f"s{k // 2}", k % 2) for k in range(6)]
    return (
        [
            {"method": m, "scene": sc, "seed": sd, "psnr": psnr[m][i], "tae": tae[m][i]}
            for m in psnr
            for i, (sc, sd) in enumerate(keys)
        ],
        psnr,
        tae,
    )


def _spec(**kw):
    cols = [Column("psnr", "PSNR", True, ".2f", "LDR-OE"), Column("tae", "HDR-TAE", False, ".4f")]
    return TableSpec(columns=cols, title="T", **kw)


PAPER = {
    "full": {"psnr": 34.75, "tae": 0.057},
    "(a)": {"psnr": 33.62, "tae": 0.057},
    "(e)": {"psnr": 34.71, "tae": 0.071},
}


def test_markdown_with_intervals_differences_and_paper():
    rows, psnr, tae = _synthetic_rows()
    md = tables.render_markdown(
        rows,
        _spec(intervals=True, reference="full", paper=PAPER, paper_source="Table 3"),
        conventions={},
    )
    lines = md.splitlines()
    assert lines[2] == (
        "| Method | n | LDR-OE PSNR↑ | Δ LDR-OE PSNR | Paper LDR-OE PSNR | LDR-OE PSNR: paper / "
        "ours / "
        "agree | HDR-TAE↓ | Δ HDR-TAE | Paper HDR-TAE | HDR-TAE: paper / ours / agree |"
    )
    by = {
        ln.split(" | ")[0][2:]: [c.strip() for c in ln.strip("|").split("|")] for ln in lines[4:7]
    }
    # full: mean +- t-interval over its 6 runs, bold best PSNR; its own difference cells read "ref"
    h = sps.t.ppf(0.975, 5) * np.std(psnr["full"], ddof=1) / math.sqrt(6)
    assert by["full"][:6] == [
        "full",
        "6",
        f"**{np.mean(psnr['full']):.2f}** ± {h:.2f}",
        "ref",
        "34.75",
        "ref",
    ]
    # (a): paired difference to full over (scene, seed), significant -> dagger; paper also lower ->
    # agree
    d = np.subtract(psnr["(a)"], psnr["full"])
    ci = sps.ttest_rel(psnr["(a)"], psnr["full"]).confidence_interval()
    assert ci.high < 0
    assert by["(a)"][3] == f"{d.mean():+.2f} ± {(ci.high - ci.low) / 2:.2f}†"
    assert by["(a)"][4:6] == ["33.62", "- / - / agree"]
    # (a) TAE: the paper prints equal values, ours not significant
    assert "†" not in by["(a)"][7] and by["(a)"][8:10] == ["0.057", "0 / n.s. / not significant"]
    # (e): TAE up significantly, as in the paper; PSNR difference not significant
    assert by["(e)"][7].endswith("†") and by["(e)"][7].startswith("+0.02")
    assert by["(e)"][9] == "+ / + / agree" and by["(e)"][5] == "- / n.s. / not significant"
    notes = "\n".join(ln for ln in lines if ln.startswith("- "))
    assert "Student-t 95 % confidence interval" in notes and "n/a for n < 2" in notes
    assert "paired difference row - full" in notes and "† where that interval excludes 0" in notes
    assert "(Table 3)" in notes


def test_latex_and_csv_with_statistics():
    rows, psnr, _ = _synthetic_rows()
    spec = _spec(intervals=True, reference="full", paper=PAPER)
    tex = tables.render_latex(rows, spec, conventions={})
    assert "\\begin{tabular}{l" + "r" * 9 + "}" in tex
    assert "\\multicolumn{4}{c}{LDR-OE PSNR$\\uparrow$}" in tex and "\\cmidrule(lr){3-6}" in tex
    assert "\\textbf{30.07} $\\pm$ " in tex and "$^\\dagger$" in tex and "- / - / agree" in tex
    assert "$\\Delta$: paired difference" in tex
    csv_text = tables.render_csv(rows, spec, conventions={})
    head, full, a, _e = [ln.split(",") for ln in csv_text.strip().splitlines()]
    assert head[:6] == [
        "Method",
        "n_scenes",
        "n_runs",
        "LDR-OE PSNR",
        "LDR-OE PSNR ci95",
        "Δ LDR-OE PSNR",
    ]
    assert full[:4] == ["full", "3", "6", "30.07"] and full[5] == "ref"
    assert a[5] == "-1.02" and a[7] == "yes" and a[8] == "33.62" and a[9] == "- / - / agree"
    # without statistics the CSV keeps its plain form
    assert (
        tables.render_csv(rows, _spec(), conventions={}).splitlines()[0]
        == "Method,n_scenes,LDR-OE PSNR,HDR-TAE"
    )


def test_interval_na_for_one_run_and_missing_reference():
    rows = [
        {"method": "full", "scene": "a", "psnr": 30.0, "tae": 0.1},
        {"method": "b", "scene": "a", "psnr": 29.0, "tae": 0.1},
    ]
    md = tables.render_markdown(rows, _spec(intervals=True, reference="full"), conventions={})
    assert "| b | 1 | 29.00 ± n/a | -1.00 ± n/a |" in md
    md2 = tables.render_markdown(rows, _spec(intervals=True, reference="nope"), conventions={})
    assert "Δ" not in md2  # no reference row: no difference columns


def test_build_tables_with_paper_values_and_seeds():
    from eval.records.suite import TableDef
    from eval.records.suite_data import build_tables

    rows, psnr, tae = _synthetic_rows()
    names = {"full": "full", "(a)": "no-video-init", "(e)": "no-tlr"}
    labels = {"full": "(f) full", "(a)": "(a) w/o video init", "(e)": "(e) w/o TLR"}
    entries = [
        {
            "scene": r["scene"],
            "row": names[r["method"]],
            "label": labels[r["method"]],
            "seed": r["seed"],
            "run_dir": "x",
            "clip_dir": "y",
            "metrics": {
                "ldr_oe_psnr": r["psnr"],
                "ldr_ne_psnr": r["psnr"] - 0.2,
                "hdr_psnr": r["psnr"] + 3,
                "hdr_tae": r["tae"],
                "ldr_convention": "ldr_png",
            },
        }
        for r in rows
    ]
    text = build_tables(
        entries, [TableDef("Ablations", "ablation", "ablation")], "markdown", reference="full"
    )
    a_line = next(ln for ln in text.splitlines() if ln.startswith("| (a) w/o video init"))
    assert (
        "| 6 |" in a_line and "33.62" in a_line and "36.07" in a_line
    )  # the paper's (a) row, typed values
    assert "- / - / agree" in a_line and "†" in a_line
    f_line = next(ln for ln in text.splitlines() if ln.startswith("| (f) full"))
    assert "34.75" in f_line and "ref" in f_line
    assert "paper Table 3" in text


# --------------------------------------------------------------------------------------------------
# seeds in the job list
# --------------------------------------------------------------------------------------------------
def test_job_list_with_seeds(tmp_path):
    from eval.experiments.runner import find_job, job_list, seeds_present

    one = job_list("exposure-noise", tmp_path, "tiny")
    three = job_list("exposure-noise", tmp_path, "tiny", seeds=3)
    assert len(three) == 3 * len(one)
    assert [j.to_json() for j in three[: len(one)]] == [
        j.to_json() for j in one
    ]  # seed 0 unchanged
    assert all(
        j.seed == 0 and "seed" not in j.overrides and "--seed" not in j.command() for j in one
    )
    j0 = one[0]
    for s in (1, 2):
        js = [j for j in three if j.seed == s]
        assert len(js) == len(one)
        j = next(x for x in js if x.scene == j0.scene and x.row == j0.row)
        assert j.run_dir == str(
            tmp_path.resolve() / "runs" / "exposure-noise" / j0.scene / f"{j0.row}-seed-{s}"
        )
        assert j.clip_dir == j0.clip_dir  # the clip stays the same
        assert j.overrides == {**j0.overrides, "seed": s}
        assert j.id.endswith(f"/{j0.row}-seed-{s}") and j.command()[-2:] == ["--seed", str(s)]
        assert (
            find_job("exposure-noise", tmp_path, "tiny", j0.scene, j0.row, s).run_dir == j.run_dir
        )
    assert len({j.run_dir for j in three}) == len(three)
    # a row's own seed override is offset, not replaced
    suite = tmp_path / "s.yaml"
    suite.write_text(
        "name: s\nscenes: tiny\nrows:\n  - {name: a, variant: full, overrides: {seed: 10}}\n"
    )
    assert [j.overrides["seed"] for j in job_list(suite, tmp_path, "tiny", seeds=2)][-1] == 11
    # the table finds the seeds that have run folders
    assert seeds_present("exposure-noise", tmp_path, "tiny") == 1
    from pathlib import Path

    Path(three[-1].run_dir).mkdir(parents=True)
    assert seeds_present("exposure-noise", tmp_path, "tiny") == 3


def test_seed_suffix_is_reserved_and_suite_reference():
    from eval.records.suite import SuiteError, load_eval_suite, parse_suite

    base = {"name": "x", "scenes": "tiny"}
    with pytest.raises(SuiteError, match="seed"):
        parse_suite({**base, "rows": [{"name": "full-seed-1", "variant": "full"}]})
    with pytest.raises(SuiteError, match="reference"):
        parse_suite({**base, "rows": [{"variant": "full"}], "reference": "nope"})
    with pytest.raises(SuiteError, match="paper"):
        parse_suite(
            {
                **base,
                "rows": [{"variant": "full"}],
                "tables": [{"columns": "ablation", "paper": "nope"}],
            }
        )
    assert parse_suite({**base, "rows": [{"variant": "full"}]}).reference == "full"
    assert load_eval_suite("control-points").reference == "ns-4"
    assert load_eval_suite("exposure-noise").reference == "ev-0"
    assert load_eval_suite("exposure-schedules").reference == "alternating"


# --------------------------------------------------------------------------------------------------
# the paper's values
# --------------------------------------------------------------------------------------------------
def test_paper_values_file():
    from eval.paper import load_paper_values, paper_records
    from eval.records.suite import builtin_suites, load_eval_suite, metric_columns

    pv = load_paper_values()
    recs = paper_records()
    assert {"table", "row", "paper_row", "metric", "value", "source"} <= set(recs[0])
    assert all(r["source"].startswith("paper ") for r in recs)
    reg = set(metric_columns()) | {"hdr_train_lpips"}
    assert {r["metric"] for r in recs} <= reg
    # the full model's values are the same in every table that lists it
    ref = {"ldr_oe_psnr": 34.75, "ldr_ne_psnr": 34.54, "hdr_psnr": 37.64, "hdr_tae": 0.057}
    for key, row in (
        ("main", "full"),
        ("ablation", "full"),
        ("control-points", "ns-4"),
        ("exposure-schedules", "alternating"),
        ("exposure-noise", "ev-0"),
        ("priors", "full"),
    ):
        assert {k: pv[key].value(row, k) for k in ref} == ref, key
    assert pv["ablation"].value("no-video-init", "hdr_psnr") == 36.07
    assert pv["main"].value("ldr-reproj-consecutive", "ldr_oe_psnr") == 17.59
    assert pv["main"].paper_rows["ldr-reproj-consecutive"] == "SplineGS-HDR"
    # every suite table with paper values: the rows exist in the suite and the reference row has
    # values
    used = set()
    for name in builtin_suites():
        s = load_eval_suite(name)
        for t in s.tables:
            if t.paper:
                used.add(t.paper)
                rows = {r.name for r in s.rows}
                assert s.reference in pv[t.paper].rows, (name, t.paper)
                assert sum(r in rows for r in pv[t.paper].rows) >= 2, (name, t.paper)
    assert {
        "main",
        "ablation",
        "control-points",
        "exposure-schedules",
        "exposure-noise",
        "priors",
    } <= used


# --------------------------------------------------------------------------------------------------
# p-values and Holm's correction
# --------------------------------------------------------------------------------------------------
def test_interval_p_value_matches_scipy_and_the_interval():
    rng = np.random.default_rng(11)
    for n, shift in ((2, 0.3), (4, 0.8), (6, 0.1), (9, -0.5)):
        a, b = rng.normal(30, 1, n), rng.normal(30, 1, n)
        a = b + shift + rng.normal(0, 0.4, n)
        keys = [(f"s{i}", 0) for i in range(n)]
        iv = stats.paired_diff(dict(zip(keys, a)), dict(zip(keys, b)))
        assert iv.p == pytest.approx(sps.ttest_rel(a, b).pvalue, rel=1e-9)
        assert iv.excludes_zero == (iv.p < 0.05)
    assert stats.mean_ci([1.0]).p is None
    assert stats.mean_ci([2.0, 2.0]).p == 0.0 and stats.mean_ci([0.0, 0.0]).p == 1.0


def _holm_closed_testing(p):
    """Holm's adjusted p-values by their closed-testing definition: the largest Bonferroni p-value
    min(1, |S| min_{j in S} p_j) over every subset S of the family that contains the test."""
    from itertools import combinations

    m = len(p)
    out = []
    for i in range(m):
        best = 0.0
        for size in range(1, m + 1):
            for sub in combinations(range(m), size):
                if i in sub:
                    best = max(best, min(1.0, size * min(p[j] for j in sub)))
        out.append(best)
    return out


def test_holm_matches_closed_testing_and_a_worked_example():
    # worked example: sorted 0.005, 0.01, 0.03, 0.04 -> x4, x3, x2, x1 = 0.02, 0.03, 0.06, 0.04,
    # then running maxima 0.02, 0.03, 0.06, 0.06
    got = stats.holm([0.01, 0.04, 0.03, 0.005])
    assert got == pytest.approx([0.03, 0.06, 0.06, 0.02])
    rng = np.random.default_rng(2)
    for m in (1, 2, 5, 8):
        p = list(rng.uniform(0, 0.2, m) ** 2)
        assert stats.holm(p) == pytest.approx(_holm_closed_testing(p), rel=1e-12)
    # tests without a p-value stay None and are not part of the family
    assert stats.holm([None, 0.02, None, 0.04]) == [
        None,
        pytest.approx(0.04),
        None,
        pytest.approx(0.04),
    ]
    assert stats.holm([]) == []


def test_seed_noise_is_the_rms_seed_difference_and_pools_more_seeds():
    """Two seeds per group: sqrt(mean((s1 - s0)^2)) computed directly. Three seeds: twice the
    pooled variance equals the mean squared difference over all pairs within a group (for each
    group, sum over i<j of (x_i - x_j)^2 = k * sum (x_i - mean)^2)."""
    rng = np.random.default_rng(3)
    two = {("s", r): list(rng.normal(30, 1, 2)) for r in range(7)}
    sn = stats.seed_noise({**two, ("lonely", 0): [29.0], ("blank", 0): [float("nan"), 30.0]})
    d = np.array([v[1] - v[0] for v in two.values()])
    assert sn.groups == 7
    assert sn.rms_diff == pytest.approx(math.sqrt(np.mean(d**2)), rel=1e-12)
    assert sn.largest == pytest.approx(np.max(np.abs(d)), rel=1e-12)
    three = {g: list(rng.normal(0, 0.5, 3)) for g in range(5)}
    sq = [(v[i] - v[j]) ** 2 for v in three.values() for i in range(3) for j in range(i + 1, 3)]
    # pooled: 2 * sum ss / sum df = 2 * (sum_pairs / 3) / (5 * 2); mean over pairs = sum_pairs / 15
    sn3 = stats.seed_noise(three)
    assert sn3.rms_diff**2 == pytest.approx(np.mean(sq), rel=1e-12)
    assert sn3.largest == pytest.approx(max(np.ptp(v) for v in three.values()))
    assert stats.seed_noise({"a": [1.0], "b": []}) is None
