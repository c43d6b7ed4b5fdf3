"""Paired differences per (scene, seed) from the runs CSV: `m4dgs-eval pairs`.

The results page gives each difference row - ref as a mean and interval; the hand-written notes
(lab/results-notes.md) also quote the per-scene values behind them. This module prints those from
the committed CSV, so that every number in the notes can be checked with one command:

    m4dgs-eval pairs control-reproj-priors --ref full-oracle --rows no-reproj-oracle

For each row: per metric, the mean of d = row - ref over the (scene, seed) runs both rows have,
with the same Student-t 95 % interval as the tables' paired differences (`eval.stats.mean_ci`, †
where it excludes 0); the same over scenes (`eval.stats.scene_mean_ci`: d averaged over each
scene's seeds first, the interval over the scene means, as the findings' "over scenes"
column); how many pairs have d > 0 ("> 0": k of n); then d of each pair, in the order of the
header (scenes by name, then seeds).

With `by_seed` (`--by-seed`), for reading a second seed against the first: the mean and interval
of d at each trainer seed alone, and whether the effect differs between scenes by more than its
seeds scatter (`eval.stats.scene_heterogeneity`: the one-way ANOVA of d with the scene as the
factor, F and p; a per-scene pattern seen at one seed has replicated when p is small).

With `holm` (`--holm`): the p-value of each printed comparison's paired t-test adjusted by Holm's
step-down method over all the comparisons printed (rows x metrics: the family a reading draws its
verdicts from; `eval.stats.holm`), † where it is below 0.05, and a closing line counting them.

With `against` (`--against SUITE:REF:ROW`): instead of the differences themselves, their change
against another suite's difference ROW - REF of the same (scene, seed) pairs, those that both have:
a control's difference in differences (the results page's Controls), per pair and over them,
e.g. `m4dgs-eval pairs control-tlr-scale --rows full-tlr-0.1-paper-schedule --against
control-tlr-priors:full:full-tlr-0.1`.

With `differ` (`--rows-differ`), for rows that are levels of one factor (three draws of the
exposure offsets, three TLR weights): whether they differ from one another by more than the
pairs scatter (`eval.stats.rows_differ`: the two-way analysis of variance without replication,
the (scene, seed) pairs as blocks, F and p), below the per-row tables."""

from __future__ import annotations

from typing import Dict, List, Optional, Sequence

from eval.calibration import VARIANT as CALIBRATION_VARIANT
from eval.records.runs_csv import FAILED, SCORED, one_line
from eval.records.suite import SuiteError, builtin_suites, load_eval_suite, metric_columns
from eval.stats import (
    heterogeneity_text,
    interval_text,
    mean_ci,
    rows_differ,
    scene_heterogeneity,
    scene_mean_ci,
)
from eval.stats import holm as holm_adjust
from eval.study.controls import pair_differences

DEFAULT_METRICS = ("ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr", "hdr_tae", "ldr_train_psnr")


def split_spec(text: str, fields: Sequence[str], example: str) -> List[str]:
    """The parts of a colon-separated spec such as SUITE:REF:ROW (`fields` names them); ValueError
    naming the expected form when the count is wrong or a part is empty."""
    parts = [p.strip() for p in text.split(":")]
    if len(parts) != len(fields) or not all(parts):
        raise ValueError(f"{text!r}: give {':'.join(fields)}, e.g. {example}")
    return parts


def _fmt(metric: str, fmts: Dict[str, str]) -> str:
    return fmts.get(metric, ".4f")


ALPHA = 0.05


def _p_text(p) -> str:
    """p with † below ALPHA; n/a without a test."""
    return "n/a" if p is None else f"{p:.3f}{'†' if p < ALPHA else ''}"


def pairs_markdown(
    rows: List[dict],
    suite: str,
    ref: Optional[str] = None,
    row_names: Optional[Sequence[str]] = None,
    metrics: Sequence[str] = DEFAULT_METRICS,
    by_seed: bool = False,
    holm: bool = False,
    against: Optional[Sequence[str]] = None,
    differ: bool = False,
) -> str:
    """Markdown tables of the paired differences of `row_names` (default: every trained row of the
    suite in the CSV but the reference; 2D calibration rows when named) against `ref` (default:
    the suite file's reference row). `suite` is a built-in suite's name or a suite YAML file (its
    `name` is the CSV's suite); with `by_seed`, also per trainer seed and the F-test of scene
    differences; with `holm`, the Holm-adjusted p-values over every printed comparison; with
    `against` = (suite, ref, row), each difference less that suite's row - ref of the same (scene,
    seed): the change, as the results page's Controls read it; with `differ`, whether the rows
    differ from one another (module docstring). Raises ValueError naming what the CSV lacks."""
    from pathlib import Path

    definition = None
    if suite not in builtin_suites() and Path(suite).is_file():
        definition = load_eval_suite(suite)
        suite = definition.name
    present = [r for r in rows if r["suite"] == suite and r.get("status") == SCORED]
    if not present:
        raise ValueError(f"no scored run of suite {suite!r} in the CSV")
    names = list(dict.fromkeys(r["row"] for r in present))
    if ref is None:
        if definition is None:
            try:
                definition = load_eval_suite(suite)
            except SuiteError:
                raise ValueError(
                    f"suite {suite!r} is not built in: give its YAML file as SUITE (its reference "
                    "row is then the default) or the reference row with --ref"
                ) from None
        ref = definition.reference
    if ref not in names:
        raise ValueError(f"suite {suite!r} has no scored run of row {ref!r} (rows: {names})")
    # by default the trained rows: a 2D calibration row joins the family (Holm, --rows-differ)
    # only when named
    cal = {r["row"] for r in present if r.get("variant") == CALIBRATION_VARIANT}
    wanted = (
        [n for n in names if n != ref and n not in cal] if row_names is None else list(row_names)
    )
    unknown = [n for n in wanted if n not in names]
    if unknown:
        raise ValueError(f"suite {suite!r} has no scored run of rows {unknown} (rows: {names})")
    if differ and len(wanted) < 2:
        raise ValueError(f"--rows-differ compares two or more rows; {len(wanted)} given ({wanted})")
    cols = metric_columns()
    bad = [m for m in metrics if m not in cols]
    if bad:
        raise ValueError(f"unknown metrics {bad} (known: {sorted(cols)})")
    fmts = {m: cols[m].fmt for m in metrics}
    diffs_of = {n: {m: pair_differences(rows, suite, n, ref, m) for m in metrics} for n in wanted}
    titles = {n: f"{suite}: {n} - {ref}" for n in wanted}
    if against is not None:
        b_suite, b_ref, b_row = against
        if not any(r["suite"] == b_suite and r.get("status") == SCORED for r in rows):
            raise ValueError(f"--against: no scored run of suite {b_suite!r} in the CSV")
        b_names = {r["row"] for r in rows if r["suite"] == b_suite and r.get("status") == SCORED}
        missing = [n for n in (b_ref, b_row) if n not in b_names]
        if missing:
            raise ValueError(
                f"--against: suite {b_suite!r} has no scored run of rows {missing} "
                f"(rows: {sorted(b_names)})"
            )
        base = {m: pair_differences(rows, b_suite, b_row, b_ref, m) for m in metrics}
        diffs_of = {
            n: {m: {k: v - base[m][k] for k, v in d[m].items() if k in base[m]} for m in metrics}
            for n, d in diffs_of.items()
        }
        titles = {
            n: f"change: ({suite}: {n} - {ref}) - ({b_suite}: {b_row} - {b_ref})" for n in wanted
        }
    out = []
    family = [(n, m) for n in wanted for m in metrics]
    pooled_of = {(n, m): mean_ci(diffs_of[n][m].values()) for n, m in family}
    adjusted = dict(zip(family, holm_adjust([pooled_of[k].p for k in family]))) if holm else {}
    for name in wanted:
        diffs = diffs_of[name]
        keys = sorted(set().union(*diffs.values()), key=lambda k: (str(k[0]), k[1]))
        seeds = sorted({k[1] for k in keys}) if by_seed else []
        extra = [f"seed {sd} (n)" for sd in seeds] + (["scenes differ (F-test)"] if by_seed else [])
        out += [
            titles[name],
            "",
            "| metric | mean ± 95 % (n) | "
            + ("Holm p | " if holm else "")
            + "over scenes (n) | > 0 | "
            + "".join(f"{c} | " for c in extra)
            + " | ".join(f"{s} / {sd}" for s, sd in keys)
            + " |",
            "|:---|---:|---:|---:|" + "---:|" * (len(extra) + len(keys) + int(holm)),
        ]
        for m in metrics:
            d = diffs[m]
            f = _fmt(m, fmts)
            cells = [f"{d[k]:+{f}}" if k in d else "" for k in keys]
            header = cols[m].label
            pooled, scenes = (
                interval_text(pooled_of[(name, m)], f),
                interval_text(scene_mean_ci(d), f),
            )
            more = [f"{sum(v > 0 for v in d.values())} of {len(d)}"]
            more += [
                interval_text(mean_ci(v for k, v in d.items() if k[1] == sd), f) for sd in seeds
            ]
            if by_seed:
                more.append(heterogeneity_text(scene_heterogeneity(d)))
            if holm:
                pooled += " | " + _p_text(adjusted[(name, m)])
            out.append(
                f"| {header} | {pooled} | {scenes} | "
                + "".join(f"{c} | " for c in more)
                + " | ".join(cells)
                + " |"
            )
        out.append("")
    if differ:
        out += [
            f"Do the rows differ from one another? ({', '.join(wanted)}: a two-way analysis of "
            "variance over the (scene, seed) pairs every row has, the rows as the factor)",
            "",
            "| metric | rows differ (F-test) | pairs |",
            "|:---|---:|---:|",
        ]
        for m in metrics:
            h = rows_differ({n: diffs_of[n][m] for n in wanted})
            header = cols[m].label
            n_pairs = "n/a" if h is None else str(h.df_within // h.df_between + 1)
            out.append(f"| {header} | {heterogeneity_text(h)} | {n_pairs} |")
        out.append("")
    # the pairs a failed run keeps out (a result of its configuration, not a run still to come)
    sides = {(suite, n) for n in [ref, *wanted]}
    if against is not None:
        sides |= {(against[0], against[1]), (against[0], against[2])}
    failed = [r for r in rows if r.get("status") == FAILED and (r["suite"], r["row"]) in sides]
    if failed:
        out += [
            "Failed runs (their (scene, seed) pairs are not in the differences above): "
            + "; ".join(
                f"{r['suite']}:{r['row']} on {r['scene']} seed {r['seed']} "
                f"({one_line(r.get('error') or 'no message', 160)})"
                for r in failed
            ),
            "",
        ]
    if holm:
        tested = [v for v in adjusted.values() if v is not None]
        out += [
            f"After Holm's correction over the {len(tested)} comparisons printed (rows x metrics): "
            f"{sum(v < ALPHA for v in tested)} exclude 0 at a family-wise level of 5 %.",
            "",
        ]
    return "\n".join(out)
