"""Does one configuration's run repeat in another suite? `m4dgs-eval repeats`.

Several controls train a configuration another suite already has (control-schedule-coverage's
`alternating` is exposure-schedules' `alternating`, control-tlr-grad's `full` is
control-tlr-priors' `full`, ...), and the notes (lab/results-notes.md, docs/reliability.md)
state before the runs whether each such pair should repeat to the last digit (the same code, seed
and kind of machine) or differ like a reseed (another machine's clips). This module checks such a
statement from the committed runs CSV alone:

    m4dgs-eval repeats exposure-schedules:random-values control-schedule-coverage:random-values

For each (scene, seed) both sides have scored: how many of the quality columns both fill are
equal (as the CSV stores them, six significant digits; the time, speed and memory columns,
eval.records.suite LAYOUTS["cost"], differ between any two runs and are left out), the columns that
differ with B - A, and each side's code fingerprint and host. Over the pairs that differ, the mean,
95 % interval and root mean square of B - A in a few headline metrics: "moved like a reseed" is then
a comparison with the suite's seed noise (results.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

from eval.inspect.pairs import split_spec
from eval.records.runs_csv import SCORED
from eval.records.suite import LAYOUTS, metric_columns
from eval.stats import interval_text, mean_ci

HEADLINE = ("ldr_oe_psnr", "hdr_psnr", "hdr_tae")


@dataclass
class PairRepeat:
    """One (scene, seed) that both sides scored."""

    scene: str
    seed: int
    compared: List[str]  # quality columns both rows fill
    differing: Dict[str, Tuple[float, float]] = field(default_factory=dict)  # column: (a, b)
    code: Tuple[str, str] = ("", "")
    host: Tuple[str, str] = ("", "")

    @property
    def equal(self) -> bool:
        return not self.differing


def parse_side(text: str) -> Tuple[str, str]:
    """(suite, row) of "SUITE:ROW"; ValueError otherwise."""
    suite, row = split_spec(text, ("SUITE", "ROW"), "exposure-schedules:alternating")
    return suite, row


def quality_columns() -> List[str]:
    """Every metric column of the CSV but the time, speed and memory ones."""
    cost = set(LAYOUTS["cost"])
    return [k for k in metric_columns() if k not in cost]


def compare_repeats(
    rows: Sequence[dict],
    a: Tuple[str, str],
    b: Tuple[str, str],
    columns: Optional[Sequence[str]] = None,
) -> List[PairRepeat]:
    """PairRepeat of every (scene, seed) where both (suite, row) sides have a scored run, sorted
    by scene then seed. `columns` defaults to quality_columns(). Raises ValueError naming a side
    without scored runs."""
    cols = list(quality_columns() if columns is None else columns)
    side = []
    for suite, row in (a, b):
        got = {
            (r["scene"], r["seed"]): r
            for r in rows
            if r["suite"] == suite and r["row"] == row and r.get("status") == SCORED
        }
        if not got:
            names = sorted({r["row"] for r in rows if r["suite"] == suite})
            raise ValueError(
                f"no scored run of {suite}:{row} in the CSV"
                + (f" (rows of {suite}: {names})" if names else f" (no suite {suite!r})")
            )
        side.append(got)
    out = []
    for key in sorted(set(side[0]) & set(side[1]), key=lambda k: (k[0], k[1])):
        ra, rb = side[0][key], side[1][key]
        both = [c for c in cols if ra.get(c) is not None and rb.get(c) is not None]
        diff = {c: (ra[c], rb[c]) for c in both if ra[c] != rb[c]}
        out.append(
            PairRepeat(
                key[0],
                key[1],
                both,
                diff,
                (ra.get("code", ""), rb.get("code", "")),
                (ra.get("host", ""), rb.get("host", "")),
            )
        )
    return out


def _rms(values: Sequence[float]) -> float:
    return math.sqrt(sum(v * v for v in values) / len(values))


def repeats_markdown(
    rows: Sequence[dict],
    a_text: str,
    b_text: str,
    columns: Optional[Sequence[str]] = None,
    show: int = 4,
) -> Tuple[str, List[PairRepeat]]:
    """(Markdown report, the pairs) of compare_repeats for "SUITE:ROW" sides A and B: a table
    with one line per (scene, seed) and up to `show` differences of each pair that differs (the
    headline metrics first, then the largest relative ones), and the headline metrics' B - A over
    those pairs."""
    a, b = parse_side(a_text), parse_side(b_text)
    reg = metric_columns()
    if columns is not None:
        bad = [c for c in columns if c not in reg]
        if bad:
            raise ValueError(f"unknown metrics {bad} (known: {sorted(reg)})")
    got = compare_repeats(rows, a, b, columns)
    if not got:
        raise ValueError(f"{a_text} and {b_text} have no (scene, seed) that both scored")

    def fmt(c: str, v: float) -> str:
        return f"{v:+{reg[c].fmt}}"

    out = [
        f"{b_text} against {a_text}: each (scene, seed) both scored, B - A",
        "",
        "| scene | seed | equal columns | largest differences (B - A) | code A / B | host A / B |",
        "|:---|---:|---:|:---|:---|:---|",
    ]
    for p in got:
        # the headline metrics first, then the other columns by relative size
        big = sorted(
            p.differing.items(),
            key=lambda kv: (
                kv[0] not in HEADLINE,
                HEADLINE.index(kv[0]) if kv[0] in HEADLINE else 0,
                -abs(kv[1][1] - kv[1][0]) / max(abs(kv[1][0]), abs(kv[1][1]), 1e-12),
            ),
        )[:show]
        shown = ", ".join(f"{c} {fmt(c, vb - va)}" for c, (va, vb) in big) or "-"
        out.append(
            f"| {p.scene} | {p.seed} | {len(p.compared) - len(p.differing)} of {len(p.compared)} "
            f"| {shown} | {p.code[0] or '?'} / {p.code[1] or '?'} "
            f"| {p.host[0] or 'not recorded'} / {p.host[1] or 'not recorded'} |"
        )
    same = sum(p.equal for p in got)
    out += ["", f"{same} of {len(got)} pairs equal in every quality column both fill."]
    moved = [p for p in got if not p.equal]
    if moved:
        out += ["", f"B - A over the {len(moved)} pairs that differ:", ""]
        out += ["| metric | mean ± 95 % (n) | rms |", "|:---|---:|---:|"]
        for c in HEADLINE:
            d = [p.differing[c][1] - p.differing[c][0] if c in p.differing else 0.0
                 for p in moved if c in p.compared]  # fmt: skip
            if not d:
                continue
            f = reg[c].fmt
            out.append(
                f"| {reg[c].group + ' ' if reg[c].group else ''}{reg[c].header} "
                f"| {interval_text(mean_ci(d), f)} | {format(_rms(d), f)} |"
            )
    out.append("")
    return "\n".join(out), got
