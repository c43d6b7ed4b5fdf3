"""The results page's figures: per-scene bars of the main metric, learned CRF curves against the
true ones, HDR-TAE vs LDR-OE PSNR per run and as paired differences, one figure per finding and
the controls' overview."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

from eval.figures import learned_crf_curve, pyplot, save_png, true_crf_curve
from eval.records.suite import LAYOUTS, metric_columns
from eval.records.suite_data import SuiteData
from eval.study.controls import CONTROLS, NO_CHANGE, Control, ControlResult, evaluate_control
from eval.study.findings import (
    AGREES,
    DISAGREES,
    FINDING_FIGURE_PREFIX,
    FINDINGS,
    NO_DATA,
    ComparisonResult,
    Finding,
)


# --------------------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------------------
def _colors(n: int) -> list:
    plt = pyplot()
    cmap = plt.get_cmap("tab10")
    return [cmap(i % 10) for i in range(n)]


def _main_metric(data: SuiteData) -> str:
    if data.suite is not None and data.suite.tables:
        cols = data.suite.tables[0].columns
        keys = LAYOUTS[cols] if isinstance(cols, str) else list(cols)
        for k in keys:
            if k in metric_columns():
                return k
    return "ldr_oe_psnr"


def bars_figure(data: SuiteData, out_png) -> Optional[Path]:
    """Per-scene bars of the suite's main metric (first column of its first table), one bar per row
    with a value = the mean over seeds, a dot per seed."""
    key = _main_metric(data)
    col = metric_columns()[key]
    vals = {}
    for e in data.table_entries:
        if not e["metrics"]:
            continue
        v = e["metrics"].get(key)
        if v is not None and math.isfinite(v):
            vals.setdefault((e["scene"], e["row"]), []).append(v)
    if not vals:
        return None
    plt = pyplot()
    scenes = data.scenes
    # a row without a value (e.g. a 2D row never made on these clips) takes no slot
    rows = [rn for rn in data.row_names if any((sc, rn) in vals for sc in scenes)]
    w = 0.8 / max(1, len(rows))
    fig, ax = plt.subplots(figsize=(max(5.0, 0.35 * len(scenes) * len(rows) + 1.5), 3.6))
    allv = [v for vs in vals.values() for v in vs]
    for j, (rn, c) in enumerate(zip(rows, _colors(len(rows)))):
        for i, sc in enumerate(scenes):
            vs = vals.get((sc, rn))
            if not vs:
                continue
            x = i - 0.4 + w * (j + 0.5)
            ax.bar(
                x,
                sum(vs) / len(vs),
                w * 0.9,
                color=c,
                label=data.labels[rn]
                if i == 0 or not any(vals.get((s2, rn)) for s2 in scenes[:i])
                else None,
            )
            ax.plot([x] * len(vs), vs, "k.", ms=3)
    lo, hi = min(allv), max(allv)
    pad = 0.1 * (hi - lo) if hi > lo else max(abs(hi) * 0.05, 1e-3)
    ax.set_ylim(lo - 2 * pad, hi + pad)
    ax.set_xticks(range(len(scenes)))
    ax.set_xticklabels(scenes, rotation=30, ha="right", fontsize=7)
    name = col.label
    ax.set_ylabel(f"{name} {'(higher better)' if col.higher_is_better else '(lower better)'}")
    ax.set_title(
        f"{data.name}: {name} per scene (bar: mean over seeds, dots: seeds; "
        "the axis does not start at 0)",
        fontsize=8,
    )
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save_png(fig, out_png)


def crf_figure(data: SuiteData, curves: Dict[tuple, dict], out_png) -> Optional[Path]:
    """Learned CRFs (mean of RGB; the lowest seed of each row and scene) against the true ones
    (dashed; black when every row shares one), one panel per scene."""

    panels = []
    for sc in data.scenes:
        lines = []
        for rn in data.row_names:
            for seed in data.seeds:
                c = curves.get((data.name, sc, rn, seed))
                if c is not None:
                    lines.append((rn, c))
                    break
        if lines:
            panels.append((sc, lines))
    if not panels:
        return None
    plt = pyplot()
    ncol = min(3, len(panels))
    nrow = math.ceil(len(panels) / ncol)
    fig, axes = plt.subplots(
        nrow,
        ncol,
        figsize=(3.3 * ncol + 2.4, 2.6 * nrow + 0.6),
        squeeze=False,
        layout="constrained",
    )
    color = dict(zip(data.row_names, _colors(len(data.row_names))))
    crfs = {c["crf"] for _, ls in panels for _, c in ls}
    handles = {}
    for ax, (sc, lines) in zip(axes.flat, panels):
        done = set()
        for rn, c in lines:
            z, y = learned_crf_curve(c)
            (h,) = ax.plot(z, y, lw=1.2, color=color[rn])
            handles.setdefault(data.labels[rn], h)
            if c["crf"] in done:
                continue
            done.add(c["crf"])
            tc = true_crf_curve(c["crf"], z.min(), z.max(), 201)
            if tc is None:
                continue
            zz, true = tc
            (h,) = ax.plot(zz, true, "--", lw=1.0, color="k" if len(crfs) == 1 else color[rn])
            handles.setdefault(f"true CRF ({c['crf']})", h)
        ax.set_title(sc, fontsize=8)
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(panels) :]:
        ax.set_visible(False)
    fig.supxlabel("log2 exposure", fontsize=8)
    fig.supylabel("LDR value (mean of RGB)", fontsize=8)
    fig.legend(
        list(handles.values()),
        list(handles),
        fontsize=6,
        loc="outside right center",
    )
    fig.suptitle(f"{data.name}: learned CRFs (solid) vs true (dashed)", fontsize=9)
    return save_png(fig, out_png)


def scatter_figure(data: SuiteData, out_png) -> Optional[Path]:
    """HDR-TAE against LDR-OE PSNR, one point per scored run, one colour per row."""
    pts = {}
    for e in data.table_entries:
        if not e["metrics"]:
            continue
        x, y = e["metrics"].get("ldr_oe_psnr"), e["metrics"].get("hdr_tae")
        if x is not None and y is not None and math.isfinite(x) and math.isfinite(y):
            pts.setdefault(e["row"], []).append((x, y))
    if not pts:
        return None
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.2, 3.6))
    for rn, c in zip(data.row_names, _colors(len(data.row_names))):
        if rn in pts:
            xs, ys = zip(*pts[rn])
            ax.scatter(xs, ys, s=14, color=c, label=data.labels[rn])
    ax.set_xlabel("LDR-OE PSNR (dB, higher better)")
    ax.set_ylabel("HDR-TAE (lower better)")
    ax.set_title(f"{data.name}: one point per run (scene, seed)", fontsize=8)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save_png(fig, out_png)


def paired_deltas(data: SuiteData, x_key="ldr_oe_psnr", y_key="hdr_tae") -> Dict[str, list]:
    """{row: [(scene, seed, x(row) - x(ref), y(row) - y(ref))]} over the pairs the tables use where
    the row and the suite's reference row both have finite x and y (the reference row left out)."""
    ref = data.suite.reference if data.suite is not None else None
    at = {
        (e["scene"], e["seed"], e["row"]): e["metrics"] for e in data.table_entries if e["metrics"]
    }
    out: Dict[str, list] = {}
    for (scene, seed, row), m in at.items():
        r = at.get((scene, seed, ref))
        if row == ref or r is None:
            continue
        vals = [m.get(x_key), m.get(y_key), r.get(x_key), r.get(y_key)]
        if all(v is not None and math.isfinite(v) for v in vals):
            out.setdefault(row, []).append((scene, seed, vals[0] - vals[2], vals[1] - vals[3]))
    return out


def delta_scatter_figure(data: SuiteData, out_png) -> Optional[Path]:
    """Per (scene, seed) pair, each row's HDR-TAE difference to the reference row against its LDR-OE
    PSNR difference: a row that trades temporal stability for PSNR lands top right."""
    pts = paired_deltas(data)
    if not pts:
        return None
    ref = data.suite.reference
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.2, 3.6))
    for rn, c in zip(data.row_names, _colors(len(data.row_names))):
        if rn in pts:
            ax.scatter(
                [p[2] for p in pts[rn]],
                [p[3] for p in pts[rn]],
                s=14,
                color=c,
                label=data.labels[rn],
            )
    ax.axhline(0.0, color="0.4", lw=0.8)
    ax.axvline(0.0, color="0.4", lw=0.8)
    ax.set_xlabel(f"Δ LDR-OE PSNR vs {ref} (dB; right: row better)")
    ax.set_ylabel(f"Δ HDR-TAE vs {ref} (up: row worse)")
    ax.set_title(f"{data.name}: one point per (scene, seed) pair and row", fontsize=8)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return save_png(fig, out_png)


# the figures of a suite, <suite>_<kind>.png, in the page's order
FIGURE_KINDS = ("bars", "crf", "tae_psnr", "delta_tae_psnr")


def suite_result_figures(data: SuiteData, curves: Dict[tuple, dict], fig_dir) -> List[Path]:
    fig_dir = Path(fig_dir)
    make = {
        "bars": lambda p: bars_figure(data, p),
        "crf": lambda p: crf_figure(data, curves, p),
        "tae_psnr": lambda p: scatter_figure(data, p),
        "delta_tae_psnr": lambda p: delta_scatter_figure(data, p),
    }
    out = [make[k](fig_dir / f"{data.name}_{k}.png") for k in FIGURE_KINDS]
    return [p for p in out if p is not None]


@dataclass(frozen=True)
class FindingPoint:
    """One comparison of a finding as its figure draws it: our Δ's mean and 95 % interval, the
    paper's Δ (None where it has none), and whether the verdict survives Holm's correction."""

    label: str  # "row - ref"
    metric: str
    mean: float
    low: Optional[float]
    high: Optional[float]
    paper: Optional[float]
    holm_significant: bool


def finding_points(res: List[ComparisonResult]) -> List[FindingPoint]:
    """What `finding_figure` draws for one finding's results (comparisons without our mean left
    out)."""
    out = []
    for r in res:
        iv = r.ours
        if iv is None or iv.mean is None:
            continue
        out.append(
            FindingPoint(
                f"{r.comparison.row} - {r.comparison.ref}",
                r.metric,
                iv.mean,
                iv.low,
                iv.high,
                r.paper_diff,
                r.verdict_holm in (AGREES, DISAGREES),
            )
        )
    return out


def finding_figure(f: Finding, res: List[ComparisonResult], out_png) -> Optional[Path]:
    """Forest plot of one finding: a panel per metric, a line per comparison with our paired Δ and
    its 95 % interval (filled where the verdict survives Holm's correction, open where it does
    not), the paper's Δ as a red cross, and 0 as a vertical line. None without any of our Δ."""
    from matplotlib.ticker import MaxNLocator

    pts = finding_points(res)
    if not pts:
        return None
    cols = metric_columns()
    labels = list(dict.fromkeys(f"{c.row} - {c.ref}" for c in f.comparisons))
    plt = pyplot()
    fig, axes = plt.subplots(
        1, len(f.metrics), figsize=(2.3 * len(f.metrics) + 1.6, 0.42 * len(labels) + 1.2)
    )
    axes = list(axes) if len(f.metrics) > 1 else [axes]
    for k, (ax, m) in enumerate(zip(axes, f.metrics)):
        col = cols[m]
        for p in (p for p in pts if p.metric == m):
            y = labels.index(p.label)
            if p.low is not None:
                ax.plot([p.low, p.high], [y, y], color="0.25", lw=1.2)
            ax.plot(
                [p.mean],
                [y],
                "o",
                ms=5,
                color="0.15",
                markerfacecolor="0.15" if p.holm_significant else "white",
            )
            if p.paper is not None:
                ax.plot([p.paper], [y], "x", ms=6, mew=1.6, color="tab:red")
        ax.axvline(0.0, color="0.5", lw=0.8, ls="--")
        ax.set_yticks(range(len(labels)))
        ax.set_yticklabels(labels if k == 0 else [], fontsize=7)
        ax.set_ylim(len(labels) - 0.5, -0.5)
        arrow = "right: better" if col.higher_is_better else "left: better"
        name = col.label
        ax.set_xlabel(f"Δ {name} ({arrow})", fontsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(nbins=4))
        ax.tick_params(axis="x", labelsize=7)
        ax.grid(axis="x", alpha=0.3)
    n = max((r.ours.n for r in res if r.ours is not None), default=0)
    fig.suptitle(
        f"{f.suite}: ours (mean, 95 % interval, at most {n} pairs; filled = survives Holm) "
        "and the paper (x)",
        fontsize=8,
    )
    return save_png(fig, out_png)


CONTROLS_FIGURE_METRICS = ("ldr_oe_psnr", "hdr_tae")


def controls_figure_data(rows: List[dict]) -> List[Tuple[Control, Dict[str, ControlResult]]]:
    """What `controls_figure` draws: (control, {metric: ControlResult}) over CONTROLS_FIGURE_METRICS
    for the controls with both effects in some metric; Holm's correction over all the control's
    metrics, as its table has it."""
    out = []
    for c in CONTROLS:
        res = {r.metric: r for r in evaluate_control(c, rows)}
        res = {
            m: res.get(m, ControlResult(m, None, None, None, NO_DATA))
            for m in CONTROLS_FIGURE_METRICS
        }
        if any(r.base is not None and r.control is not None for r in res.values()):
            out.append((c, res))
    return out


def controls_figure(rows: List[dict], out_png) -> Optional[Path]:
    """Forest plot of the controls whose two effects have data (`controls_figure_data`): a panel
    per metric of CONTROLS_FIGURE_METRICS, per control its base effect (grey) and the effect under
    the control (blue), each mean and 95 % interval, an arrow from one mean to the other, the blue
    marker filled where the change survives Holm's correction. None when no control has both
    effects."""
    from matplotlib.ticker import MaxNLocator

    results = controls_figure_data(rows)
    if not results:
        return None
    cols = metric_columns()
    plt = pyplot()
    fig, axes = plt.subplots(
        1,
        len(CONTROLS_FIGURE_METRICS),
        figsize=(9.0, 0.5 * len(results) + 1.3),
        squeeze=False,
        layout="constrained",
    )
    for k, (ax, m) in enumerate(zip(axes[0], CONTROLS_FIGURE_METRICS)):
        col = cols[m]
        for y, (_, res) in enumerate(results):
            r = res[m]
            for iv, dy, color in ((r.base, -0.15, "0.55"), (r.control, 0.15, "tab:blue")):
                if iv is None or iv.mean is None:
                    continue
                if iv.low is not None:
                    ax.plot([iv.low, iv.high], [y + dy] * 2, color=color, lw=1.2)
                filled = iv is r.base or r.reading_holm not in (NO_CHANGE, NO_DATA)
                ax.plot(
                    [iv.mean], [y + dy], "o", ms=5, color=color,
                    markerfacecolor=color if filled else "white",
                )  # fmt: skip
            if r.base is not None and r.control is not None and r.base.mean is not None:
                ax.annotate(
                    "",
                    xy=(r.control.mean, y + 0.15),
                    xytext=(r.base.mean, y - 0.15),
                    arrowprops={"arrowstyle": "->", "color": "0.3", "lw": 0.8},
                )
        ax.axvline(0.0, color="0.5", lw=0.8, ls="--")
        ax.set_yticks(range(len(results)))
        ax.set_yticklabels([f"{c.key} ({c.arm})" for c, _ in results] if k == 0 else [], fontsize=7)
        ax.set_ylim(len(results) - 0.5, -0.5)
        name = col.label
        ax.set_xlabel(f"Δ {name} (row - ref)", fontsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(nbins=4))
        ax.tick_params(axis="x", labelsize=7)
        ax.grid(axis="x", alpha=0.3)
    fig.suptitle(
        "Controls: the effect as found (grey) and under the control (blue); mean, 95 % interval",
        fontsize=8,
    )
    return save_png(fig, out_png)


def finding_figures(evaluated: Dict[str, List[ComparisonResult]], fig_dir) -> Dict[str, Path]:
    """{finding key: PNG} for every finding of `evaluated` (evaluate_findings: those whose suite
    has scored runs), named finding_<key>.png in fig_dir."""
    out = {}
    for f in FINDINGS:
        if f.key in evaluated:
            p = finding_figure(
                f, evaluated[f.key], Path(fig_dir) / f"{FINDING_FIGURE_PREFIX}{f.key}.png"
            )
            if p is not None:
                out[f.key] = p
    return out
