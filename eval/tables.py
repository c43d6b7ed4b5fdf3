"""Paper-style result tables (pure formatting; no I/O, no metric computation).

Input: rows = list of dicts {"method": str, "scene": str, <metric key>: float | None, ...} and a TableSpec (columns:
metric key, header, higher_is_better, format, optional group such as "LDR-OE" / "HDR"). Output: the per-method mean
over scenes, the best value per column in bold (ties at the displayed precision all bold; None / NaN shown as "n/a"
and never best), rendered as Markdown (default), LaTeX (booktabs, \\textbf) or CSV (no bold), with a footnote block
listing the metric conventions (eval.metrics.CONVENTIONS keys or literal strings).

Mean over scenes: a method missing a value (None / NaN / absent) for any scene gets "n/a" for that column, unless
the spec sets `partial_means=True` (then the mean is over the scenes that have the value, and the footnote says so).
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field

NA = "n/a"


@dataclass
class Column:
    """One table column: `key` in the rows, `header` text, direction, python format spec, optional group/convention."""

    key: str
    header: str
    higher_is_better: bool = True
    fmt: str = ".2f"
    group: str | None = None
    convention: str | None = None  # a CONVENTIONS key or a literal sentence

    @classmethod
    def from_dict(cls, d: dict) -> "Column":
        return cls(**d)


@dataclass
class TableSpec:
    """A table: its columns, optional title, extra convention notes, method order and scene filter."""

    columns: list
    title: str | None = None
    conventions: list = field(default_factory=list)  # extra CONVENTIONS keys / literal sentences
    methods: list | None = None  # row order (default: order of first appearance)
    scenes: list | None = None  # restrict to these scenes (default: all scenes in the rows)
    partial_means: bool = False
    method_header: str = "Method"

    @classmethod
    def from_dict(cls, d: dict) -> "TableSpec":
        d = dict(d)
        d["columns"] = [c if isinstance(c, Column) else Column.from_dict(c) for c in d["columns"]]
        return cls(**d)


def _missing(v) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def aggregate(rows: list, spec: TableSpec) -> list:
    """Per-method mean over scenes -> list of {"method", "n_scenes", <key>: float | None} in the table's row order."""
    rows = [r for r in rows if spec.scenes is None or r.get("scene") in spec.scenes]
    order = list(spec.methods) if spec.methods is not None else []
    for r in rows:
        if r["method"] not in order and spec.methods is None:
            order.append(r["method"])
    out = []
    for m in order:
        mrows = [r for r in rows if r["method"] == m]
        agg = {"method": m, "n_scenes": len({r.get("scene") for r in mrows})}
        for c in spec.columns:
            vals = [r.get(c.key) for r in mrows]
            present = [float(v) for v in vals if not _missing(v)]
            if not present or (len(present) < len(vals) and not spec.partial_means):
                agg[c.key] = None
            else:
                agg[c.key] = sum(present) / len(present)
        out.append(agg)
    return out


def _fmt(v, fmt: str) -> str:
    if _missing(v):
        return NA
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return format(v, fmt)


def best_flags(agg: list, spec: TableSpec) -> list:
    """[row][col] True where the value is the column's best at the displayed precision (ties all True)."""
    flags = [[False] * len(spec.columns) for _ in agg]
    for j, c in enumerate(spec.columns):
        shown = [(i, float(_fmt(r[c.key], c.fmt))) for i, r in enumerate(agg) if not _missing(r[c.key])]
        if not shown:
            continue
        best = max(v for _, v in shown) if c.higher_is_better else min(v for _, v in shown)
        for i, v in shown:
            if v == best:
                flags[i][j] = True
    return flags


def footnotes(spec: TableSpec, conventions: dict | None = None) -> list:
    """Convention sentences for the table: each column's, then the spec's extras, de-duplicated, in order."""
    if conventions is None:
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
    return notes


def _arrow(c: Column, latex: bool) -> str:
    if latex:
        return "$\\uparrow$" if c.higher_is_better else "$\\downarrow$"
    return "↑" if c.higher_is_better else "↓"


def render_markdown(rows: list, spec: TableSpec, *, conventions: dict | None = None, notes: bool = True) -> str:
    """GitHub Markdown table; bold as **x**; group names prefixed to headers ("HDR PSNR↑")."""
    agg = aggregate(rows, spec)
    flags = best_flags(agg, spec)
    heads = [spec.method_header] + [
        (f"{c.group} " if c.group else "") + c.header + _arrow(c, False) for c in spec.columns]
    lines = []
    if spec.title:
        lines += [f"**{spec.title}**", ""]
    lines.append("| " + " | ".join(heads) + " |")
    lines.append("|" + "|".join([":---"] + ["---:"] * len(spec.columns)) + "|")
    for r, fl in zip(agg, flags):
        cells = [str(r["method"])]
        for c, f in zip(spec.columns, fl):
            s = _fmt(r[c.key], c.fmt)
            cells.append(f"**{s}**" if f else s)
        lines.append("| " + " | ".join(cells) + " |")
    if notes:
        lines.append("")
        lines += [f"- {n}" for n in footnotes(spec, conventions)]
    return "\n".join(lines) + "\n"


_LATEX_ESC = {"&": "\\&", "%": "\\%", "$": "\\$", "#": "\\#", "_": "\\_", "{": "\\{", "}": "\\}",
              "~": "\\textasciitilde{}", "^": "\\textasciicircum{}", "\\": "\\textbackslash{}"}


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


def render_latex(rows: list, spec: TableSpec, *, conventions: dict | None = None, notes: bool = True) -> str:
    """booktabs tabular (l + one r per column), a \\multicolumn group row when groups are set, \\textbf for the best."""
    agg = aggregate(rows, spec)
    flags = best_flags(agg, spec)
    n = len(spec.columns)
    lines = []
    if spec.title:
        lines.append(f"% {spec.title}")
    lines.append("\\begin{tabular}{l" + "r" * n + "}")
    lines.append("\\toprule")
    runs = _groups(spec)
    if any(g for g, _, _ in runs):
        cells, rules = [""], []
        for g, start, cnt in runs:
            cells.append(f"\\multicolumn{{{cnt}}}{{c}}{{{latex_escape(g)}}}" if g else " & ".join([""] * cnt))
            if g:
                rules.append(f"\\cmidrule(lr){{{start + 2}-{start + cnt + 1}}}")
        lines.append(" & ".join(cells) + " \\\\")
        if rules:
            lines.append(" ".join(rules))
    heads = [latex_escape(spec.method_header)] + [latex_escape(c.header) + _arrow(c, True) for c in spec.columns]
    lines.append(" & ".join(heads) + " \\\\")
    lines.append("\\midrule")
    for r, fl in zip(agg, flags):
        cells = [latex_escape(r["method"])]
        for c, f in zip(spec.columns, fl):
            s = _fmt(r[c.key], c.fmt)
            cells.append(f"\\textbf{{{s}}}" if f else s)
        lines.append(" & ".join(cells) + " \\\\")
    lines.append("\\bottomrule")
    lines.append("\\end{tabular}")
    if notes:
        lines.append("\\par\\footnotesize")
        lines += [latex_escape(nt) + " \\\\" for nt in footnotes(spec, conventions)]
    return "\n".join(lines) + "\n"


def render_csv(rows: list, spec: TableSpec, *, conventions: dict | None = None, notes: bool = False) -> str:
    """CSV: header row (method, n_scenes, then "<group> <header>"), one row per method, values at the column
    precision, "n/a" for missing, no bold. `notes=True` appends the footnotes as '# ' comment lines."""
    agg = aggregate(rows, spec)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([spec.method_header, "n_scenes"] + [((c.group + " ") if c.group else "") + c.header
                                                  for c in spec.columns])
    for r in agg:
        w.writerow([r["method"], r["n_scenes"]] + [_fmt(r[c.key], c.fmt) for c in spec.columns])
    text = buf.getvalue()
    if notes:
        text += "".join(f"# {nt}\n" for nt in footnotes(spec, conventions))
    return text


def render(rows: list, spec: TableSpec, fmt: str = "markdown", **kw) -> str:
    """Dispatch on fmt in {"markdown", "latex", "csv"}."""
    fns = {"markdown": render_markdown, "md": render_markdown, "latex": render_latex, "tex": render_latex,
           "csv": render_csv}
    if fmt not in fns:
        raise ValueError(f"table format must be one of markdown/latex/csv, got {fmt!r}")
    return fns[fmt](rows, spec, **kw)


def paper_table_spec(title: str | None = None, *, ldr_convention: str = "ldr_float", lpips_available: bool = True,
                     lpips_normalized: bool = True) -> TableSpec:
    """The layout of the paper's main synthetic table (LDR-OE, LDR-NE, HDR: PSNR/SSIM/LPIPS; HDR-TAE)."""
    lp_conv = ("lpips" if lpips_normalized else "lpips_unnormalized") if lpips_available else "lpips_na"
    cols = []
    for grp, pre in (("LDR-OE", "ldr_oe"), ("LDR-NE", "ldr_ne"), ("HDR", "hdr")):
        cols += [Column(f"{pre}_psnr", "PSNR", True, ".2f", grp, "hdr_mu_law" if pre == "hdr" else "psnr"),
                 Column(f"{pre}_ssim", "SSIM", True, ".4f", grp, "ssim"),
                 Column(f"{pre}_lpips", "LPIPS", False, ".4f", grp, lp_conv)]
    cols.append(Column("hdr_tae", "HDR-TAE", False, ".4f", None, "hdr_tae"))
    return TableSpec(columns=cols, title=title, conventions=[ldr_convention])
