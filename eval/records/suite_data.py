"""A suite's rows of the runs CSV (SuiteData: complete (scene, seed) pairs, the reference row) and
their tables: build_tables renders every table of a suite from collected entries, the one code
path of `m4dgs-eval table` and of the results page."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Mapping, Optional, Tuple

from eval.calibration import SEED_FREE_ROWS
from eval.calibration import VARIANT as CALIBRATION_VARIANT
from eval.conventions import MOVING_CONTENT_KEYS, PSNR_CAP_DB, all_conventions
from eval.records.runs_csv import FAILED, SCORED, SUITE_ORDER, metric_keys, row_key
from eval.records.suite import TableDef, builtin_suites, load_eval_suite, table_spec
from eval.stats import seed_noise
from eval.tables import render

FORMATS = {"md": "markdown", "markdown": "markdown", "latex": "latex", "csv": "csv"}


# --------------------------------------------------------------------------------------------------
# suites in the CSV
# --------------------------------------------------------------------------------------------------
@dataclass
class SuiteData:
    """The CSV rows of one suite, completed to the grid scenes x rows x seeds."""

    name: str
    suite: object  # eval.records.suite.EvalSuite, or None when the definition is unknown
    rows: List[dict]  # the CSV rows of the suite
    scenes: List[str]  # scenes with a CSV row, in the scene suite's order
    all_scenes: List[str]  # every scene of the suite's scene suite
    seeds: List[int]  # the trainer seeds some CSV row of the suite has
    row_names: List[str]  # in the suite's order
    labels: Dict[str, str]
    entries: List[dict] = field(default_factory=list)  # build_tables' entries (below)

    @property
    def scored(self) -> List[dict]:
        return [e for e in self.entries if e["metrics"]]

    @property
    def pairs(self) -> List[Tuple[str, int]]:
        """Every (scene, seed) of the grid."""
        return list(dict.fromkeys((e["scene"], e["seed"]) for e in self.entries))

    @property
    def complete_pairs(self) -> List[Tuple[str, int]]:
        """The (scene, seed) pairs on which every row that has a scored run anywhere in the suite
        is scored (a row nobody ran does not hold a pair back): the runs the tables compare while
        a suite is still running, every row on the same pairs."""
        ran = {e["row"] for e in self.scored}
        done: Dict[Tuple[str, int], set] = {}
        for e in self.scored:
            done.setdefault((e["scene"], e["seed"]), set()).add(e["row"])
        return [p for p in self.pairs if ran and ran <= done.get(p, set())]

    @property
    def table_entries(self) -> List[dict]:
        """The entries the tables and figures use: those of the complete pairs; every entry when
        no pair is complete (the tables then show n/a where a row lacks a run) or all are."""
        keep = set(self.complete_pairs)
        if not keep:
            return list(self.entries)
        return [e for e in self.entries if (e["scene"], e["seed"]) in keep]

    @property
    def left_out(self) -> List[dict]:
        """Scored entries the tables leave out: those of pairs that are not complete yet."""
        kept = {id(e) for e in self.table_entries}
        return [e for e in self.scored if id(e) not in kept]

    @property
    def missing(self) -> List[dict]:
        """Entries without metrics whose last attempt did not fail (not run, or running)."""
        return [e for e in self.entries if not e["metrics"] and not e.get("error")]

    @property
    def failed(self) -> List[dict]:
        """Entries whose job failed (a CSV row with status "failed"; "error" says why)."""
        return [e for e in self.entries if not e["metrics"] and e.get("error")]

    @property
    def presets(self) -> Dict[str, int]:
        out: Dict[str, int] = {}
        for r in self.rows:
            if r.get("status") == SCORED:
                out[r.get("preset") or "?"] = out.get(r.get("preset") or "?", 0) + 1
        return dict(sorted(out.items()))

    def partial_metrics(self) -> Dict[str, Tuple[int, int]]:
        """{metric: (runs that have it, scored runs of the rows that have it in some run)} for the
        metrics that some scored runs of a row have and others of the same row lack: a run scored
        before the metric existed, or a row written back by an export that did not know it. A
        metric that a row never has (LPIPS without weights, tracks of a row without them) is not
        partial, nor one of eval.conventions.MOVING_CONTENT_KEYS that no run of a scene has
        (the dynamic-pixel scores of a scene where nothing moves): the counts leave such scenes
        out."""
        out: Dict[str, Tuple[int, int]] = {}
        for k in metric_keys():
            scenes = {e["scene"] for e in self.scored if e["metrics"].get(k) is not None}
            by_row: Dict[str, List[bool]] = {}
            for e in self.scored:
                if e["scene"] in scenes or k not in MOVING_CONTENT_KEYS:
                    by_row.setdefault(e["row"], []).append(e["metrics"].get(k) is not None)
            reported = [v for v in by_row.values() if any(v)]
            have, total = sum(sum(v) for v in reported), sum(len(v) for v in reported)
            if have < total:
                out[k] = (have, total)
        return out

    def seed_noise(self, metric: str):
        """eval.stats.SeedNoise of one metric over the suite's (scene, row) groups with runs of two
        or more trainer seeds (every scored run, not only the tables' complete pairs; not the
        rows that make one prediction for every seed, whose copies would read as zero noise), or
        None."""
        groups: Dict[Tuple[str, str], List[float]] = {}
        for e in self.scored:
            if e.get("same_every_seed"):
                continue
            v = e["metrics"].get(metric)
            if v is not None:
                groups.setdefault((e["scene"], e["row"]), []).append(float(v))
        return seed_noise(groups)

    def provenance(self, column: str) -> Dict[str, int]:
        """{value: number of scored runs} of a provenance column ("code", "generator",
        "torch_threads", "host"); runs whose CSV row does not say count under "not recorded", but
        the calibration rows, which train nothing, under "none (2D rows)" for the m4dgs code and
        the torch threads."""
        out: Dict[str, int] = {}
        for r in self.rows:
            if r.get("status") == SCORED:
                v = str(r.get(column) or "") or (
                    "none (2D rows)"
                    if r.get("variant") == CALIBRATION_VARIANT
                    and column in ("code", "torch_threads")
                    else "not recorded"
                )
                out[v] = out.get(v, 0) + 1
        return dict(sorted(out.items()))


def _load_suite(name: str, definitions: Optional[Mapping[str, object]] = None):
    """The suite's definition: from `definitions` ({name: EvalSuite}, suite files given by path),
    else the built-in suite of that name, else None."""
    if definitions and name in definitions:
        return definitions[name]
    return load_eval_suite(name) if name in builtin_suites() else None


def suite_data(
    name: str, rows: List[dict], definitions: Optional[Mapping[str, object]] = None
) -> SuiteData:
    """Entries of one suite for the tables: every (seed, clip setting, scene, row) of the grid in
    the order of the suite's job list (so the row order matches `eval table`), a CSV row as a scored
    entry with its metrics, a missing or absent one without. definitions: {name: EvalSuite} of
    suites that are not built in (`m4dgs-eval results --suite FILE`)."""
    s = _load_suite(name, definitions)
    keys = metric_keys()
    by = {row_key(r): r for r in rows if r["suite"] == name}
    present = list(dict.fromkeys(r["scene"] for r in by.values()))
    all_scenes = present
    if s is not None:
        try:
            from eval.records.suite import scene_suite_names

            all_scenes = scene_suite_names(s)
        except Exception:  # noqa: BLE001 - an unknown scene suite: keep the scenes of the CSV
            all_scenes = present
    scenes = [sc for sc in all_scenes if sc in present] + sorted(
        sc for sc in present if sc not in all_scenes
    )
    # the trainer seeds the suite's rows have (a campaign may run seeds 2 and 3 only: seeds 0 and 1
    # are then no runs missing but seeds it never meant to run)
    seeds = sorted({k[3] for k in by}) or [0]
    # rows grouped by clip setting, in the suite's order (the job list's order, so the tables list
    # the rows as `eval table` does); rows the suite no longer defines come last
    groups, labels = [], {}
    if s is not None:
        for key in s.clips:
            groups.append([r.name for r in s.rows if r.clip == key])
        labels = {r.name: r.label for r in s.rows}
    extra = [rn for rn in dict.fromkeys(r["row"] for r in by.values()) if rn not in labels]
    for rn in extra:
        labels[rn] = next(r.get("label") or rn for r in by.values() if r["row"] == rn)
    groups.append(extra)
    row_names = ([r.name for r in s.rows] if s is not None else []) + extra
    # the calibration rows (from the suite's definition, else the CSV's variant) and those whose
    # prediction no trainer seed changes
    calibration = (
        {r.name: r.calibration for r in s.rows if r.calibration is not None}
        if s is not None
        else {
            r["row"]: r["variant"] for r in by.values() if r.get("variant") == CALIBRATION_VARIANT
        }
    )
    seed_free = {rn for rn, cal in calibration.items() if cal in SEED_FREE_ROWS}
    entries = []
    for seed in seeds:
        for group in groups:
            for sc in scenes:
                for rn in group:
                    r = by.get((name, sc, rn, seed))
                    metrics, error = None, None
                    if r is not None and r.get("status") == FAILED:
                        error = r.get("error") or "failed (no message recorded)"
                    if r is not None and r.get("status") == SCORED:
                        metrics = {k: r[k] for k in keys if r.get(k) is not None}
                        metrics["ldr_convention"] = r.get("ldr_convention") or "ldr_png"
                    run = rn if seed == 0 else f"{rn}-seed-{seed}"
                    entries.append(
                        {
                            "scene": sc,
                            "row": rn,
                            "label": labels[rn],
                            "seed": seed,
                            "run_dir": f"{name}/{sc}/{run}",
                            "clip_dir": None,
                            "metrics": metrics,
                            "error": error,
                            "calibration": calibration.get(rn),
                            "same_every_seed": rn in seed_free,
                        }
                    )
    return SuiteData(
        name, s, [by[k] for k in sorted(by)], scenes, all_scenes, seeds, row_names, labels, entries
    )


def suites_in(rows: List[dict]) -> List[str]:
    names = list(dict.fromkeys(r["suite"] for r in rows))
    return [n for n in SUITE_ORDER if n in names] + sorted(n for n in names if n not in SUITE_ORDER)


def suite_tables(data: SuiteData, fmt: str = "markdown", first_only: bool = False) -> str:
    """The suite's tables rendered by build_tables (below; the code of `m4dgs-eval table`)."""
    if data.suite is not None:
        defs, ref = data.suite.tables, data.suite.reference
    else:
        defs = [TableDef(data.name, "paper")]
        ref = "full" if "full" in data.row_names else None
    if first_only:
        defs = defs[:1]
    return build_tables(data.table_entries, defs, fmt, ref)


def build_tables(
    entries: list, table_defs: list, fmt: str = "markdown", reference: str | None = None
) -> str:
    """Render every table of a suite from collected entries: mean +- 95 % t-interval over the
    (scene, seed) runs of each row, best mean in bold, the paired difference to the `reference` row
    (a row name; its label in the table), for tables with `paper` the paper's values and the
    direction agreement, footnotes. A calibration row (entry "calibration") with scored runs
    appears in the tables where it has a value."""
    present = [e for e in entries if e["metrics"]]
    methods = list(dict.fromkeys(e["label"] for e in entries))
    label_of = {}
    for e in entries:
        label_of.setdefault(e["row"], e["label"])
    ref_label = label_of.get(reference) if reference is not None else None
    rows = []
    for e in (
        entries
    ):  # a run without metrics.json counts as a scene without values: its row's means are n/a
        r = {"method": e["label"], "scene": e["scene"], "seed": e.get("seed", 0)}
        if e["metrics"]:
            r.update(
                {k: v for k, v in e["metrics"].items() if isinstance(v, (int, float)) or v is None}
            )
        rows.append(r)
    calibration = {e["label"] for e in entries if e.get("calibration")}
    scored_labels = {e["label"] for e in present}
    lp = any(r.get(k) is not None for r in rows for k in r if k.endswith("_lpips"))
    convs = {e["metrics"].get("ldr_convention", "ldr_png") for e in present}
    ldr_conv = (
        convs.pop()
        if len(convs) == 1
        else "LDR scored with mixed conventions across runs (see metrics.json)"
    )
    conventions = all_conventions()
    parts = []
    for td in table_defs:
        spec = table_spec(td, lpips_available=lp, ldr_convention=ldr_conv, methods=methods)
        spec.intervals, spec.reference = True, ref_label
        # a scored calibration row stays out of a table where it has no value (a 2D prediction
        # has no training time, cameras or training-frame renders); one without runs yet stays, n/a
        keys = [c.key for c in spec.columns]
        valued = {r["method"] for r in rows if any(r.get(k) is not None for k in keys)}
        spec.methods = [
            m for m in methods if m not in calibration or m in valued or m not in scored_labels
        ]
        spec.calibration = frozenset(
            m for m in calibration if m in spec.methods and m in scored_labels
        )
        # (only where a second seed repeats them: with one seed there is nothing to count once)
        spec.seed_free = frozenset(
            e["label"]
            for e in entries
            if e.get("same_every_seed") and e.get("seed") and e["label"] in spec.methods
        )
        if getattr(td, "paper", None):
            from eval.paper import load_paper_values

            pt = load_paper_values()[td.paper]
            spec.paper = {label_of[row]: vals for row, vals in pt.rows.items() if row in label_of}
            spec.paper_source = pt.source
        if any(r.get(c.key) == PSNR_CAP_DB for r in rows for c in spec.columns if "psnr" in c.key):
            spec.conventions = list(spec.conventions) + ["psnr_cap"]
        parts.append(
            render(
                rows,
                spec,
                FORMATS[fmt],
                conventions=conventions,
                **({"notes": True} if FORMATS[fmt] == "csv" else {}),
            )
        )
    missing = [e for e in entries if not e["metrics"]]
    if missing:
        note = (
            f"{len(missing)} of {len(entries)} runs have no metrics.json yet "
            f"(e.g. {missing[0]['run_dir']})"
        )
        parts.append(
            ("% " if FORMATS[fmt] == "latex" else "# " if FORMATS[fmt] == "csv" else "> ")
            + note
            + "\n"
        )
    return "\n".join(parts)


# the compact table `m4dgs-eval table` prints by default (--columns all: every table of the suite)
# (the held-out views' LDR-OE mPSNR where the clips have views: the score that 2D cannot fake)
COMPACT_COLUMNS = ("ldr_oe_psnr", "nv_ldr_oe_mpsnr", "hdr_psnr", "hdr_tae", "train_minutes")
METHOD = "Mono4DGS-HDR"


def compact_tables(entries: list, title: str) -> tuple:
    """(entries, table definitions) of the compact table: LDR-OE PSNR, the views' LDR-OE mPSNR,
    HDR PSNR, HDR-TAE and training time (COMPACT_COLUMNS) without the columns no run has a value
    of, and the `full` row labelled as the method ("Mono4DGS-HDR (full)") where its label does
    not say so."""
    keys = [
        k for k in COMPACT_COLUMNS if any((e["metrics"] or {}).get(k) is not None for e in entries)
    ]
    out = [
        dict(e, label=f"{METHOD} ({e['label']})")
        if e["row"] == "full" and METHOD not in e["label"]
        else e
        for e in entries
    ]
    return out, [TableDef(title, keys or list(COMPACT_COLUMNS))]
