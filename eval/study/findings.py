"""The paper's findings (FINDINGS) and their verdicts on the runs CSV: for each, the paper's
difference, ours with its interval and number of (scene, seed) pairs, and the verdict; the
"Findings" section of the results page."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

from eval.paper import load_paper_values
from eval.records.runs_csv import SCORED
from eval.records.suite import metric_columns
from eval.stats import (
    LEVEL,
    by_key,
    heterogeneity_text,
    holm,
    paired_diff,
    scene_heterogeneity,
    scene_paired_diff,
)
from m4dgs.core import io as mio

FINDING_FIGURE_PREFIX = "finding_"  # a finding's figure: finding_<key>.png


# --------------------------------------------------------------------------------------------------
# findings
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Comparison:
    """Δ = row - ref; `expect` the direction the finding claims for the row: "better" or "worse"
    (used where the paper has no value for one of the two rows)."""

    row: str
    ref: str
    expect: str


@dataclass(frozen=True)
class Finding:
    key: str
    title: str
    suite: str
    paper: Optional[str]  # table of eval/paper_values.yaml
    comparisons: Tuple[Comparison, ...]
    metrics: Tuple[str, ...] = ("ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr", "hdr_tae")


FINDINGS_FILE = Path(__file__).with_name("findings.yaml")


def load_findings(path=FINDINGS_FILE) -> Tuple[Finding, ...]:
    """The findings of a findings file (eval/study/findings.yaml: one entry per finding, its
    comparisons as {row, ref, expect}; `metrics` only where they are not the default)."""
    out = []
    for d in mio.read_yaml(path):
        comparisons = tuple(Comparison(c["row"], c["ref"], c["expect"]) for c in d["comparisons"])
        extra = {"metrics": tuple(d["metrics"])} if "metrics" in d else {}
        out.append(Finding(d["key"], d["title"], d["suite"], d["paper"], comparisons, **extra))
    return tuple(out)


# the paper's findings, as data (eval/study/findings.yaml)
FINDINGS: Tuple[Finding, ...] = load_findings()

AGREES, DISAGREES, NOT_SIG, PAPER_TIE, NO_DATA = (
    "agrees",
    "disagrees",
    "not significant",
    "paper tie",
    "not enough data",
)


@dataclass
class ComparisonResult:
    comparison: Comparison
    metric: str
    paper_diff: Optional[float]
    claim: int  # expected sign of Δ (+1 / -1), 0 where the paper's two values are equal
    claim_from: str  # "paper" or "finding"
    ours: object  # eval.stats.Interval or None
    verdict: str
    # the same difference over scenes (eval.stats.scene_paired_diff: n = scenes) and its verdict
    scenes: object = None
    verdict_scenes: str = NO_DATA
    # Holm-adjusted p-value of `ours` within the finding's comparisons (eval.stats.holm) and the
    # verdict with that significance
    p_holm: Optional[float] = None
    verdict_holm: str = NO_DATA
    # do the (scene, seed) differences vary between scenes beyond the seeds' scatter?
    # (eval.stats.scene_heterogeneity; None without two scenes and a scene with two seeds)
    heterogeneity: object = None


def claim_sign(c: Comparison, metric: str, paper_diff: Optional[float]) -> Tuple[int, str]:
    """The sign the finding claims for Δ = row - ref: the paper's sign where it has both values
    (0 for a tie as printed), else the finding's `expect` in the metric's direction."""
    if paper_diff is not None:
        return (0 if abs(paper_diff) < 1e-9 else (1 if paper_diff > 0 else -1)), "paper"
    hib = metric_columns()[metric].higher_is_better
    better = 1 if hib else -1
    return (better if c.expect == "better" else -better), "finding"


def verdict(claim: int, ours, significant: Optional[bool] = None) -> str:
    """The verdict of an interval against the claimed sign; `significant` overrides "the interval
    excludes 0" (e.g. with a Holm-adjusted p-value)."""
    if ours is None or ours.mean is None or ours.half is None:
        return NO_DATA
    if claim == 0:
        return PAPER_TIE
    if not (ours.excludes_zero if significant is None else significant):
        return NOT_SIG
    return AGREES if (ours.mean > 0) == (claim > 0) else DISAGREES


def _holm_verdicts(res: List["ComparisonResult"]) -> None:
    """Fill p_holm / verdict_holm of one finding's results: the family is every comparison of the
    finding that has an interval (paper ties included, so the correction is never too lenient)."""
    adj = holm([None if r.ours is None or r.ours.half is None else r.ours.p for r in res])
    for r, a in zip(res, adj):
        r.p_holm = a
        r.verdict_holm = verdict(r.claim, r.ours, None if a is None else a < 1 - LEVEL)


def evaluate_finding(f: Finding, rows: List[dict]) -> List[ComparisonResult]:
    """Every (comparison, metric) of a finding on the scored CSV rows of its suite: the paired
    difference over the (scene, seed) runs both rows have (eval.stats.paired_diff)."""
    pt = load_paper_values().get(f.paper) if f.paper else None
    mine = [r for r in rows if r["suite"] == f.suite and r.get("status") == SCORED]
    out = []
    for c in f.comparisons:
        a = [r for r in mine if r["row"] == c.row]
        b = [r for r in mine if r["row"] == c.ref]
        for m in f.metrics:
            pd = None
            if pt is not None:
                pa, pb = pt.value(c.row, m), pt.value(c.ref, m)
                pd = None if pa is None or pb is None else pa - pb
            sign, src = claim_sign(c, m, pd)
            va, vb = (by_key(a, m), by_key(b, m)) if a and b else ({}, {})
            ours = paired_diff(va, vb) if a and b else None
            if ours is not None and ours.n == 0:
                ours = None
            scenes = scene_paired_diff(va, vb) if ours is not None else None
            het = scene_heterogeneity({k: va[k] - vb[k] for k in va if k in vb})
            out.append(
                ComparisonResult(
                    c,
                    m,
                    pd,
                    sign,
                    src,
                    ours,
                    verdict(sign, ours),
                    scenes,
                    verdict(sign, scenes),
                    heterogeneity=het,
                )
            )
    _holm_verdicts(out)
    return out


def evaluate_findings(rows: List[dict]) -> Dict[str, List[ComparisonResult]]:
    """{finding key: evaluate_finding} of every finding whose suite has a scored run: what the
    findings tables, their figures and the glance table read (computed once per page)."""
    present = {r["suite"] for r in rows if r.get("status") == SCORED}
    return {f.key: evaluate_finding(f, rows) for f in FINDINGS if f.suite in present}


def paper_inside(res: ComparisonResult) -> Optional[bool]:
    """Whether the paper's Δ lies inside our interval (None without a paper Δ or an interval). A
    "not significant" verdict with the paper's Δ outside our interval says more than "too few
    runs": our runs rule out an effect of the paper's size."""
    iv = res.ours
    if res.paper_diff is None or iv is None or iv.mean is None or iv.half is None:
        return None
    return iv.low <= res.paper_diff <= iv.high


def _claim_text(res: ComparisonResult, col) -> str:
    if res.claim == 0:
        return "tie"
    up = res.claim > 0
    better = up == col.higher_is_better
    return ("+" if up else "-") + (" (better)" if better else " (worse)")


def _paper_diff_text(v: float, fmt: str) -> str:
    """A difference of the paper's values at the column precision, at most 3 decimals (the paper
    prints 2 or 3), signed."""
    if fmt.endswith("f") and fmt[1:-1].isdigit():
        fmt = f".{min(int(fmt[1:-1]), 3)}f"
    return format(v, "+" + fmt)


HETEROGENEITY_ALPHA = 0.05  # "scenes differ" in the findings tables' summary lines


def findings_markdown(
    rows: List[dict],
    notes_link: Optional[str],
    figures: Optional[Dict[str, str]] = None,
    evaluated: Optional[Dict[str, List[ComparisonResult]]] = None,
) -> str:
    """The Findings section; figures: {finding key: link of its forest plot} to show under its
    table; evaluated: evaluate_findings(rows) when the caller has it."""
    if evaluated is None:
        evaluated = evaluate_findings(rows)
    lines = [
        "## Findings",
        "",
        "One table per finding of the paper. Δ = row - ref, paired over the (scene, seed) runs "
        "both rows have (mean ± the Student-t 95 % interval of the mean difference, as in the "
        "tables; n = pairs). Claim: the sign of Δ the paper's own values show (its Syn-Exp-3 "
        "table, `eval/paper_values.yaml`), or, where the paper has no value for one of the rows, "
        "the direction the finding states. Verdict: agrees / disagrees (our interval excludes 0 "
        "on the claimed / the other side), not significant (it includes 0), paper tie (the "
        "paper's two values are equal as printed), not enough data (fewer than 2 pairs). Paper Δ "
        "in ours: whether the paper's Δ lies inside our interval; where it does not, our runs "
        "rule out an effect of the paper's size even when the verdict is not significant. Over "
        "scenes: the same difference averaged per scene first, the interval taken over the scene "
        "means (n = scenes, `eval.stats.scene_paired_diff`), with its verdict; the first interval "
        "speaks for these scenes and their seeds, this one for scenes like them, and with two "
        "scenes it is wide by design. After Holm: the verdict again, with the p-values of the "
        "paired t-tests adjusted by Holm's method over all the comparisons of the finding (its "
        'rows x metrics), so that the chance of one or more false "agrees" or "disagrees" in a '
        "finding is at most 5 % (`eval.stats.holm`); at 95 % per comparison about one in twenty "
        "comparisons excludes 0 by chance when there is no effect, so read a verdict that does not "
        "survive Holm as a lead, not a finding. Scenes differ: whether the differences vary "
        "between scenes by more than between the seeds of one scene (the one-way analysis of "
        "variance with the scene as the factor and the seeds as replicates, its p-value; "
        "`eval.stats.scene_heterogeneity`; n/a with one seed). Where they do, the pairs are not "
        "exchangeable samples of one effect: the first interval still answers for these scenes, "
        "but only the one over scenes answers for scenes like them. With few scenes the test has "
        "little power, so a large p is weak evidence of a uniform effect. The verdicts are "
        "computed from the CSV; what they "
        "mean, and the controls run for disagreements, are written by hand"
        + (f" in [{Path(notes_link).name}]({notes_link})." if notes_link else "."),
        "",
        findings_glance_markdown(rows, evaluated),
    ]
    for f in FINDINGS:
        lines += finding_markdown(f, evaluated.get(f.key), figures)
    return "\n".join(lines)


def finding_markdown(
    f: Finding,
    res: Optional[List[ComparisonResult]],
    figures: Optional[Dict[str, str]] = None,
) -> List[str]:
    """The lines of one finding's section of the Findings section: its table of comparisons,
    the verdict counts before and after Holm, over scenes and where the scenes differ; res:
    evaluate_finding(f, rows), None when its suite has no scored run; figures as in
    findings_markdown."""
    cols = metric_columns()
    lines = [f"### {f.title}", ""]
    if res is None:
        return lines + [f"**not enough data**: no scored run of suite `{f.suite}` in the CSV.", ""]
    src = load_paper_values()[f.paper].source if f.paper else None
    lines += [
        f"Suite `{f.suite}`" + (f"; paper values: {src}." if src else "."),
        "",
        "| row | ref | metric | paper Δ | claim | ours Δ | n | verdict | after Holm "
        "| paper Δ in ours | over scenes | scenes | verdict over scenes | scenes differ |",
        "|:---|:---|:---|---:|:---|---:|---:|:---|:---|:---|---:|---:|:---|---:|",
    ]
    for r in res:
        col = cols[r.metric]
        name = col.label
        pd = "n/a" if r.paper_diff is None else _paper_diff_text(r.paper_diff, col.fmt)
        if r.ours is None or r.ours.mean is None:
            ours, n = "n/a", 0 if r.ours is None else r.ours.n
        else:
            half = "n/a" if r.ours.half is None else format(r.ours.half, col.fmt)
            ours, n = f"{format(r.ours.mean, '+' + col.fmt)} ± {half}", r.ours.n
        claim = _claim_text(r, col) + ("" if r.claim_from == "paper" else " (finding)")
        inside = {True: "yes", False: "no", None: "n/a"}[paper_inside(r)]
        sc = r.scenes
        if sc is None or sc.mean is None:
            over, k = "n/a", 0 if sc is None else sc.n
        else:
            half = "n/a" if sc.half is None else format(sc.half, col.fmt)
            over, k = f"{format(sc.mean, '+' + col.fmt)} ± {half}", sc.n
        lines.append(
            f"| {r.comparison.row} | {r.comparison.ref} | {name} | {pd} | {claim} | {ours} "
            f"| {n} | {r.verdict} | {r.verdict_holm} | {inside} | {over} | {k} "
            f"| {r.verdict_scenes} | {heterogeneity_text(r.heterogeneity, test=False)} |"
        )
    counts = {
        v: sum(r.verdict == v for r in res)
        for v in (AGREES, DISAGREES, NOT_SIG, PAPER_TIE, NO_DATA)
    }
    over = {
        v: sum(r.verdict_scenes == v for r in res)
        for v in (AGREES, DISAGREES, NOT_SIG, PAPER_TIE, NO_DATA)
    }
    tested = sum(r.p_holm is not None for r in res)
    kept = {v: sum(r.verdict_holm == v for r in res) for v in (AGREES, DISAGREES)}
    pairs = max((r.ours.n for r in res if r.ours is not None), default=0)
    inside = [paper_inside(r) for r in res]
    known = [x for x in inside if x is not None]
    lines += [
        "",
        f"Verdicts: {counts[AGREES]} agree, {counts[DISAGREES]} disagree, "
        f"{counts[NOT_SIG]} not significant, {counts[PAPER_TIE]} paper tie, "
        f"{counts[NO_DATA]} not enough data, of {len(res)} comparisons; "
        f"at most {pairs} (scene, seed) pairs per comparison"
        + (
            f"; the paper's Δ lies inside our interval in {sum(known)} of the {len(known)} "
            "comparisons with both."
            if known
            else "."
        ),
        "",
        f"After Holm's correction over the {tested} comparisons with an interval: "
        f"{kept[AGREES]} agree, {kept[DISAGREES]} disagree (with no effect anywhere, about "
        f"{0.05 * tested:.1f} of them would exclude 0 by chance before the correction).",
        "",
        f"Over scenes: {over[AGREES]} agree, {over[DISAGREES]} disagree, "
        f"{over[NOT_SIG]} not significant, {over[PAPER_TIE]} paper tie, "
        f"{over[NO_DATA]} not enough data (fewer than 2 scenes).",
        "",
    ]
    het = [r for r in res if r.heterogeneity is not None]
    if het:
        differ = [r for r in het if r.heterogeneity.p < HETEROGENEITY_ALPHA]
        split = sum(
            r.verdict in (AGREES, DISAGREES) and r.verdict_scenes == NOT_SIG for r in differ
        )
        lines += [
            f"Scenes differ (p < {HETEROGENEITY_ALPHA}) in {len(differ)} of the {len(het)} "
            "comparisons with two or more seeds on some scene"
            + (
                f"; {split} of them resolved over the (scene, seed) pairs and not over scenes"
                if differ
                else ""
            )
            + ".",
            "",
        ]
    if figures and f.key in figures:
        lines += [f"![{FINDING_FIGURE_PREFIX}{f.key}]({figures[f.key]})", ""]
    return lines


def findings_glance_markdown(
    rows: List[dict],
    evaluated: Dict[str, List[ComparisonResult]],
    details_link: Optional[str] = None,
) -> str:
    """One line per finding of the paper: how many (scene, seed) pairs stand behind it and its
    verdicts after Holm's correction within the finding (as in its findings table), so that a
    reader sees at once what the runs so far support; evaluated: evaluate_findings(rows);
    details_link: where the findings tables are (None: below). Findings whose suite has no scored
    run say so."""
    where = f"[the findings tables]({details_link})" if details_link else "the tables below"
    lines = [
        "**The paper's findings at a glance** (verdicts after Holm's correction over each "
        "finding's comparisons; the last column counts the comparisons whose paper Δ lies inside "
        "our 95 % interval, so that our runs do not rule out an effect of the paper's size; "
        f"every comparison with its interval: {where}):",
        "",
        "| finding of the paper | suite | scenes x seeds | pairs | agree | disagree "
        "| not significant | paper tie | not enough data | paper's Δ inside ours |",
        "|:---|:---|:---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for f in FINDINGS:
        if f.key not in evaluated:
            n = len(f.comparisons) * len(f.metrics)
            lines.append(f"| {f.title} | `{f.suite}` | no runs | 0 | 0 | 0 | 0 | 0 | {n} | n/a |")
            continue
        res = evaluated[f.key]
        mine = [r for r in rows if r["suite"] == f.suite and r.get("status") == SCORED]
        holm = [r.verdict_holm for r in res]
        pairs = max((r.ours.n for r in res if r.ours is not None), default=0)
        known = [x for x in (paper_inside(r) for r in res) if x is not None]
        lines.append(
            f"| {f.title} | `{f.suite}` | {len({r['scene'] for r in mine})} x "
            f"{len({r['seed'] for r in mine})} | {pairs} | {holm.count(AGREES)} "
            f"| {holm.count(DISAGREES)} | {holm.count(NOT_SIG)} | {holm.count(PAPER_TIE)} "
            f"| {holm.count(NO_DATA)} | "
            + (f"{sum(known)} of {len(known)}" if known else "n/a")
            + " |"
        )
    return "\n".join(lines) + "\n"
