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
    three causes the control tests (method, scale, benchmark; docs/results-notes.md)."""

    key: str
    title: str
    arm: str
    base: Effect
    control: Effect
    metrics: Tuple[str, ...] = ("ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr", "hdr_tae")


_VIDEO_INIT_SMALL = Effect(
    "control-video-init-priors", "no-video-init", "full", "realistic priors, small schedule"
)
CONTROLS: Tuple[Control, ...] = (
    Control(
        "video-init-split",
        "Ablation (a): is (a)'s lead the stage split? (full with the paper's 27 / 73 % split)",
        "method",
        Effect("control-video-init", "no-video-init", "full", "full with 3,000 + 2,500"),
        Effect(
            "control-video-init", "no-video-init", "full-paper-split", "full with 1,500 + 4,000"
        ),
    ),
    Control(
        "video-init-priors",
        "Ablation (a): is (a)'s lead the benchmark's priors? (oracle against realistic priors)",
        "benchmark",
        _VIDEO_INIT_SMALL,
        Effect(
            "control-video-init-priors",
            "no-video-init-oracle",
            "full-oracle",
            "oracle priors, small schedule",
        ),
    ),
    Control(
        "video-init-depth",
        "Ablation (a): is (a)'s lead the depth prior? (exact depth, tracks and flow realistic)",
        "benchmark",
        Effect("control-video-init-prior-parts", "no-video-init", "full", "realistic priors"),
        Effect(
            "control-video-init-prior-parts",
            "no-video-init-exact-depth",
            "full-exact-depth",
            "exact depth",
        ),
    ),
    Control(
        "video-init-motion",
        "Ablation (a): is (a)'s lead the track and flow priors? (exact tracks and flow, depth "
        "realistic)",
        "benchmark",
        Effect("control-video-init-prior-parts", "no-video-init", "full", "realistic priors"),
        Effect(
            "control-video-init-prior-parts",
            "no-video-init-exact-motion",
            "full-exact-motion",
            "exact tracks and flow",
        ),
    ),
    Control(
        "video-init-motion-masks",
        "Ablation (a): is (a)'s lead the track and flow priors, with the masks held to the "
        "paper's? (exact tracks and flow against realistic, epipolar masks in both)",
        "benchmark",
        Effect(
            "control-video-init-masks",
            "no-video-init-epipolar",
            "full-epipolar",
            "realistic priors, epipolar masks",
        ),
        Effect(
            "control-video-init-masks",
            "no-video-init-exact-motion-epipolar",
            "full-exact-motion-epipolar",
            "exact tracks and flow, epipolar masks",
        ),
    ),
    Control(
        "video-init-scale",
        "Ablation (a): is (a)'s lead the small schedule? (the paper's 4K + 11K against 15K)",
        "scale",
        _VIDEO_INIT_SMALL,
        Effect(
            "control-video-init-scale",
            "no-video-init-paper-schedule",
            "full-paper-schedule",
            "realistic priors, the paper's schedule",
        ),
    ),
    Control(
        "tlr-weight",
        "Ablation (e): is TLR's small effect on HDR-TAE its weight? (0.1, the paper's text, "
        "against 0.01)",
        "method",
        Effect("control-tlr", "no-tlr", "full", "TLR weight 0.01"),
        Effect("control-tlr", "no-tlr", "full-tlr-0.1", "TLR weight 0.1"),
    ),
    Control(
        "track-loss-priors",
        "Priors: is the track loss's missing cost the benchmark's priors? (oracle against "
        "realistic priors)",
        "benchmark",
        Effect("control-track-loss", "no-track-loss", "full", "realistic priors"),
        Effect("control-track-loss", "no-track-loss-oracle", "full-oracle", "oracle priors"),
    ),
    Control(
        "tlr-weight-priors",
        "TLR at the paper's weight: is its PSNR cost the benchmark's priors? (oracle against "
        "realistic priors)",
        "benchmark",
        Effect("control-tlr-priors", "full-tlr-0.1", "full", "realistic priors"),
        Effect("control-tlr-priors", "full-tlr-0.1-oracle", "full-oracle", "oracle priors"),
    ),
    Control(
        "tlr-weight-grad",
        "TLR at the paper's weight: is its PSNR cost the neighbour renders' stopped gradient? "
        "(with the gradient against without)",
        "method",
        Effect("control-tlr-grad", "full-tlr-0.1", "full", "neighbours without gradient"),
        Effect("control-tlr-grad", "full-tlr-0.1-grad", "full-grad", "neighbours with gradient"),
    ),
    Control(
        "tlr-weight-floor",
        "TLR at the paper's weight: is its PSNR cost the near-black pixels? (a floor of 1 % of the "
        "render's median in TLR's denominator against the paper's denominator)",
        "method",
        Effect("control-tlr-floor", "full-tlr-0.1", "full", "the paper's denominator"),
        Effect(
            "control-tlr-floor", "full-tlr-0.1-floor", "full-floor", "a floor in the denominator"
        ),
    ),
    # added 2026-11-29 before any run of control-tlr-weight (docs/results-notes.md): the floor
    # run at weight 0.1 against the weight alone at 0.03 and at 0.05, each against its own suite's
    # full; the one of the two whose HDR-TAE effect is nearer the floor run's is the reading
    *(
        Control(
            f"tlr-floor-vs-weight-{w}",
            f"TLR's denominator floor: a weaker TLR? (the floor at weight 0.1 against weight {w} "
            "with the paper's denominator)",
            "method",
            Effect(
                "control-tlr-weight",
                f"full-tlr-{w}",
                "full",
                f"weight {w}, the paper's denominator",
            ),
            Effect(
                "control-tlr-floor",
                "full-tlr-0.1-floor",
                "full",
                "weight 0.1, a floor in the denominator",
            ),
            ("ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr", "hdr_tae", "hdr_tce"),
        )
        for w in ("0.03", "0.05")
    ),
    Control(
        "schedule-coverage",
        "Schedules: is random values' HDR PSNR cost the few frames near the range's ends? "
        "(values within half a stop of a level against log-uniform values)",
        "benchmark",
        Effect("control-schedule-coverage", "random-values", "alternating", "log-uniform values"),
        Effect(
            "control-schedule-coverage",
            "random-values-banded",
            "alternating",
            "values within half a stop of a level",
        ),
    ),
    Control(
        "tlr-weight-scale",
        "TLR at the paper's weight: is its PSNR cost the small schedule? (the paper's 4K + 11K "
        "against 3K + 2.5K)",
        "scale",
        Effect("control-tlr", "full-tlr-0.1", "full", "small schedule"),
        Effect(
            "control-tlr-scale",
            "full-tlr-0.1-paper-schedule",
            "full-paper-schedule",
            "the paper's schedule",
        ),
    ),
    Control(
        "reproj-schedule",
        "Ablation (d): is the reprojection loss's small effect its schedule? (throughout stage 2, "
        "the paper's text, against its first 700 steps)",
        "method",
        Effect("control-reproj", "no-reproj", "full", "L_pr in stage 2's first 700 steps"),
        Effect("control-reproj", "no-reproj", "full-pr-whole", "L_pr throughout stage 2"),
    ),
    Control(
        "reproj-prior",
        "Ablation (d): is the reprojection loss's small effect the benchmark's priors? (oracle "
        "against realistic priors)",
        "benchmark",
        Effect("control-reproj-priors", "no-reproj", "full", "realistic priors"),
        Effect("control-reproj-priors", "no-reproj-oracle", "full-oracle", "oracle priors"),
    ),
    Control(
        "reproj-scale",
        "Ablation (d): is the reprojection loss's small effect the small schedule? (the paper's "
        "4K + 11K against 3K + 2.5K)",
        "scale",
        Effect("paper-ablation", "no-reproj", "full", "small schedule"),
        Effect(
            "control-scale",
            "no-reproj-paper-schedule",
            "full-paper-schedule",
            "the paper's schedule",
        ),
    ),
    Control(
        "depth-loss-prior",
        "Priors: is the gain without the depth loss the benchmark's depth prior? (exact depth, "
        "tracks and flow realistic)",
        "benchmark",
        Effect("control-depth-loss", "no-depth-loss", "full", "realistic depth prior"),
        Effect(
            "control-depth-loss",
            "no-depth-loss-exact-depth",
            "full-exact-depth",
            "exact depth prior",
        ),
    ),
    Control(
        "depth-loss-scale",
        "Priors: is the depth loss's missing cost the small schedule? (the paper's 4K + 11K "
        "against 3K + 2.5K)",
        "scale",
        Effect("priors", "no-depth-loss", "full", "small schedule"),
        Effect(
            "control-loss-scale",
            "no-depth-loss-paper-schedule",
            "full-paper-schedule",
            "the paper's schedule",
        ),
    ),
    Control(
        "track-loss-scale",
        "Priors: is the track loss's missing cost the small schedule? (the paper's 4K + 11K "
        "against 3K + 2.5K)",
        "scale",
        Effect("priors", "no-track-loss", "full", "small schedule"),
        Effect(
            "control-loss-scale",
            "no-track-loss-paper-schedule",
            "full-paper-schedule",
            "the paper's schedule",
        ),
    ),
    Control(
        "depth-loss-stage",
        "Priors: is the gain without the depth loss stage 2's term? (removed from stage 2 only, "
        "against both stages)",
        "method",
        Effect("control-depth-loss", "no-depth-loss", "full", "depth term removed in both stages"),
        Effect(
            "control-depth-loss",
            "no-depth-loss-stage2",
            "full",
            "depth term removed in stage 2 only",
        ),
    ),
    *(
        Control(
            f"track-loss-stage{sfx}",
            "Priors: is the track loss's missing cost stage 2's term? (removed from stage 2 only, "
            f"against both stages; {prior} priors)",
            "method",
            Effect(
                "control-track-loss",
                f"no-track-loss{sfx}",
                f"full{sfx}",
                f"track/flow term removed in both stages ({prior} priors)",
            ),
            Effect(
                "control-track-loss-stage",
                f"no-track-loss-stage2{sfx}",
                f"full{sfx}",
                f"track/flow term removed in stage 2 only ({prior} priors)",
            ),
        )
        for sfx, prior in (("", "realistic"), ("-oracle", "oracle"))
    ),
    *(
        Control(
            f"exposure-draw-{k}",
            "Exposure perturbation: is the small cost of ±0.75 EV one draw of the offsets? "
            f"(draw {k} against draw 0)",
            "benchmark",
            Effect("exposure-noise", "ev-0.75", "ev-0", "offsets of perturb_seed 0"),
            Effect(
                "exposure-noise-draw", f"ev-0.75-draw-{k}", "ev-0", f"offsets of perturb_seed {k}"
            ),
        )
        for k in (1, 2)
    ),
    Control(
        "exposure-scale",
        "Exposure perturbation: is the small cost of ±0.75 EV the small schedule? (the paper's "
        "4K + 11K against 3K + 2.5K)",
        "scale",
        Effect("exposure-noise", "ev-0.75", "ev-0", "small schedule"),
        Effect(
            "control-scale", "ev-0.75-paper-schedule", "full-paper-schedule", "the paper's schedule"
        ),
    ),
)

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
    order (the Controls' effects and `m4dgs-eval pairs`)."""
    mine = [r for r in rows if r["suite"] == suite and r.get("status") == SCORED]
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
