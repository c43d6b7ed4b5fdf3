"""Paired differences per (scene, seed) from the runs CSV: `m4dgs-eval pairs`.

The results page gives each difference row - ref as a mean and interval; the hand-written notes
(docs/results-notes.md) also quote the per-scene values behind them. This module prints those from
the committed CSV, so that every number in the notes can be checked with one command:

    m4dgs-eval pairs control-reproj-priors --ref full-oracle --rows no-reproj-oracle

For each row: per metric, the mean of d = row - ref over the (scene, seed) runs both rows have,
with the same Student-t 95 % interval as the tables' paired differences (`eval.stats.mean_ci`, †
where it excludes 0); the same over scenes (d averaged over each scene's seeds first, the interval
over the scene means, as the findings' "over scenes" column); then d of each pair, in the order of
the header (scenes by name, then seeds)."""

from __future__ import annotations

from typing import Dict, List, Optional, Sequence, Tuple

from .stats import by_key, mean_ci

SCORED = "scored"
DEFAULT_METRICS = ("ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr", "hdr_tae", "ldr_train_psnr")


def pair_differences(
    rows: List[dict], suite: str, row: str, ref: str, metric: str
) -> Dict[Tuple[str, int], float]:
    """{(scene, seed): row - ref} of one metric over the scored CSV rows of `suite`."""
    mine = [r for r in rows if r["suite"] == suite and r.get("status") == SCORED]
    a = by_key([r for r in mine if r["row"] == row], metric)
    b = by_key([r for r in mine if r["row"] == ref], metric)
    return {k: a[k] - b[k] for k in sorted(a) if k in b}


def _fmt(metric: str, fmts: Dict[str, str]) -> str:
    return fmts.get(metric, ".4f")


def _summary(iv, f: str) -> str:
    """mean ± half († where the interval excludes 0) (n), or n/a."""
    if iv.mean is None:
        return "n/a"
    half = "n/a" if iv.half is None else format(iv.half, f)
    return f"{iv.mean:+{f}} ± {half}{'†' if iv.excludes_zero else ''} ({iv.n})"


def pairs_markdown(
    rows: List[dict],
    suite: str,
    ref: Optional[str] = None,
    row_names: Optional[Sequence[str]] = None,
    metrics: Sequence[str] = DEFAULT_METRICS,
) -> str:
    """Markdown tables of the paired differences of `row_names` (default: every row of the suite
    in the CSV but the reference) against `ref` (default: the suite file's reference row).
    Raises ValueError naming what the CSV lacks."""
    from .suite import load_eval_suite, metric_columns

    present = [r for r in rows if r["suite"] == suite and r.get("status") == SCORED]
    if not present:
        raise ValueError(f"no scored run of suite {suite!r} in the CSV")
    names = list(dict.fromkeys(r["row"] for r in present))
    if ref is None:
        ref = load_eval_suite(suite).reference
    if ref not in names:
        raise ValueError(f"suite {suite!r} has no scored run of row {ref!r} (rows: {names})")
    wanted = [n for n in names if n != ref] if row_names is None else list(row_names)
    unknown = [n for n in wanted if n not in names]
    if unknown:
        raise ValueError(f"suite {suite!r} has no scored run of rows {unknown} (rows: {names})")
    cols = metric_columns()
    bad = [m for m in metrics if m not in cols]
    if bad:
        raise ValueError(f"unknown metrics {bad} (known: {sorted(cols)})")
    fmts = {m: cols[m].fmt for m in metrics}
    out = []
    for name in wanted:
        keys = sorted(
            set().union(*(pair_differences(rows, suite, name, ref, m) for m in metrics)),
            key=lambda k: (str(k[0]), k[1]),
        )
        out += [
            f"{suite}: {name} - {ref}",
            "",
            "| metric | mean ± 95 % (n) | over scenes (n) | "
            + " | ".join(f"{s} / {sd}" for s, sd in keys)
            + " |",
            "|:---|---:|---:|" + "---:|" * len(keys),
        ]
        for m in metrics:
            d = pair_differences(rows, suite, name, ref, m)
            f = _fmt(m, fmts)
            per_scene: Dict[str, List[float]] = {}
            for (scene, _), v in d.items():
                per_scene.setdefault(scene, []).append(v)
            scenes = mean_ci(sum(v) / len(v) for v in per_scene.values())
            cells = [f"{d[k]:+{f}}" if k in d else "" for k in keys]
            header = ((cols[m].group + " ") if cols[m].group else "") + cols[m].header
            out.append(
                f"| {header} | {_summary(mean_ci(d.values()), f)} | {_summary(scenes, f)} | "
                + " | ".join(cells)
                + " |"
            )
        out.append("")
    return "\n".join(out)
