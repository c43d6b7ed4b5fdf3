"""The controls (CONTROLS): runs made to test a disagreement with the paper. For each, the effect
as found, the same effect under the control and their difference in differences with its interval;
the "Controls" section of the results page."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

from eval.records.runs_csv import SCORED
from eval.records.suite import metric_columns
from eval.stats import LEVEL, by_key, holm, interval_text, mean_ci, paired_diff
from eval.study.findings import NO_DATA
from eval.tables import in_stops
from m4dgs.core import io as mio

CONTROLS_FIGURE = "controls.png"  # the overview figure of the controls


# --------------------------------------------------------------------------------------------------
# controls for disagreements
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Effect:
    """Δ = row - ref within one suite, under a named condition (e.g. "realistic priors")."""

    suite: str
    row: str
    ref: str
    condition: str


@dataclass(frozen=True)
class Control:
    """A control run for a disagreement: does the effect found under `base` change under
    `control`? The change is the difference of the two paired differences (a difference in
    differences), paired over the (scene, seed) runs all four rows have. `arm` names which of the
    three causes the control tests (method, scale, benchmark; lab/results-notes.md)."""

    key: str
    title: str
    arm: str
    base: Effect
    control: Effect
    metrics: Tuple[str, ...] = ("ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr", "hdr_tae")


CONTROLS_FILE = Path(__file__).with_name("controls.yaml")


def load_controls(path=CONTROLS_FILE) -> Tuple[Control, ...]:
    """The controls of a controls file (eval/study/controls.yaml: one entry per control, its base
    and control effects as {suite, row, ref, condition}; `metrics` only where they are not the
    default)."""
    out = []
    for d in mio.read_yaml(path):
        base, control = (
            Effect(e["suite"], e["row"], e["ref"], e["condition"])
            for e in (d["base"], d["control"])
        )
        extra = {"metrics": tuple(d["metrics"])} if "metrics" in d else {}
        out.append(Control(d["key"], d["title"], d["arm"], base, control, **extra))
    return tuple(out)


# the controls run for disagreements, as data (eval/study/controls.yaml)
CONTROLS: Tuple[Control, ...] = load_controls()

NO_CHANGE, GROWS, SHRINKS = "no resolvable change", "grows", "shrinks"
REVERSES = "reverses"


@dataclass
class ControlResult:
    metric: str
    base: object  # eval.stats.Interval of the base effect (None: no data)
    control: object  # the same under the control
    change: object  # Interval of control - base, paired over the keys all four rows have
    reading: str
    # the reading with the change's p-value Holm-adjusted over the control's metrics
    reading_holm: str = NO_DATA


def pair_differences(
    rows: List[dict], suite: str, row: str, ref: str, metric: str
) -> Dict[tuple, float]:
    """{(scene, seed): row - ref} of one metric over the scored CSV rows of `suite`, in key
    order (the Controls' effects and `m4dgs-eval pairs`). A ratio metric that the tables show in
    stops (a `log2` column, e.g. highlight_peak_ratio) differs in stops, log2(row / ref), as the
    tables' paired differences do; a pair with a non-positive ratio is left out."""
    mine = [r for r in rows if r["suite"] == suite and r.get("status") == SCORED]
    col = metric_columns().get(metric)
    if col is not None and col.log2:
        mine = [{**r, metric: in_stops(r.get(metric))} for r in mine]
    a = by_key([r for r in mine if r["row"] == row], metric)
    b = by_key([r for r in mine if r["row"] == ref], metric)
    return {k: a[k] - b[k] for k in sorted(a) if k in b}


def _effect_by_key(e: Effect, rows: List[dict], metric: str) -> Dict[tuple, float]:
    """{(scene, seed): row - ref} of one metric over the scored CSV rows of e's suite."""
    return pair_differences(rows, e.suite, e.row, e.ref, metric)


def control_reading(base, change, significant: Optional[bool] = None) -> str:
    """How the effect moves under the control when the change's interval excludes 0, read on the
    effect's size: with the control the effect is base.mean + change.mean, "shrinks" when that is
    smaller in magnitude than base.mean, else "grows" (same sign) or "reverses" (the other sign,
    and at least as large: an effect near 0 that becomes a large one of the opposite sign);
    otherwise "no resolvable change", or NO_DATA (fewer than 2 pairs). `significant` overrides
    "the interval excludes 0" (e.g. with a Holm-adjusted p-value)."""
    if change is None or change.half is None or base is None or base.mean is None:
        return NO_DATA
    if not (change.excludes_zero if significant is None else significant):
        return NO_CHANGE
    after = base.mean + change.mean
    if abs(after) < abs(base.mean):
        return SHRINKS
    return GROWS if (after > 0) == (base.mean > 0) else REVERSES


def evaluate_control(c: Control, rows: List[dict]) -> List[ControlResult]:
    """Per metric: the base effect, the control effect (each paired over its own (scene, seed)
    pairs) and the change control - base (paired over the pairs both effects have), read as it is
    and after Holm's correction over the control's metrics."""
    out = []
    for m in c.metrics:
        eb, ec = _effect_by_key(c.base, rows, m), _effect_by_key(c.control, rows, m)
        base = mean_ci(eb.values()) if eb else None
        ctrl = mean_ci(ec.values()) if ec else None
        change = paired_diff(ec, eb) if eb and ec else None
        if change is not None and change.n == 0:
            change = None
        out.append(ControlResult(m, base, ctrl, change, control_reading(base, change)))
    adj = holm([None if r.change is None or r.change.half is None else r.change.p for r in out])
    for r, a in zip(out, adj):
        r.reading_holm = control_reading(r.base, r.change, None if a is None else a < 1 - LEVEL)
    return out


def _provenance_of(e: Effect, rows: List[dict], column: str) -> List[str]:
    return sorted(
        {
            str(r.get(column) or "?")
            for r in rows
            if r["suite"] == e.suite and r["row"] in (e.row, e.ref) and r.get("status") == SCORED
        }
    )


def controls_markdown(
    rows: List[dict], notes_link: Optional[str], figure: Optional[str] = None
) -> str:
    """The "Controls" section: one table per control whose two effects have data, after the
    overview figure (`controls_figure`; `figure`: its link) when there is one."""
    cols = metric_columns()
    lines = [
        "## Controls",
        "",
        "Runs made to tell apart why a result disagrees with the paper (the method, the scale of "
        "the runs, or the benchmark). Each table compares the effect as found (base) with the "
        "same effect under the control: Δ = row - ref, each paired over its own (scene, seed) "
        "runs, and the change = control Δ - base Δ, paired over the (scene, seed) runs all four "
        "rows have (a difference in differences; mean ± Student-t 95 % interval, † where it "
        "excludes 0). Reading, on the effect's size (base Δ + change): it grows or shrinks under "
        "the control, or reverses (changes sign and ends at least as large), when the change is "
        "resolved (†); else no resolvable change; after Holm: the same with the change's "
        "p-value adjusted over the control's metrics (Holm's method, family-wise 5 %). An "
        "effect and its control compare rows of one code and generator version unless the "
        "table says otherwise."
        + (
            f" What the answers mean is written in [{Path(notes_link).name}]({notes_link})."
            if notes_link
            else ""
        ),
        "",
    ]
    if figure:
        lines += [
            "Overview (LDR-OE PSNR and HDR-TAE): each control's base effect (grey) and the same "
            "effect under the control (blue), mean and 95 % interval, joined by an arrow; the "
            "blue marker is filled where the change survives Holm's correction. Labels are the "
            "controls' keys, named in each section below.",
            "",
            f"![{CONTROLS_FIGURE[:-4]}]({figure})",
            "",
        ]
    present = {r["suite"] for r in rows if r.get("status") == SCORED}
    for c in CONTROLS:
        lines += [f"### {c.title}", ""]
        missing = [s for s in dict.fromkeys((c.base.suite, c.control.suite)) if s not in present]
        if missing:
            lines += [
                "**not enough data**: no scored run of "
                + ", ".join(f"suite `{s}`" for s in missing)
                + " in the CSV.",
                "",
            ]
            continue
        lines += [
            f"Arm: {c.arm} (key `{c.key}`). Base: `{c.base.row}` - `{c.base.ref}` in "
            f"`{c.base.suite}` ({c.base.condition}); control: `{c.control.row}` - "
            f"`{c.control.ref}` in `{c.control.suite}` ({c.control.condition}).",
            "",
        ]
        for column, what in (
            ("code", "code versions"),
            ("generator", "generator versions"),
            ("host", "hosts"),  # older runs recorded none: only recorded hosts are compared
        ):
            vb, vc = _provenance_of(c.base, rows, column), _provenance_of(c.control, rows, column)
            if column == "host":
                vb, vc = [h for h in vb if h != "?"], [h for h in vc if h != "?"]
            if vb and vc and vb != vc:  # one side without runs: nothing to compare yet
                lines += [
                    f"**Different {what}**: base {', '.join(vb)}, control "
                    f"{', '.join(vc)}; the change mixes the control with that difference.",
                    "",
                ]
        lines += [
            f"| metric | base Δ ({c.base.condition}) | control Δ ({c.control.condition}) "
            "| change | reading | after Holm |",
            "|:---|---:|---:|---:|:---|:---|",
        ]
        for r in evaluate_control(c, rows):
            col = cols[r.metric]
            name = col.label
            base, control, change = (
                interval_text(iv, col.fmt, "n = ") for iv in (r.base, r.control, r.change)
            )
            lines.append(
                f"| {name} | {base} | {control} | {change} | {r.reading} | {r.reading_holm} |"
            )
        lines.append("")
    return "\n".join(lines)
