"""`m4dgs-eval report findings`: a finding's verdicts read from any runs CSV (a campaign's own
CSV before its rows are merged), the paired differences and Holm's correction recomputed here
with numpy / scipy, several CSVs merged by `suite merge`'s rules, and the same section as the
results page prints."""

from __future__ import annotations

import numpy as np
from click.testing import CliRunner
from scipy import stats

SCENES = ("a-scene", "b-scene", "c-scene")


def _cli(*args):
    from eval.cli import main

    return CliRunner().invoke(main, ["report", "findings", *args])


def _rows(rng, lead):
    """held-movers rows (full, ns-2-chains-free, ns-2-chains-held) over three scenes and two
    seeds; `lead` {row: offset} on every metric of the finding."""
    rows = []
    for scene in SCENES:
        for seed in (0, 1):
            base = 30 + 3 * rng.random()
            for row in ("full", "ns-2-chains-free", "ns-2-chains-held"):
                d = lead.get(row, 0.0)
                rows.append(
                    dict(suite="held-movers", scene=scene, row=row, seed=seed, status="scored")
                    | dict(
                        dyn_ldr_psnr=base + d + rng.normal(0, 0.3),
                        highlight_stops=1.0 - d / 10 + rng.normal(0, 0.05),
                        ldr_oe_psnr=base + d / 2 + rng.normal(0, 0.3),
                    )
                )
    return rows


def _cells(text, ref, metric_label):
    line = next(
        ln
        for ln in text.splitlines()
        if ln.startswith(f"| ns-2-chains-held | {ref} | {metric_label} |")
    )
    return [c.strip() for c in line.strip("|").split("|")]


def _want(rows, row, ref, metric):
    by = {(r["scene"], r["seed"], r["row"]): r[metric] for r in rows}
    return np.array([by[(s, sd, row)] - by[(s, sd, ref)] for s in SCENES for sd in (0, 1)])


def _holm(ps):
    """Holm's step-down adjustment, written out here: the k-th smallest p times (m - k + 1),
    running maximum, capped at 1."""
    order = np.argsort(ps)
    m = len(ps)
    out, run = np.empty(m), 0.0
    for k, i in enumerate(order):
        run = max(run, min(1.0, (m - k) * ps[i]))
        out[i] = run
    return out


def test_findings_from_a_campaign_csv_are_the_paired_differences_after_holm(tmp_path):
    from eval.records.runs_csv import read_runs_csv, write_runs_csv
    from eval.study.findings import FINDINGS, evaluate_findings, findings_markdown

    staged = tmp_path / "held-movers.csv"
    write_runs_csv(staged, _rows(np.random.default_rng(0), {"ns-2-chains-held": 2.0}))
    rows = read_runs_csv(staged)
    r = _cli("held-movers", "--csv", str(staged))
    assert r.exit_code == 0, r.output
    text = r.output
    assert text.startswith("### Holding the depth prior along the highlight chains")
    # every comparison x metric of the finding, recomputed: mean ± t-interval, n, the raw p for Holm
    metrics = [
        ("dyn_ldr_psnr", "Dynamic LDR-OE PSNR", ".2f", True),
        ("highlight_stops", "HDR highlight err (stops)", ".3f", False),
        ("ldr_oe_psnr", "LDR-OE PSNR", ".2f", True),
    ]
    ps, cells = [], []
    for ref in ("full", "ns-2-chains-free"):
        for key, label, fmt, higher in metrics:
            want = _want(rows, "ns-2-chains-held", ref, key)
            half = stats.t.ppf(0.975, len(want) - 1) * want.std(ddof=1) / np.sqrt(len(want))
            c = _cells(text, ref, label)
            assert c[5] == f"{format(want.mean(), '+' + fmt)} ± {format(half, fmt)}"
            assert c[6] == "6"
            ps.append(stats.ttest_rel(want, np.zeros_like(want)).pvalue)
            cells.append((c, want.mean() > 0 if higher else want.mean() < 0))
    for (c, better), p in zip(cells, _holm(np.array(ps))):
        assert c[8] == ("not significant" if p >= 0.05 else ("agrees" if better else "disagrees"))
    # the large lead survives Holm on the movers' pixels against both references
    assert _cells(text, "full", "Dynamic LDR-OE PSNR")[8] == "agrees"
    # the same section the results page prints for these rows
    page = findings_markdown(rows, None, evaluated=evaluate_findings(rows))
    title = next(f.title for f in FINDINGS if f.key == "held-movers")
    section = page.split(f"### {title}\n")[1].split("\n### ")[0]
    assert text.split(f"### {title}\n")[1].strip() == section.strip()


def test_later_csvs_replace_rows_and_a_finding_without_runs_says_so(tmp_path):
    from eval.records.runs_csv import write_runs_csv

    rng = np.random.default_rng(1)
    base = tmp_path / "runs.csv"
    write_runs_csv(base, _rows(rng, {}))
    # the staged CSV re-scores ns-2-chains-held on every pair 5 dB higher, and adds a failed run
    # that must not replace a scored one
    staged_rows = [
        r | dict(dyn_ldr_psnr=r["dyn_ldr_psnr"] + 5.0)
        for r in _rows(np.random.default_rng(1), {})
        if r["row"] == "ns-2-chains-held"
    ]
    staged_rows.append(
        dict(suite="held-movers", scene="a-scene", row="full", seed=0, status="failed")
    )
    staged = tmp_path / "staged.csv"
    write_runs_csv(staged, staged_rows)
    one = _cli("held-movers", "--csv", str(base)).output
    both = _cli("held-movers", "--csv", str(base), "--csv", str(staged)).output
    a = float(_cells(one, "full", "Dynamic LDR-OE PSNR")[5].split(" ± ")[0])
    b = float(_cells(both, "full", "Dynamic LDR-OE PSNR")[5].split(" ± ")[0])
    assert abs((b - a) - 5.0) < 0.006  # every pair moved by 5 dB, printed to 2 decimals
    assert _cells(both, "full", "Dynamic LDR-OE PSNR")[6] == "6"  # the failed run kept out
    # no key: every finding whose suite has a scored run; a named one without runs says so
    r = _cli("--csv", str(base))
    assert r.exit_code == 0 and r.output.count("\n### ") + r.output.startswith("### ") == 1
    r = _cli("held-movers-main", "--csv", str(base))
    assert r.exit_code == 0
    assert "no scored run of suite `held-movers-main`" in r.output


def test_bad_keys_and_files_are_usage_errors_naming_them(tmp_path):
    from eval.records.runs_csv import write_runs_csv

    r = _cli("held-movers,nope", "--csv", str(tmp_path / "missing.csv"))
    assert r.exit_code == 2 and "missing.csv" in r.output
    csv_path = tmp_path / "runs.csv"
    write_runs_csv(csv_path, _rows(np.random.default_rng(2), {}))
    not_runs = tmp_path / "notes.csv"
    not_runs.write_text("scene,value\na,1\n")
    r = _cli("--csv", str(csv_path), "--csv", str(not_runs))
    assert r.exit_code != 0 and "Traceback" not in r.output
    assert "notes.csv: not a runs CSV" in r.output and "suite, row, seed, status" in r.output
    r = _cli("held-movers,nope", "--csv", str(csv_path))
    assert r.exit_code == 2 and "nope" in r.output and "held-movers-main" in r.output
    empty = tmp_path / "empty.csv"
    write_runs_csv(empty, [])
    r = _cli("--csv", str(empty))
    assert r.exit_code == 1 and "--list" in r.output
    listed = _cli("--list").output.splitlines()
    assert any(ln.startswith("held-movers\tsuite held-movers\t") for ln in listed)
