"""Paper-style result tables (pure formatting; no I/O, no metric computation).

Input: rows = list of dicts {"method": str, "scene": str, <metric key>: float | None, ...} and a
TableSpec (columns: metric key, header, higher_is_better, format, optional group such as "LDR-OE" /
"HDR"). Output: the per-method mean over scenes, the best value per column in bold (ties at the
displayed precision all bold; None / NaN shown as "n/a" and never best), rendered as Markdown
(default), LaTeX (booktabs, \\textbf) or CSV (no bold), with a footnote block listing the metric
conventions (eval.metrics.CONVENTIONS keys or literal strings).

Mean over scenes: a method missing a value (None / NaN / absent) for any scene gets "n/a" for that
column, unless the spec sets `partial_means=True` (then the mean is over the scenes that have the
value, and the footnote says so).

Rows may carry a "seed" (trainer seed, default 0): a method's values are then its (scene, seed)
runs. Optional statistics (eval.stats), each switched on in the TableSpec:

- `intervals`: cells read "mean ± h", h the half-width of the Student-t 95 % interval of the mean
  over the method's n runs (n/a for n < 2), and an "n" column counts the runs;
- `reference`: a method; every metric gets a "Δ" column with the paired difference row - reference
  over the (scene, seed) runs both have, mean ± its t-interval, marked † when the interval excludes
  0 ("ref" in its own row);
- `paper`: {method: {metric key: value}} typed from the paper; every metric gets a "Paper" column
  and a "paper / ours / agree" column: the sign of (row - reference) in the paper, ours ("n.s." when
  our interval includes 0), and agree / disagree / not significant (eval.stats.agreement).

The best value stays bold, judged on the means.

A column with `log2=True` shows a ratio metric in stops: every run's value becomes log2(value)
before the mean, the interval and the paired difference, so the mean is the log of the geometric
mean and a difference is the log of a ratio (an arithmetic mean of ratios lets one runaway run set
it: 0.5 and 2 average to 1.25, in stops to 0).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field

from eval.stats import agreement, by_key, mean_ci, paired_diff

NA = "n/a"


@dataclass
class Column:
    """One table column: `key` in the rows, `header` text, direction, python format spec, optional
    group/convention."""

    key: str
    header: str
    higher_is_better: bool = True
    fmt: str = ".2f"
    group: str | None = None
    convention: str | None = None  # a CONVENTIONS key or a literal sentence
    # a ratio whose right value is `target` (e.g. 1): the best is the value closest to it, and the
    # header's arrow reads "→1" (higher_is_better is then only the figures' reading direction)
    target: float | None = None
    # a property of the clip, not a score (e.g. the camera's motion): no arrow, never bold
    context: bool = False
    # a positive ratio shown in stops: each run's value becomes log2(value) before any statistic
    # (the module docstring); `target` is then in stops too (0: right)
    log2: bool = False

    @property
    def label(self) -> str:
        """The column's name in one line: "group header" (the header alone without a group)."""
        return ((self.group + " ") if self.group else "") + self.header

    @classmethod
    def from_dict(cls, d: dict) -> "Column":
        return cls(**d)


@dataclass
class TableSpec:
    """A table: its columns, optional title, extra convention notes, method order and scene
    filter."""

    columns: list
    title: str | None = None
    conventions: list = field(default_factory=list)  # extra CONVENTIONS keys / literal sentences
    methods: list | None = None  # row order (default: order of first appearance)
    scenes: list | None = None  # restrict to these scenes (default: all scenes in the rows)
    partial_means: bool = False
    method_header: str = "Method"
    intervals: bool = False  # "mean ± CI half-width" cells and an "n" column (eval.stats.mean_ci)
    reference: str | None = None  # method of the paired differences: a "Δ" column per metric
    paper: dict | None = (
        None  # {method: {key: value}} from the paper: "Paper" and agreement columns per metric
    )
    paper_source: str | None = None  # the paper table those values come from (footnote)
    level: float = 0.95  # confidence level of the intervals
    # methods whose runs are one prediction repeated for every trainer seed (the calibration rows
    # copy-nearest and flow-merge): their n and interval count each scene once (a copy is not a
    # second sample); their paired differences still pair them with every seed's reference run
    seed_free: frozenset = frozenset()
    # methods that are 2D calibration rows (eval.calibration): a footnote says what they are
    calibration: frozenset = frozenset()

    @classmethod
    def from_dict(cls, d: dict) -> "TableSpec":
        d = dict(d)
        d["columns"] = [c if isinstance(c, Column) else Column.from_dict(c) for c in d["columns"]]
        return cls(**d)


def _missing(v) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def _own_runs(mrows: list, method: str, spec: TableSpec) -> list:
    """The runs of a method that count as samples of its own mean: all of them, or for a
    seed-free method (spec.seed_free) the lowest seed's run of each scene."""
    if method not in spec.seed_free:
        return mrows
    first = {}
    for r in sorted(mrows, key=lambda r: r.get("seed") or 0):
        first.setdefault(r.get("scene"), r)
    return list(first.values())


def in_stops(v):
    """log2 of a positive value (a ratio in stops); None for a missing or non-positive one (no
    ratio to show). What a `log2` column shows and differences (also `m4dgs-eval pairs`)."""
    if _missing(v) or v <= 0:
        return None
    return math.log2(v)


def _shown(rows: list, spec: TableSpec) -> list:
    """The rows with every `log2` column's values in stops (copies; the others as given)."""
    logs = [c.key for c in spec.columns if c.log2]
    if not logs:
        return rows
    return [{**r, **{k: in_stops(r[k]) for k in logs if k in r}} for r in rows]


def aggregate(rows: list, spec: TableSpec) -> list:
    """Per-method mean over scenes -> list of {"method", "n_scenes", <key>: float | None} in the
    table's row order (a `log2` column's mean in stops)."""
    rows = _shown([r for r in rows if spec.scenes is None or r.get("scene") in spec.scenes], spec)
    order = list(spec.methods) if spec.methods is not None else []
    for r in rows:
        if r["method"] not in order and spec.methods is None:
            order.append(r["method"])
    out = []
    for m in order:
        mrows = _own_runs([r for r in rows if r["method"] == m], m, spec)
        agg = {
            "method": m,
            "n_scenes": len({r.get("scene") for r in mrows}),
            "n_runs": sum(any(not _missing(r.get(c.key)) for c in spec.columns) for r in mrows),
        }
        for c in spec.columns:
            vals = [r.get(c.key) for r in mrows]
            present = [float(v) for v in vals if not _missing(v)]
            if not present or (len(present) < len(vals) and not spec.partial_means):
                agg[c.key] = None
            else:
                agg[c.key] = sum(present) / len(present)
        out.append(agg)
    return out


@dataclass
class CellStats:
    """Statistics of one (method, metric) cell: the interval of the mean (None where the mean is
    n/a), the paired difference to the reference (None: no reference or n/a), the paper's value and
    the agreement triple."""

    ci: object = None  # eval.stats.Interval
    diff: object = None  # eval.stats.Interval
    is_reference: bool = False
    paper: float | None = None
    agree: tuple | None = None  # (paper's direction, ours, verdict)


def _has_reference(agg: list, spec: TableSpec) -> bool:
    return spec.reference is not None and any(r["method"] == spec.reference for r in agg)


def cell_stats(rows: list, spec: TableSpec, agg: list | None = None) -> list:
    """[row][col] CellStats in the order of aggregate(rows, spec)."""
    agg = aggregate(rows, spec) if agg is None else agg
    rows = _shown([r for r in rows if spec.scenes is None or r.get("scene") in spec.scenes], spec)
    has_ref = _has_reference(agg, spec)
    ref_rows = [r for r in rows if r["method"] == spec.reference] if has_ref else []
    ref_agg = next((a for a in agg if a["method"] == spec.reference), None) if has_ref else None
    paper = spec.paper or {}
    out = []
    for a in agg:
        m = a["method"]
        mrows = [r for r in rows if r["method"] == m]
        own = _own_runs(mrows, m, spec)
        line = []
        for c in spec.columns:
            st = CellStats(is_reference=has_ref and m == spec.reference)
            if a[c.key] is not None:
                st.ci = mean_ci([r.get(c.key) for r in own], spec.level)
                if has_ref and m != spec.reference and ref_agg[c.key] is not None:
                    st.diff = paired_diff(by_key(mrows, c.key), by_key(ref_rows, c.key), spec.level)
            st.paper = paper.get(m, {}).get(c.key)
            if spec.paper is not None and has_ref and m != spec.reference:
                pr = paper.get(spec.reference, {}).get(c.key)
                st.agree = agreement(
                    None if st.paper is None or pr is None else st.paper - pr, st.diff
                )
            line.append(st)
        out.append(line)
    return out


def _subcolumns(agg: list, spec: TableSpec) -> list:
    """Sub-columns of every metric: "value", then "diff" (with a reference row), "paper" and "agree"
    (with paper values)."""
    sub = ["value"]
    if _has_reference(agg, spec):
        sub.append("diff")
    if spec.paper is not None:
        sub += ["paper", "agree"]
    return sub


_SYMBOLS = {"markdown": (" ± ", "†"), "latex": (" $\\pm$ ", "$^\\dagger$")}


def _paper_fmt(v, fmt: str) -> str:
    """A paper value at the column precision, but at most 3 decimals (the paper prints 2 or 3)."""
    if _missing(v):
        return NA
    if fmt.endswith("f") and fmt[:-1].lstrip(".").isdigit():
        fmt = f".{min(int(fmt[:-1].lstrip('.')), 3)}f"
    return format(v, fmt)


def _sub_cell(
    kind: str, st: CellStats, c: "Column", value_text: str, style: str, intervals: bool
) -> str:
    """Text of one sub-column cell; value_text is the (possibly bold) formatted mean."""
    pm, dagger = _SYMBOLS[style]
    if kind == "value":
        if not intervals or st.ci is None:
            return value_text
        return value_text + pm + (NA if st.ci.half is None else format(st.ci.half, c.fmt))
    if kind == "diff":
        if st.is_reference:
            return "ref"
        d = st.diff
        if d is None or d.mean is None:
            return NA
        text = format(d.mean, "+" + c.fmt) + pm + (NA if d.half is None else format(d.half, c.fmt))
        return text + (dagger if d.excludes_zero else "")
    if kind == "paper":
        return _paper_fmt(st.paper, c.fmt)
    if st.is_reference:
        return "ref"
    return NA if st.agree is None else " / ".join(st.agree)


def _sub_header(kind: str, c: "Column", latex: bool) -> str:
    name = (f"{c.group} " if c.group else "") + c.header
    if kind == "value":
        return (latex_escape(c.header) if latex else name) + _arrow(c, latex)
    if latex:
        return {"diff": "$\\Delta$", "paper": "Paper", "agree": "paper / ours / agree"}[kind]
    return {
        "diff": f"Δ {name}",
        "paper": f"Paper {name}",
        "agree": f"{name}: paper / ours / agree",
    }[kind]


def _fmt(v, fmt: str) -> str:
    if _missing(v):
        return NA
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return format(v, fmt)


def best_flags(agg: list, spec: TableSpec) -> list:
    """[row][col] True where the value is the column's best at the displayed precision (ties all
    True)."""
    flags = [[False] * len(spec.columns) for _ in agg]
    for j, c in enumerate(spec.columns):
        if c.context:
            continue
        shown = [
            (i, float(_fmt(r[c.key], c.fmt))) for i, r in enumerate(agg) if not _missing(r[c.key])
        ]
        if not shown:
            continue
        if c.target is not None:
            shown = [(i, abs(v - c.target)) for i, v in shown]
            best = min(v for _, v in shown)
        else:
            best = max(v for _, v in shown) if c.higher_is_better else min(v for _, v in shown)
        for i, v in shown:
            if v == best:
                flags[i][j] = True
    return flags


def _names(spec: TableSpec, methods: frozenset) -> str:
    """The given methods' names, comma-separated, in the table's row order."""
    order = list(spec.methods or []) + sorted(methods)
    return ", ".join(m for m in dict.fromkeys(order) if m in methods)


def footnotes(spec: TableSpec, conventions: dict | None = None, agg: list | None = None) -> list:
    """Convention sentences for the table: each column's, then the spec's extras, de-duplicated, in
    order, then the statistics notes (intervals, paired differences, paper values; `agg` tells
    whether the reference row is there)."""
    if conventions is None:
        # deferred: eval.metrics imports torch (~1.5 s); tables alone are torch-free
        from eval.metrics import CONVENTIONS as conventions  # noqa: N811
    notes = []
    for key in [c.convention for c in spec.columns if c.convention] + list(spec.conventions):
        text = conventions.get(key, key)
        if text not in notes:
            notes.append(text)
    if spec.partial_means:
        notes.append("Means over the scenes that have a value (partial means).")
    else:
        notes.append("Means over scenes; n/a where a method lacks the value for a scene.")
    pct = f"{100 * spec.level:g} %"
    seed_note = (
        "one prediction for every trainer seed, so their n and interval count each scene once; "
        "their Δ pairs them with every seed's run."
    )
    if spec.intervals:
        notes.append(
            f"mean ± h: h is the half-width of the Student-t {pct} confidence interval of the "
            "mean over the "
            "n runs of a row (scenes x trainer seeds, treated as independent samples; t quantile "
            "with n - 1 "
            "degrees of freedom); n/a for n < 2."
        )
    if spec.calibration:
        notes.append(
            f"{_names(spec, spec.calibration)}: 2D calibration rows, predictions that reconstruct "
            'nothing, scored like the trained rows (docs/eval.md, "Calibration rows"): a trained '
            "row's lead over them is what its reconstruction adds; they appear in the tables where "
            "they have values"
            + (f"; {seed_note}" if spec.intervals and spec.seed_free == spec.calibration else ".")
        )
    if spec.intervals and spec.seed_free and spec.seed_free != spec.calibration:
        notes.append(f"{_names(spec, spec.seed_free)}: {seed_note}")
    ref = (
        spec.reference
        if (spec.reference is not None and (agg is None or _has_reference(agg, spec)))
        else None
    )
    if ref is not None:
        notes.append(
            f"Δ: paired difference row - {ref} over the (scene, seed) runs both rows have, mean ± "
            f"the Student-t {pct} interval of the mean difference; † where that interval excludes "
            "0 (per difference, not corrected for the table's many differences: without any effect "
            "about one in twenty would get a † by chance; `m4dgs-eval results` gives each finding "
            "of the paper's verdicts after Holm's correction)."
        )
    if spec.paper is not None:
        src = f" ({spec.paper_source})" if spec.paper_source else ""
        notes.append(
            f"Paper: the paper's value{src}, n/a where the paper has none. paper / ours / agree: "
            "the sign of "
            f"(row - {ref or 'reference'}) in the paper and in our mean difference (n.s. where "
            "our interval "
            "includes 0), then agree, disagree, not significant, or paper tie (the paper's two "
            "values are "
            "equal as printed)."
        )
    return notes


def _arrow(c: Column, latex: bool) -> str:
    if c.context:
        return ""
    if c.target is not None:
        return f"$\\to {c.target:g}$" if latex else f"→{c.target:g}"
    if latex:
        return "$\\uparrow$" if c.higher_is_better else "$\\downarrow$"
    return "↑" if c.higher_is_better else "↓"


def render_markdown(
    rows: list, spec: TableSpec, *, conventions: dict | None = None, notes: bool = True
) -> str:
    """GitHub Markdown table; bold as **x**; group names prefixed to headers ("HDR PSNR↑")."""
    agg = aggregate(rows, spec)
    flags = best_flags(agg, spec)
    stats = cell_stats(rows, spec, agg)
    sub = _subcolumns(agg, spec)
    heads = (
        [spec.method_header]
        + (["n"] if spec.intervals else [])
        + [_sub_header(k, c, False) for c in spec.columns for k in sub]
    )
    lines = []
    if spec.title:
        lines += [f"**{spec.title}**", ""]
    lines.append("| " + " | ".join(heads) + " |")
    lines.append("|" + "|".join([":---"] + ["---:"] * (len(heads) - 1)) + "|")
    for r, fl, st in zip(agg, flags, stats):
        cells = [str(r["method"])] + ([str(r["n_runs"])] if spec.intervals else [])
        for c, f, cs in zip(spec.columns, fl, st):
            s = _fmt(r[c.key], c.fmt)
            s = f"**{s}**" if f else s
            cells += [_sub_cell(k, cs, c, s, "markdown", spec.intervals) for k in sub]
        lines.append("| " + " | ".join(cells) + " |")
    if notes:
        lines.append("")
        lines += [f"- {n}" for n in footnotes(spec, conventions, agg)]
    return "\n".join(lines) + "\n"


_LATEX_ESC = {
    "&": "\\&",
    "%": "\\%",
    "$": "\\$",
    "#": "\\#",
    "_": "\\_",
    "{": "\\{",
    "}": "\\}",
    "~": "\\textasciitilde{}",
    "^": "\\textasciicircum{}",
    "\\": "\\textbackslash{}",
    "±": "$\\pm$",
    "Δ": "$\\Delta$",
    "†": "$^\\dagger$",
}


def latex_escape(s: str) -> str:
    return "".join(_LATEX_ESC.get(ch, ch) for ch in str(s))


def _groups(spec: TableSpec) -> list:
    """Consecutive runs of the same group: [(group or None, start col, count)]."""
    runs = []
    for j, c in enumerate(spec.columns):
        if runs and runs[-1][0] == c.group:
            runs[-1] = (c.group, runs[-1][1], runs[-1][2] + 1)
        else:
            runs.append((c.group, j, 1))
    return runs


def render_latex(
    rows: list, spec: TableSpec, *, conventions: dict | None = None, notes: bool = True
) -> str:
    """booktabs tabular (l + one r per column), a \\multicolumn group row when groups are set,
    \\textbf for the best."""
    agg = aggregate(rows, spec)
    flags = best_flags(agg, spec)
    stats = cell_stats(rows, spec, agg)
    sub = _subcolumns(agg, spec)
    k = len(sub)
    lead = ["n"] if spec.intervals else []  # columns between the method and the metrics
    n = len(spec.columns) * k + len(lead)
    lines = []
    if spec.title:
        lines.append(f"% {spec.title}")
    lines.append("\\begin{tabular}{l" + "r" * n + "}")
    lines.append("\\toprule")
    first = 2 + len(lead)  # table column number of the first metric cell
    if k > 1:  # one multicolumn per metric over its sub-columns, then the sub-column names
        cells = [""] + [""] * len(lead)
        rules = []
        for j, c in enumerate(spec.columns):
            title = latex_escape((f"{c.group} " if c.group else "") + c.header) + _arrow(c, True)
            cells.append(f"\\multicolumn{{{k}}}{{c}}{{{title}}}")
            rules.append(f"\\cmidrule(lr){{{first + j * k}-{first + j * k + k - 1}}}")
        lines.append(" & ".join(cells) + " \\\\")
        lines.append(" ".join(rules))
        heads = (
            [latex_escape(spec.method_header)]
            + lead
            + [
                "ours" if s_ == "value" else _sub_header(s_, c, True)
                for c in spec.columns
                for s_ in sub
            ]
        )
    else:
        runs = _groups(spec)
        if any(g for g, _, _ in runs):
            cells, rules = [""] + [""] * len(lead), []
            for g, start, cnt in runs:
                cells.append(
                    f"\\multicolumn{{{cnt}}}{{c}}{{{latex_escape(g)}}}"
                    if g
                    else " & ".join([""] * cnt)
                )
                if g:
                    rules.append(f"\\cmidrule(lr){{{start + first}-{start + cnt + first - 1}}}")
            lines.append(" & ".join(cells) + " \\\\")
            if rules:
                lines.append(" ".join(rules))
        heads = (
            [latex_escape(spec.method_header)]
            + lead
            + [latex_escape(c.header) + _arrow(c, True) for c in spec.columns]
        )
    lines.append(" & ".join(heads) + " \\\\")
    lines.append("\\midrule")
    for r, fl, st in zip(agg, flags, stats):
        cells = [latex_escape(r["method"])] + ([str(r["n_runs"])] if spec.intervals else [])
        for c, f, cs in zip(spec.columns, fl, st):
            s = _fmt(r[c.key], c.fmt)
            s = f"\\textbf{{{s}}}" if f else s
            cells += [_sub_cell(s_, cs, c, s, "latex", spec.intervals) for s_ in sub]
        lines.append(" & ".join(cells) + " \\\\")
    lines.append("\\bottomrule")
    lines.append("\\end{tabular}")
    if notes:
        lines.append("\\par\\footnotesize")
        lines += [latex_escape(nt) + " \\\\" for nt in footnotes(spec, conventions, agg)]
    return "\n".join(lines) + "\n"


def render_csv(
    rows: list, spec: TableSpec, *, conventions: dict | None = None, notes: bool = False
) -> str:
    """CSV: header row (method, n_scenes, then "<group> <header>"), one row per method, values at
    the column precision, "n/a" for missing, no bold. `notes=True` appends the footnotes as '# '
    comment lines.

    With the spec's statistics: an "n_runs" column, and after each metric "<name> ci95"
    (half-width), "Δ <name>", "Δ <name> ci95", "Δ <name> excludes 0" (yes / no), "Paper <name>" and
    "<name> paper/ours/agree" (one field, ' / '-separated), each only when switched on."""
    agg = aggregate(rows, spec)
    stats = cell_stats(rows, spec, agg)
    sub = _subcolumns(agg, spec)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    head = [spec.method_header, "n_scenes"] + (["n_runs"] if spec.intervals else [])
    for c in spec.columns:
        name = c.label
        head.append(name)
        head += [f"{name} ci95"] if spec.intervals else []
        head += [f"Δ {name}", f"Δ {name} ci95", f"Δ {name} excludes 0"] if "diff" in sub else []
        head += [f"Paper {name}", f"{name} paper/ours/agree"] if "paper" in sub else []
    w.writerow(head)

    def num(v, fmt):
        return NA if v is None else _fmt(v, fmt)

    for r, st in zip(agg, stats):
        line = [r["method"], r["n_scenes"]] + ([r["n_runs"]] if spec.intervals else [])
        for c, cs in zip(spec.columns, st):
            line.append(_fmt(r[c.key], c.fmt))
            if spec.intervals:
                line.append(num(None if cs.ci is None else cs.ci.half, c.fmt))
            if "diff" in sub:
                d = cs.diff
                if cs.is_reference:
                    line += ["ref", "", ""]
                elif d is None or d.mean is None:
                    line += [NA, NA, NA]
                else:
                    line += [
                        format(d.mean, "+" + c.fmt),
                        num(d.half, c.fmt),
                        NA if d.excludes_zero is None else ("yes" if d.excludes_zero else "no"),
                    ]
            if "paper" in sub:
                line += [
                    _paper_fmt(cs.paper, c.fmt),
                    _sub_cell("agree", cs, c, "", "markdown", False),
                ]
        w.writerow(line)
    text = buf.getvalue()
    if notes:
        text += "".join(f"# {nt}\n" for nt in footnotes(spec, conventions, agg))
    return text


def render(rows: list, spec: TableSpec, fmt: str = "markdown", **kw) -> str:
    """Dispatch on fmt in {"markdown", "latex", "csv"}."""
    fns = {
        "markdown": render_markdown,
        "md": render_markdown,
        "latex": render_latex,
        "tex": render_latex,
        "csv": render_csv,
    }
    if fmt not in fns:
        raise ValueError(f"table format must be one of markdown/latex/csv, got {fmt!r}")
    return fns[fmt](rows, spec, **kw)


def paper_table_spec(
    title: str | None = None,
    *,
    ldr_convention: str = "ldr_float",
    lpips_available: bool = True,
    lpips_normalized: bool = True,
) -> TableSpec:
    """The layout of the paper's main synthetic table (LDR-OE, LDR-NE, HDR: PSNR/SSIM/LPIPS;
    HDR-TAE)."""
    lp_conv = (
        ("lpips" if lpips_normalized else "lpips_unnormalized") if lpips_available else "lpips_na"
    )
    cols = []
    for grp, pre in (("LDR-OE", "ldr_oe"), ("LDR-NE", "ldr_ne"), ("HDR", "hdr")):
        cols += [
            Column(
                f"{pre}_psnr", "PSNR", True, ".2f", grp, "hdr_mu_law" if pre == "hdr" else "psnr"
            ),
            Column(f"{pre}_ssim", "SSIM", True, ".4f", grp, "ssim"),
            Column(f"{pre}_lpips", "LPIPS", False, ".4f", grp, lp_conv),
        ]
    cols.append(Column("hdr_tae", "HDR-TAE", False, ".4f", None, "hdr_tae"))
    return TableSpec(columns=cols, title=title, conventions=[ldr_convention])
