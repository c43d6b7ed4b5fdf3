"""The published results: a small CSV of per-run metrics, and docs/results.md regenerated from it.

    m4dgs-eval export SUITE [SUITE...] --root RUNS --csv results/runs.csv
    m4dgs-eval results --csv results/runs.csv --out docs/results.md

`export` collects the runs of suites (the records `m4dgs-eval table` aggregates: eval.cli
collect_suite) into one tidy CSV, one row per (suite, scene, row, seed) with the scalar metrics of
eval.suite.metric_columns() as columns (6 significant digits), and the learned CRF curves (mean of
RGB on a fixed log2-exposure grid, 3 decimals) into a second CSV beside it (`<stem>-crf.csv`). It
merges with an existing CSV: a scored run replaces the row of the same key, a run without
metrics.json ("missing", or "failed" with its error when the job's last attempt failed:
eval.runner.record_failure) never replaces a scored row, and rows of other suites, scenes or seeds
stay, so suites run in different sessions accumulate.

`results` renders, for every suite in the CSV, what stands behind it (scenes, seeds, presets,
scored, failed and missing runs), every table of the suite through eval.cli.build_tables (the same
code as `eval table`: mean +- Student-t 95 % interval, paired differences to the reference row, the
paper's values and the direction-agreement column) over the (scene, seed) pairs on which every row
with runs is scored (SuiteData.complete_pairs: a suite still running compares every row on the same
runs), figures (per-scene bars of the main metric, learned CRF curves against the true ones, HDR-TAE
vs LDR-OE PSNR per run and as paired differences to the reference row), and a "Findings" section
with one table per finding of the paper (FINDINGS): the paper's difference, ours with its interval
and number of (scene, seed) pairs, and the verdict; then a "Controls" section (CONTROLS): for each
control run for a disagreement, the effect as found, the same effect under the control, and their
difference in differences with its interval. It also replaces the block between README_START and
README_END of the README with the main table. The output depends only on the CSV (no dates), so
running it twice changes nothing. Prose that needs a human (what a verdict or a control's answer
means) lives in a hand-written notes file that the page links."""

from __future__ import annotations

import csv
import hashlib
import io
import math
import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

from m4dgs.core import io as mio

# --------------------------------------------------------------------------------------------------
# CSV schema
# --------------------------------------------------------------------------------------------------
KEY = ("suite", "scene", "row", "seed")
META = KEY + (
    "label",  # the row's label in the tables
    "variant",  # m4dgs.training.variants name
    "clip_setting",  # clip setting id (OUT/clips/<id>: syn-exp-3, syn-exp-3-crf-aces-filmic)
    "crf",  # the clip's true camera response
    "preset",  # training preset of the run (run.json / metrics.json)
    "status",  # scored | failed (the job's last attempt failed) | missing (no metrics.json yet)
    "ldr_convention",  # ldr_png | ldr_jpeg (metrics.json)
    # provenance: runs of one comparison should come from the same code, clips and thread count
    "code",  # 12 hex digits of the fingerprint of the m4dgs sources it ran (run.json)
    "generator",  # benchgen generator version of the run's clip (clip.json generator.version)
    "torch_threads",  # torch threads of the training (run.json; another count = another draw)
    "host",  # the machine it trained on: host_label(run.json host); another CPU kind = another draw
    "error",  # a failed run's one-line error (<run>/failure.json), else empty
)
SCORED, MISSING, FAILED = "scored", "missing", "failed"
CRF_GRID = [i / 2 for i in range(-20, 21)]  # log2 exposure -10 .. 10 in half stops
CRF_KEY = KEY + ("crf",)
SUITE_ORDER = (
    "paper-main",
    "paper-ablation",
    "control-points",
    "exposure-schedules",
    "exposure-noise",
    "priors",
    "crf",
)
README_START = "<!-- results:main:start -->"
README_END = "<!-- results:main:end -->"
MAIN_SUITE = "paper-main"


def metric_keys() -> List[str]:
    """The metric columns of the CSV: every key a suite table may show (eval.suite)."""
    from .suite import metric_columns

    return list(metric_columns())


def crf_csv_path(csv_path) -> Path:
    """The CRF-curve CSV beside the runs CSV: results/runs.csv -> results/runs-crf.csv."""
    p = Path(csv_path)
    return p.with_name(p.stem + "-crf.csv")


def floors_csv_path(csv_path) -> Path:
    """The clip-floor CSV beside the runs CSV: results/runs.csv -> results/runs-floors.csv."""
    p = Path(csv_path)
    return p.with_name(p.stem + "-floors.csv")


# the ground-truth HDR-TAE floors of a scene's clips (clip.json gt): the metric scored on the
# ground truth itself, a property of the scene's HDR render, which every clip setting of one scene
# and generator version shares (priors, camera response and exposure schedule change the inputs)
FLOOR_KEY = ("scene", "generator")
FLOOR_COLUMNS = ("hdr_tae_floor", "hdr_tae_floor_interior")


def read_floors_csv(path) -> Dict[tuple, Dict[str, Optional[float]]]:
    """{(scene, generator): {"hdr_tae_floor", "hdr_tae_floor_interior"}} of a clip-floor CSV."""
    p = Path(path)
    if not p.exists():
        return {}
    with open(p, newline="", encoding="utf-8") as f:
        return {
            (r["scene"], r["generator"]): {c: parse_number(r.get(c)) for c in FLOOR_COLUMNS}
            for r in csv.DictReader(f)
        }


def write_floors_csv(path, floors: Dict[tuple, Dict[str, Optional[float]]]) -> None:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(list(FLOOR_KEY) + list(FLOOR_COLUMNS))
    for k in sorted(floors):
        w.writerow(list(k) + [fmt_number(floors[k].get(c)) for c in FLOOR_COLUMNS])
    mio.write_bytes_atomic(Path(path), buf.getvalue().encode())


def _clip_meta(clip_dir) -> dict:
    """A clip's clip.json ({} when the clip folder or the file is missing)."""
    c = Path(clip_dir) / "clip.json" if clip_dir else None
    return mio.read_json(c) if c is not None and c.exists() else {}


def clip_floors(meta: dict) -> Optional[Tuple[str, Dict[str, Optional[float]]]]:
    """(generator version, floors) from a clip's clip.json contents, None without a generator
    version or a recorded floor (clips benchgen did not make, or made before the floors were
    recorded)."""
    gen = str((meta.get("generator") or {}).get("version", ""))
    gt = meta.get("gt") or {}
    vals = {k: gt.get(k) for k in FLOOR_COLUMNS}
    vals = {k: float(v) if isinstance(v, (int, float)) else None for k, v in vals.items()}
    if not gen or vals["hdr_tae_floor"] is None:
        return None
    return gen, vals


def fmt_number(v) -> str:
    """A metric as CSV text: 6 significant digits (integers from 1e6 on), "" for None / NaN."""
    if v is None or isinstance(v, bool):
        return ""
    v = float(v)
    if math.isnan(v):
        return ""
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    return f"{v:.0f}" if abs(v) >= 1e6 else f"{v:.6g}"


def parse_number(text: str) -> Optional[float]:
    return None if text is None or text.strip() == "" else float(text)


def _key(r: dict) -> tuple:
    return (r["suite"], r["scene"], r["row"], int(r["seed"]))


# --------------------------------------------------------------------------------------------------
# export
# --------------------------------------------------------------------------------------------------
def _crf_values(curve: dict) -> Optional[List[float]]:
    """metrics.json crf_curve -> the learned curve (mean of RGB) on CRF_GRID (None without one)."""
    import numpy as np

    if not curve or not curve.get("learned") or not curve.get("log2_x"):
        return None
    z = np.asarray(curve["log2_x"], np.float64)
    y = np.asarray(curve["learned"], np.float64).reshape(len(z), -1).mean(axis=1)
    return [float(v) for v in np.interp(CRF_GRID, z, y)]


def host_label(host: Optional[Mapping[str, object]]) -> str:
    """run.json's `host` record (m4dgs.core.host.host_info) -> one CSV cell: the CPU model, the
    instruction set torch's CPU kernels dispatch on and, for a run trained on CUDA, the device,
    joined by " / " (e.g. "AMD EPYC / AVX2", "AMD EPYC / AVX2 / NVIDIA H200"); "" without one
    (runs made before run.json recorded the host)."""
    if not host:
        return ""
    parts = [str(host.get(k) or "").strip() for k in ("cpu", "cpu_capability", "gpu")]
    return " / ".join(p for p in parts if p)


def _provenance(run_dir, clip_meta: dict) -> Dict[str, str]:
    """The provenance cells of a run: code fingerprint (12 hex digits), the clip's generator version
    (from its clip.json contents), the torch thread count, the host (`host_label`) and the training
    preset (run.json, written when training starts: also known for a run that failed before it was
    scored); "" where a run (or an older run.json / clip.json) does not say."""
    info = {}
    p = Path(run_dir) / "run.json"
    if p.exists():
        info = mio.read_json(p)
    gen = (clip_meta.get("generator") or {}).get("version", "")
    threads = info.get("torch_threads", "")
    return {
        "code": str(info.get("code") or "")[:12],
        "generator": str(gen),
        "torch_threads": str(threads),
        "host": host_label(info.get("host")),
        "preset": str(info.get("preset") or ""),
    }


def export_suite(
    suite, root, scenes=None, seeds=None, add_missing: bool = False
) -> Tuple[List[dict], List[dict], dict]:
    """(runs rows, CRF rows, clip floors) of one suite's jobs under ROOT (eval.cli.collect_suite):
    every job, a scored one with its metrics, a job without metrics.json with status "failed"
    (and its error) when its run folder records a failed attempt, else "missing";
    the floors {(scene, generator): {...}} of the scored runs' clips (clip_floors). Without
    `scenes`, only the scenes with at least one run folder of the suite (the subset that was run);
    with `scenes`, every job of those scenes. add_missing: first compute, for every scored run, the
    metrics its metrics.json lacks because an earlier version scored it
    (eval.score.add_missing_metrics; written into the run's metrics.json)."""
    from .cli import collect_suite
    from .runner import read_failure
    from .suite import load_eval_suite

    s = load_eval_suite(suite)
    entries = collect_suite(suite, root, scenes, seeds=seeds)
    if scenes is None:  # scenes without any run folder were not run: not part of the subset
        ran = {e["scene"] for e in entries if Path(e["run_dir"]).exists()}
        entries = [e for e in entries if e["scene"] in ran]
    if add_missing:
        from .score import add_missing_metrics

        for e in entries:
            if e["metrics"]:
                e["metrics"], _ = add_missing_metrics(e["run_dir"], clip=e["clip_dir"])
    keys = metric_keys()
    rows, crfs, floors, metas = [], [], {}, {}
    for e in entries:
        if e["clip_dir"] not in metas:  # the runs of one clip read its clip.json once
            metas[e["clip_dir"]] = _clip_meta(e["clip_dir"])
        meta = metas[e["clip_dir"]]
        row = s.row(e["row"])
        setting = s.clips[row.clip]
        m = e["metrics"] or {}
        curve = m.get("crf_curve") or {}
        error = None if e["metrics"] else read_failure(e["run_dir"])
        prov = _provenance(e["run_dir"], meta)
        run_preset = prov.pop("preset")
        r = {
            "suite": s.name,
            "scene": e["scene"],
            "row": e["row"],
            "seed": int(e.get("seed") or 0),
            "label": row.label,
            "variant": row.variant,
            "clip_setting": setting.setting_id(s.scenes),
            "crf": curve.get("crf") or setting.crf or "hdrnerf",
            # a failed run's preset from its run.json, so that its row is recognised at that
            # preset when the run folder is gone (eval.campaign.recorded_runs)
            "preset": (m.get("run") or {}).get("preset") or (run_preset if error else ""),
            "status": SCORED if e["metrics"] else (FAILED if error else MISSING),
            "ldr_convention": m.get("ldr_convention", "") if e["metrics"] else "",
            **prov,
            "error": error or "",
        }
        for k in keys:
            v = m.get(k)
            r[k] = v if isinstance(v, (int, float)) and not isinstance(v, bool) else None
        rows.append(r)
        vals = _crf_values(curve) if e["metrics"] else None
        if vals is not None:
            crfs.append({**{k: r[k] for k in CRF_KEY}, "values": vals})
        fl = clip_floors(meta) if e["metrics"] else None
        if fl is not None:
            floors[(e["scene"], fl[0])] = fl[1]
    return rows, crfs, floors


def read_runs_csv(path) -> List[dict]:
    """Rows of a runs CSV: metric cells as floats (None when empty), seed as int, the rest text."""
    p = Path(path)
    if not p.exists():
        return []
    with open(p, newline="", encoding="utf-8") as f:
        rd = csv.DictReader(f)
        out = []
        for r in rd:
            d = {}
            for k, v in r.items():
                if k in META:
                    d[k] = int(v) if k == "seed" else (v or "")
                else:
                    d[k] = parse_number(v)
            out.append(d)
    return out


def read_crf_csv(path) -> Dict[tuple, dict]:
    """{(suite, scene, row, seed): {"crf", "log2_x", "learned"}} of a CRF-curve CSV."""
    p = Path(path)
    if not p.exists():
        return {}
    with open(p, newline="", encoding="utf-8") as f:
        rd = csv.reader(f)
        head = next(rd, None)
        if head is None:
            return {}
        n = len(CRF_KEY)
        grid = [float(h) for h in head[n:]]
        out = {}
        for r in rd:
            d = dict(zip(CRF_KEY, r[:n]))
            d["seed"] = int(d["seed"])
            out[_key(d)] = {
                "crf": d["crf"],
                "log2_x": grid,
                "learned": [parse_number(v) for v in r[n:]],
            }
    return out


def _sorted(rows: List[dict]) -> List[dict]:
    return sorted(rows, key=_key)


def write_runs_csv(path, rows: List[dict], extra: Sequence[str] = ()) -> None:
    """Write the runs CSV atomically (META, the metric columns, then `extra` columns of an older
    file), rows sorted by (suite, scene, row, seed)."""
    cols = list(META) + metric_keys()
    cols += [c for c in extra if c not in cols]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in _sorted(rows):
        w.writerow([r.get(c, "") if c in META else fmt_number(r.get(c)) for c in cols])
    mio.write_bytes_atomic(Path(path), buf.getvalue().encode())


def write_crf_csv(path, curves: Dict[tuple, dict]) -> None:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(list(CRF_KEY) + [f"{x:g}" for x in CRF_GRID])
    for k in sorted(curves):
        c = curves[k]
        vals = list(c["learned"])
        if list(c["log2_x"]) != CRF_GRID:
            import numpy as np

            vals = list(np.interp(CRF_GRID, c["log2_x"], vals))
        w.writerow(list(k) + [c["crf"]] + ["" if v is None else f"{v:.3f}" for v in vals])
    mio.write_bytes_atomic(Path(path), buf.getvalue().encode())


def merge_rows(old: List[dict], new: List[dict]) -> List[dict]:
    """New rows replace old rows of the same (suite, scene, row, seed); a missing or failed run
    never replaces a scored one, nor a missing run a failed one (its run folder lost, the CSV is
    the record of that failure); every other old row stays."""
    idx = {_key(r): r for r in old}
    for r in new:
        k = _key(r)
        was = idx[k].get("status") if k in idx else None
        if r["status"] != SCORED and was == SCORED:
            continue
        if r["status"] == MISSING and was == FAILED:
            continue
        idx[k] = r
    return _sorted(list(idx.values()))


def export(
    suites: Sequence[str],
    root,
    csv_path,
    scenes=None,
    seeds=None,
    log=None,
    add_missing: bool = False,
) -> dict:
    """Collect the runs of `suites` under ROOT and merge them into csv_path, its CRF CSV and its
    clip-floor CSV (floors_csv_path; written when a run's clip records its floors). add_missing:
    see export_suite.

    Returns {suite: {"scored", "failed", "missing"}} of what was collected; raises InputError
    when a suite has no scored run under ROOT (a wrong ROOT would otherwise add only missing
    rows)."""
    from m4dgs.core.errors import InputError

    say = log or (lambda s: None)
    old = read_runs_csv(csv_path)
    extra = []
    if Path(csv_path).exists():
        with open(csv_path, newline="", encoding="utf-8") as f:
            head = next(csv.reader(f), [])
        extra = [c for c in head if c not in META and c not in metric_keys()]
    curves = read_crf_csv(crf_csv_path(csv_path))
    floors = read_floors_csv(floors_csv_path(csv_path))
    new_rows, summary = [], {}
    for suite in suites:
        rows, crfs, fl = export_suite(suite, root, scenes, seeds, add_missing=add_missing)
        floors.update(fl)
        name = rows[0]["suite"] if rows else str(suite)
        scored = [r for r in rows if r["status"] == SCORED]
        if not scored:
            raise InputError(
                f"no metrics.json found for suite {name!r} under {root} "
                "(run `m4dgs-eval run` first)"
            )
        presets = sorted(
            {r["preset"] for r in scored}
            | {r["preset"] for r in old if r["suite"] == name and r.get("status") == SCORED}
        )
        if len(presets) > 1:
            say(f"warning: suite {name} mixes presets {presets} in {csv_path}")
        for r in scored:  # a re-scored run's curve replaces the old one (or removes it)
            curves.pop(_key(r), None)
        for c in crfs:
            curves[_key(c)] = {"crf": c["crf"], "log2_x": CRF_GRID, "learned": c["values"]}
        new_rows += rows
        failed = sum(r["status"] == FAILED for r in rows)
        summary[name] = {
            "scored": len(scored),
            "failed": failed,
            "missing": len(rows) - len(scored) - failed,
        }
    merged = merge_rows(old, new_rows)
    for name in summary:
        # runs whose row does not say (older code) are not another version or host
        for column, what in (
            ("code", "m4dgs code versions"),
            ("generator", "clip generator versions"),
            ("host", "hosts"),
        ):
            seen = Counter(
                str(r[column])
                for r in merged
                if r["suite"] == name and r.get("status") == SCORED and r.get(column)
            )
            if len(seen) > 1:
                counts = ", ".join(f"{k} ({v} runs)" for k, v in sorted(seen.items()))
                say(
                    f"warning: suite {name} mixes {what} in {csv_path}: {counts}; paired "
                    "differences across them compare other code, clips or machines, not only "
                    "the rows (docs/reliability.md)"
                )
    Path(csv_path).parent.mkdir(parents=True, exist_ok=True)
    write_runs_csv(csv_path, merged, extra)
    write_crf_csv(crf_csv_path(csv_path), curves)
    if floors:
        write_floors_csv(floors_csv_path(csv_path), floors)
    return summary


# --------------------------------------------------------------------------------------------------
# suites in the CSV
# --------------------------------------------------------------------------------------------------
@dataclass
class SuiteData:
    """The CSV rows of one suite, completed to the grid scenes x rows x seeds."""

    name: str
    suite: object  # eval.suite.EvalSuite, or None when the definition is unknown
    rows: List[dict]  # the CSV rows of the suite
    scenes: List[str]  # scenes with a CSV row, in the scene suite's order
    all_scenes: List[str]  # every scene of the suite's scene suite
    seeds: List[int]
    row_names: List[str]  # in the suite's order
    labels: Dict[str, str]
    entries: List[dict] = field(default_factory=list)  # eval.cli.build_tables entries

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
        partial."""
        out: Dict[str, Tuple[int, int]] = {}
        for k in metric_keys():
            by_row: Dict[str, List[bool]] = {}
            for e in self.scored:
                by_row.setdefault(e["row"], []).append(e["metrics"].get(k) is not None)
            reported = [v for v in by_row.values() if any(v)]
            have, total = sum(sum(v) for v in reported), sum(len(v) for v in reported)
            if have < total:
                out[k] = (have, total)
        return out

    def seed_noise(self, metric: str):
        """eval.stats.SeedNoise of one metric over the suite's (scene, row) groups with runs of two
        or more trainer seeds (every scored run, not only the tables' complete pairs), or None."""
        from .stats import seed_noise

        groups: Dict[Tuple[str, str], List[float]] = {}
        for e in self.scored:
            v = e["metrics"].get(metric)
            if v is not None:
                groups.setdefault((e["scene"], e["row"]), []).append(float(v))
        return seed_noise(groups)

    def provenance(self, column: str) -> Dict[str, int]:
        """{value: number of scored runs} of a provenance column ("code", "generator",
        "torch_threads", "host"); runs whose CSV row does not say count under "not recorded"."""
        out: Dict[str, int] = {}
        for r in self.rows:
            if r.get("status") == SCORED:
                v = str(r.get(column) or "") or "not recorded"
                out[v] = out.get(v, 0) + 1
        return dict(sorted(out.items()))


def _load_suite(name: str, definitions: Optional[Mapping[str, object]] = None):
    """The suite's definition: from `definitions` ({name: EvalSuite}, suite files given by path),
    else the built-in suite of that name, else None."""
    from .suite import builtin_suites, load_eval_suite

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
    by = {_key(r): r for r in rows if r["suite"] == name}
    present = list(dict.fromkeys(r["scene"] for r in by.values()))
    all_scenes = present
    if s is not None:
        try:
            from .suite import scene_suite_names

            all_scenes = scene_suite_names(s)
        except Exception:  # noqa: BLE001 - an unknown scene suite: keep the scenes of the CSV
            all_scenes = present
    scenes = [sc for sc in all_scenes if sc in present] + sorted(
        sc for sc in present if sc not in all_scenes
    )
    seeds = list(range(1 + max((k[3] for k in by), default=0)))
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
                        }
                    )
    return SuiteData(
        name, s, [by[k] for k in sorted(by)], scenes, all_scenes, seeds, row_names, labels, entries
    )


def suites_in(rows: List[dict]) -> List[str]:
    names = list(dict.fromkeys(r["suite"] for r in rows))
    return [n for n in SUITE_ORDER if n in names] + sorted(n for n in names if n not in SUITE_ORDER)


def suite_tables(data: SuiteData, fmt: str = "markdown", first_only: bool = False) -> str:
    """The suite's tables rendered by eval.cli.build_tables (the code of `eval table`)."""
    from .cli import build_tables
    from .suite import TableDef

    if data.suite is not None:
        defs, ref = data.suite.tables, data.suite.reference
    else:
        defs = [TableDef(data.name, "paper")]
        ref = "full" if "full" in data.row_names else None
    if first_only:
        defs = defs[:1]
    return build_tables(data.table_entries, defs, fmt, ref)


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


def _cmp(ref: str, expect: str, *rows: str) -> Tuple[Comparison, ...]:
    return tuple(Comparison(r, ref, expect) for r in rows)


FINDINGS: Tuple[Finding, ...] = (
    Finding(
        "baselines",
        "The full method beats each baseline (paper Table 1)",
        "paper-main",
        "main",
        tuple(
            Comparison("full", b, "better")
            for b in ("static-hdr", "ldr-reproj-consecutive", "ldr-reproj", "world-only")
        ),
    ),
    Finding(
        "ablations",
        "Each ablation row costs quality (paper Table 3)",
        "paper-ablation",
        "ablation",
        _cmp(
            "full",
            "worse",
            "no-video-init",
            "no-occlusion",
            "no-cov-invariance",
            "no-reproj",
            "no-tlr",
        ),
    ),
    Finding(
        "control-points",
        "N_s = 4 is the sweet spot of the control-point interval (paper Table 4)",
        "control-points",
        "control-points",
        _cmp("ns-4", "better", "ns-1", "ns-2") + _cmp("ns-4", "worse", "ns-8", "ns-16"),
    ),
    Finding(
        "perturbation",
        "Exposure perturbation degrades gracefully (paper appendix)",
        "exposure-noise",
        "exposure-noise",
        (
            Comparison("ev-0.25", "ev-0", "worse"),
            Comparison("ev-0.5", "ev-0.25", "worse"),
            Comparison("ev-0.75", "ev-0.5", "worse"),
            Comparison("ev-0.75", "ev-0", "worse"),
        ),
    ),
    Finding(
        "schedules",
        "The alternating schedule is best; random schedules cost a little (paper appendix)",
        "exposure-schedules",
        "exposure-schedules",
        _cmp("alternating", "worse", "random-order", "random-values"),
    ),
    Finding(
        "priors",
        "Better priors help: dropping the depth or track loss, or harsher priors, cost quality "
        "(paper appendix; oracle and harsh priors beyond the paper)",
        "priors",
        "priors",
        _cmp("full", "worse", "no-depth-loss", "no-track-loss")
        + (Comparison("full-oracle", "full", "better"), Comparison("full-harsh", "full", "worse")),
    ),
)

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
    from .suite import metric_columns

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
    from .stats import LEVEL, holm

    adj = holm([None if r.ours is None or r.ours.half is None else r.ours.p for r in res])
    for r, a in zip(res, adj):
        r.p_holm = a
        r.verdict_holm = verdict(r.claim, r.ours, None if a is None else a < 1 - LEVEL)


def evaluate_finding(f: Finding, rows: List[dict]) -> List[ComparisonResult]:
    """Every (comparison, metric) of a finding on the scored CSV rows of its suite: the paired
    difference over the (scene, seed) runs both rows have (eval.stats.paired_diff)."""
    from .paper import load_paper_values
    from .stats import by_key, paired_diff, scene_heterogeneity, scene_paired_diff

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


def heterogeneity_text(h) -> str:
    """The findings tables' "scenes differ" cell: p = 0.123 (p < 0.001 below it), n/a for None."""
    if h is None:
        return "n/a"
    return "p < 0.001" if h.p < 0.001 else f"p = {h.p:.3f}"


def findings_markdown(
    rows: List[dict],
    notes_link: Optional[str],
    figures: Optional[Dict[str, str]] = None,
    evaluated: Optional[Dict[str, List[ComparisonResult]]] = None,
) -> str:
    """The Findings section; figures: {finding key: link of its forest plot} to show under its
    table; evaluated: evaluate_findings(rows) when the caller has it."""
    from .paper import load_paper_values
    from .suite import metric_columns

    cols = metric_columns()
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
        lines += [f"### {f.title}", ""]
        if f.key not in evaluated:
            lines += [f"**not enough data**: no scored run of suite `{f.suite}` in the CSV.", ""]
            continue
        res = evaluated[f.key]
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
                f"| {r.verdict_scenes} | {heterogeneity_text(r.heterogeneity)} |"
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
    return "\n".join(lines)


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
    # added 2026-11-29 before any run of control-tlr-weight (lab/controls/): the floor
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
    from .stats import by_key

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
    from .stats import LEVEL, holm, mean_ci, paired_diff

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


def _interval_text(iv, fmt: str) -> str:
    if iv is None or iv.mean is None:
        return "n/a"
    half = "n/a" if iv.half is None else format(iv.half, fmt)
    dag = "†" if iv.excludes_zero else ""
    return f"{format(iv.mean, '+' + fmt)} ± {half}{dag} (n = {iv.n})"


def controls_markdown(
    rows: List[dict], notes_link: Optional[str], figure: Optional[str] = None
) -> str:
    """The "Controls" section: one table per control whose two effects have data, after the
    overview figure (`controls_figure`; `figure`: its link) when there is one."""
    from .suite import metric_columns

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
            lines.append(
                f"| {name} | {_interval_text(r.base, col.fmt)} | "
                f"{_interval_text(r.control, col.fmt)} | {_interval_text(r.change, col.fmt)} "
                f"| {r.reading} | {r.reading_holm} |"
            )
        lines.append("")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------------
# figures
# --------------------------------------------------------------------------------------------------
def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path) -> Path:
    """PNG without the Software tag (byte-stable across runs), written atomically."""
    plt = _plt()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)
    mio.write_bytes_atomic(Path(path), buf.getvalue())
    return Path(path)


def _colors(n: int) -> list:
    plt = _plt()
    cmap = plt.get_cmap("tab10")
    return [cmap(i % 10) for i in range(n)]


def _main_metric(data: SuiteData) -> str:
    from .suite import LAYOUTS, metric_columns

    if data.suite is not None and data.suite.tables:
        cols = data.suite.tables[0].columns
        keys = LAYOUTS[cols] if isinstance(cols, str) else list(cols)
        for k in keys:
            if k in metric_columns():
                return k
    return "ldr_oe_psnr"


def bars_figure(data: SuiteData, out_png) -> Optional[Path]:
    """Per-scene bars of the suite's main metric (first column of its first table), one bar per row
    = the mean over seeds, a dot per seed."""
    from .suite import metric_columns

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
    plt = _plt()
    rows, scenes = data.row_names, data.scenes
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
    return _save(fig, out_png)


def crf_figure(data: SuiteData, curves: Dict[tuple, dict], out_png) -> Optional[Path]:
    """Learned CRFs (mean of RGB; the lowest seed of each row and scene) against the true ones
    (dashed; black when every row shares one), one panel per scene."""
    import numpy as np

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
    plt = _plt()
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
            z = np.asarray(c["log2_x"], np.float64)
            y = np.asarray([np.nan if v is None else v for v in c["learned"]], np.float64)
            (h,) = ax.plot(z, y, lw=1.2, color=color[rn])
            handles.setdefault(data.labels[rn], h)
            if c["crf"] in done:
                continue
            done.add(c["crf"])
            try:
                from m4dgs.core.crf import get_crf

                f = get_crf(c["crf"])
            except Exception:  # noqa: BLE001 - a response this installation does not know
                continue
            zz = np.linspace(z.min(), z.max(), 201)
            true = np.asarray(f.rgb(np.repeat(np.exp2(zz)[:, None], 3, 1))).mean(axis=1)
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
    return _save(fig, out_png)


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
    plt = _plt()
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
    return _save(fig, out_png)


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
    plt = _plt()
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
    return _save(fig, out_png)


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


FINDING_FIGURE_PREFIX = "finding_"


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

    from .suite import metric_columns

    pts = finding_points(res)
    if not pts:
        return None
    cols = metric_columns()
    labels = list(dict.fromkeys(f"{c.row} - {c.ref}" for c in f.comparisons))
    plt = _plt()
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
    return _save(fig, out_png)


CONTROLS_FIGURE = "controls.png"
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

    from .suite import metric_columns

    results = controls_figure_data(rows)
    if not results:
        return None
    cols = metric_columns()
    plt = _plt()
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
    return _save(fig, out_png)


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


# --------------------------------------------------------------------------------------------------
# the page
# --------------------------------------------------------------------------------------------------
def _rel(path, start) -> str:
    return Path(os.path.relpath(Path(path).resolve(), Path(start).resolve())).as_posix()


def _suite_summary(data: SuiteData) -> dict:
    expected = len(data.entries)
    return {
        "scenes": len(data.scenes),
        "all_scenes": len(data.all_scenes),
        "seeds": len(data.seeds),
        "rows": len(data.row_names),
        "scored": len(data.scored),
        "missing": len(data.missing),
        "failed": len(data.failed),
        "pairs": len(data.pairs),
        "complete_pairs": len(data.complete_pairs),
        "left_out": len(data.left_out),
        "expected": expected,
        "presets": data.presets,
        "code": data.provenance("code"),
        "generator": data.provenance("generator"),
        "torch_threads": data.provenance("torch_threads"),
        "host": data.provenance("host"),
    }


def one_line(text: str, limit: int = 240) -> str:
    """One line of at most `limit` characters (an error message on the page)."""
    t = " ".join(str(text).split())
    return t if len(t) <= limit else t[: limit - 3] + "..."


def _counts_text(p: Dict[str, int]) -> str:
    """{value: runs} -> "v" when one value, else "v1 (n1 runs), v2 (n2 runs)"."""
    if len(p) == 1:
        return next(iter(p))
    return ", ".join(f"{k} ({v} runs)" for k, v in p.items())


def _presets_text(p: Dict[str, int]) -> str:
    if not p:
        return "n/a"
    if len(p) == 1:
        return next(iter(p))
    return "mixed: " + ", ".join(f"{k} ({v} runs)" for k, v in p.items())


def _partial_text(data: SuiteData) -> str:
    """The line saying which runs the tables of a suite in progress compare."""
    pairs = ", ".join(f"{sc} seed {seed}" for sc, seed in data.complete_pairs)
    return (
        f"- **Incomplete pairs**: the tables and figures use the {len(data.complete_pairs)} of "
        f"{len(data.pairs)} (scene, seed) pairs on which every row with runs is scored ({pairs}), "
        "so that every row is compared on the same runs; the "
        f"{len(data.left_out)} scored run(s) of the other pairs wait for the missing runs above"
        + (" or are left out with the failed run(s) of their pair" if data.failed else "")
    )


def floors_text(data: SuiteData, floors: Dict[tuple, Dict[str, Optional[float]]]) -> Optional[str]:
    """The suite's line on the ground-truth HDR-TAE floors of its scored runs' clips (mean and
    range over its (scene, generator) clips in `floors`), None when none has a recorded floor."""
    clips = sorted(
        {(r["scene"], str(r.get("generator") or "")) for r in data.rows if r["status"] == SCORED}
    )
    have = [floors[c] for c in clips if c in floors]
    if not have:
        return None

    def stat(col):
        v = [f[col] for f in have if f.get(col) is not None]
        return f"{sum(v) / len(v):.3f} ({min(v):.3f}-{max(v):.3f})" if v else "n/a"

    return (
        "- Ground-truth HDR-TAE floor of its clips (clip.json `gt.hdr_tae_floor`: the metric "
        "scored on the ground truth itself, the level a method's HDR-TAE is read against, "
        "docs/rendering.md): "
        f"mean {stat('hdr_tae_floor')} over {len(have)} of its {len(clips)} clips; edge-excluded "
        f"(`gt.hdr_tae_floor_interior`, for `hdr_tae_interior`) {stat('hdr_tae_floor_interior')}"
    )


# the headline metrics whose seed noise a suite's section gives, with their names there
SEED_NOISE_METRICS = {
    "ldr_oe_psnr": "LDR-OE PSNR",
    "hdr_psnr": "HDR PSNR",
    "hdr_tae": "HDR-TAE",
    "hdr_tce": "HDR-TCE",
}


def seed_noise_text(data: SuiteData) -> Optional[str]:
    """The section's line on how much a run moves with its trainer seed alone (SuiteData.seed_noise
    of the headline metrics), or None when no (scene, row) has runs of two seeds."""
    from .suite import metric_columns

    cols = metric_columns()
    parts, groups = [], 0
    for k in SEED_NOISE_METRICS:
        sn = data.seed_noise(k)
        if sn is None:
            continue
        fmt = cols[k].fmt
        name = SEED_NOISE_METRICS[k]
        parts.append(f"{name} {sn.rms_diff:{fmt}} (largest {sn.largest:{fmt}})")
        groups = max(groups, sn.groups)
    if not parts:
        return None
    return (
        "- Seed noise (the same scene and row trained with another trainer seed; root mean square "
        f"difference of two runs, over {groups} (scene, row) groups with two or more seeds): "
        + ", ".join(parts)
        + "; one (scene, seed) difference between two rows carries noise of this size (less "
        "where the two rows share a trained phase), a mean over n pairs about 1/sqrt(n) of it"
    )


def suite_section(
    data: SuiteData,
    fig_paths: List[Path],
    out_dir: Path,
    floors: Optional[dict] = None,
    partial: Optional[Dict[str, Tuple[int, int]]] = None,
) -> str:
    """The suite's section of the results page; partial: data.partial_metrics() when the caller
    has it."""
    from .suite import suites_dir

    sm = _suite_summary(data)
    desc = data.suite.description if data.suite is not None else "(no suite definition found)"
    lines = [f"## {data.name}", "", desc, ""]
    if data.suite is not None:
        builtin = suites_dir() / (data.name + ".yaml")
        path = builtin if data.suite.path.resolve() == builtin.resolve() else data.suite.path
        shown = f"eval/suites/{data.name}.yaml" if path == builtin else path.as_posix()
        lines += [f"Definition: [{shown}]({_rel(path, out_dir)})."]
        lines.append("")
    missing = data.missing
    miss_txt = f"{sm['missing']}" + (
        " ("
        + ", ".join(f"`{e['run_dir']}`" for e in missing[:8])
        + (f", and {len(missing) - 8} more" if len(missing) > 8 else "")
        + ")"
        if missing
        else ""
    )
    lines += [
        f"- Scenes: {sm['scenes']} of the {sm['all_scenes']} of its scene suite: "
        + ", ".join(data.scenes),
        f"- Rows: {sm['rows']} ("
        + ", ".join(f"`{r}`" for r in data.row_names)
        + f"); reference row: `{data.suite.reference if data.suite is not None else 'n/a'}`",
        f"- Trainer seeds: {sm['seeds']} (" + ", ".join(str(s) for s in data.seeds) + ")",
        f"- Preset: {_presets_text(sm['presets'])}",
        f"- Provenance: m4dgs code {_counts_text(sm['code'])}; clip generator version "
        f"{_counts_text(sm['generator'])}; torch threads {_counts_text(sm['torch_threads'])}; "
        f"host {_counts_text(sm['host'])}",
        f"- Runs: {sm['scored']} scored of {sm['expected']} "
        f"(= {sm['scenes']} scenes x {sm['rows']} rows x {sm['seeds']} seeds); "
        + (f"failed: {sm['failed']}; " if sm["failed"] else "")
        + "missing: "
        + miss_txt,
    ]
    if data.failed:
        lines.append(
            "- **Failed runs** (the job's last attempt stopped with an error; a result of the "
            "configuration when it repeats, and its (scene, seed) pair is left out of every row's "
            "tables): "
            + "; ".join(f"`{e['run_dir']}`: {one_line(e['error'])}" for e in data.failed)
        )
    ft = floors_text(data, floors or {})
    if ft:
        lines.append(ft)
    pm = data.partial_metrics() if partial is None else partial
    if pm:
        lines.append(
            "- Metrics some runs lack (scored before the metric existed, or written back by an "
            "export that did not know it): "
            + ", ".join(f"`{k}` in {h} of {n} runs" for k, (h, n) in pm.items())
            + "; the tables show n/a for it where a row lacks a run's value, the findings pair "
            "only the runs that have it"
        )
    sn = seed_noise_text(data)
    if sn:
        lines.append(sn)
    if sm["left_out"]:
        lines.append(_partial_text(data))
    lines += [
        "",
        suite_tables(data).rstrip("\n"),
        "",
    ]
    if fig_paths:
        lines += ["Figures:", ""]
        for p in fig_paths:
            lines += [f"![{p.stem}]({_rel(p, out_dir)})", ""]
    return "\n".join(lines)


def readme_block(
    main: Optional[SuiteData],
    results_link: str,
    csv_name: str,
    floors: Optional[dict] = None,
    rows: Optional[List[dict]] = None,
    evaluated: Optional[Dict[str, List[ComparisonResult]]] = None,
) -> str:
    """The README's results block (between the markers); `floors` (read_floors_csv) adds the
    line on the clips' HDR-TAE floor under the table, `rows` (the runs CSV) the findings at a
    glance (findings_glance_markdown; `evaluated`: evaluate_findings(rows) when the caller has
    it) under it."""
    head = [
        README_START,
        "<!-- generated by `m4dgs-eval results`; do not edit between the markers -->",
    ]
    if main is None or not main.scored:
        body = [
            f"The result tables are pending: `{csv_name}` has no scored run of `{MAIN_SUITE}` yet. "
            f"[{results_link}]({results_link}) lists what is there.",
        ]
    elif not main.complete_pairs or {e["row"] for e in main.table_entries if e["metrics"]} != set(
        main.row_names
    ):
        body = [
            f"The result tables are pending: `{csv_name}` has {len(main.scored)} scored run(s) of "
            f"`{MAIN_SUITE}` so far, and not yet a (scene, seed) pair on which every row is "
            f"scored. [{results_link}]({results_link}) lists what is there.",
        ]
    else:
        sm = _suite_summary(main)
        partial = ""
        if sm["left_out"]:
            partial = (
                f" The table compares the {sm['complete_pairs']} (scene, seed) pairs on which "
                f"every row is scored ({sm['left_out']} more run(s) wait for their pairs)."
            )
        body = [
            f"Suite `{MAIN_SUITE}`, preset {_presets_text(sm['presets'])}: {sm['scored']} of "
            f"{sm['expected']} runs scored ({sm['scenes']} scenes x {sm['rows']} rows x "
            f"{sm['seeds']} seeds).{partial} Every suite, the paper's values beside ours, figures "
            f"and the findings: [{results_link}]({results_link}).",
            "",
            suite_tables(main, first_only=True).rstrip("\n"),
        ]
        ft = floors_text(main, floors or {})
        if ft:
            body.append(ft)
    if rows and any(r.get("status") == SCORED for r in rows):
        if evaluated is None:
            evaluated = evaluate_findings(rows)
        glance = findings_glance_markdown(rows, evaluated, f"{results_link}#findings")
        body += ["", glance.rstrip("\n")]
    return "\n".join(head + [""] + body + ["", README_END])


def replace_readme_block(text: str, block: str, path="README") -> str:
    from m4dgs.core.errors import InputError

    i, j = text.find(README_START), text.find(README_END)
    if i < 0 or j < i:
        raise InputError(
            f"{path}: no {README_START} ... {README_END} markers; add them where the results "
            "table goes, or pass --no-readme"
        )
    return text[:i] + block + text[j + len(README_END) :]


def _is_results_figure(name: str) -> bool:
    """Whether a file name is one `suite_result_figures` writes: <suite>_<kind>.png, the suite a
    shipped suite (eval/suites/*.yaml)."""
    from .suite import suites_dir

    if name == CONTROLS_FIGURE:
        return True
    if name.startswith(FINDING_FIGURE_PREFIX) and name.endswith(".png"):
        return name[len(FINDING_FIGURE_PREFIX) : -len(".png")] in {f.key for f in FINDINGS}
    for kind in sorted(FIGURE_KINDS, key=len, reverse=True):
        tail = f"_{kind}.png"
        if name.endswith(tail):
            return (suites_dir() / f"{name[: -len(tail)]}.yaml").is_file()
    return False


def render_results(
    csv_path,
    out_md,
    *,
    figures_dir=None,
    readme=None,
    notes=None,
    command: Optional[str] = None,
    title: str = "Results",
    suite_files: Sequence = (),
) -> dict:
    """Write out_md (and the figures, and the README block) from the runs CSV.

    suite_files: YAML files of suites that are not built in (your own rows against full), so that
    their sections show the definition, the reference row and the row order; a CSV with none of
    the paper's suites then gets no findings or controls sections (they would all lack data).

    figures_dir None: no figures (else PNGs in it named as this page's figures, <suite>_<kind>.png,
    that the page no longer makes are removed). readme: a README path whose marked block is
    replaced (None: none). notes: the hand-written notes file linked from the page (None: no
    link). title: the page's heading. Returns {"suites", "figures", "readme"}."""
    csv_path, out_md = Path(csv_path), Path(out_md)
    out_dir = out_md.parent
    rows = read_runs_csv(csv_path)
    curves = read_crf_csv(crf_csv_path(csv_path))
    floors = read_floors_csv(floors_csv_path(csv_path))
    names = suites_in(rows)
    from .suite import builtin_suites, load_eval_suite

    definitions = {d.name: d for d in (load_eval_suite(p) for p in suite_files)}
    datas = {n: suite_data(n, rows, definitions) for n in names}
    partial = {n: d.partial_metrics() for n, d in datas.items()}
    # a page of only your own suites: the paper's findings and controls would all lack data
    own_only = bool(names) and not set(names) & set(builtin_suites())
    notes_link = _rel(notes, out_dir) if notes else None
    csv_link = _rel(csv_path, out_dir)
    cmd = command or f"m4dgs-eval results --csv {csv_path} --out {out_md}"
    digest = hashlib.sha256(csv_path.read_bytes()).hexdigest()[:12] if csv_path.exists() else None
    lines = [
        f"# {title}",
        "",
        f"<!-- generated by `{cmd}` from {csv_path.as_posix()}; do not edit by hand -->",
        "",
        (
            f"Generated by `{cmd}` from [{csv_path.as_posix()}]({csv_link}) (sha256 {digest}, "
            f"with the CRF curves in `{crf_csv_path(csv_path).name}`"
            + (
                f" and the clips' HDR-TAE floors in `{floors_csv_path(csv_path).name}`)."
                if floors
                else ")."
            )
            if digest
            else f"Generated by `{cmd}` from `{csv_path.as_posix()}` (the file does not exist yet)."
        ),
        "The CSV is written by `m4dgs-eval export SUITE --root RUNS --csv "
        f"{csv_path.as_posix()}` (docs/eval.md); the runs themselves stay out of git.",
        "Tables: mean ± the half-width of the Student-t 95 % interval over a row's (scene, seed) "
        "runs, Δ the paired difference to the suite's reference row († where its interval "
        "excludes 0), the paper's value and the direction agreement where the paper has the "
        'table (docs/eval.md, "m4dgs-eval table").',
    ]
    if notes_link:
        lines.append(
            f"Hand-written notes (what the verdicts mean, controls for disagreements): "
            f"[{Path(notes_link).name}]({notes_link})."
        )
    lines.append("")
    if not any(d.scored for d in datas.values()):
        lines += [
            "**The runs are pending**: "
            + (
                f"`{csv_path.as_posix()}` does not exist yet."
                if not csv_path.exists()
                else f"`{csv_path.as_posix()}` has no scored run yet."
            )
            + " Fill it with `m4dgs-eval run SUITE --preset small --seeds 2 --root "
            "experiments-small` and `m4dgs-eval export SUITE --root experiments-small --csv "
            f"{csv_path.as_posix()}`, then run `{cmd}` again.",
            "",
        ]
    if names:
        lines += [
            "| suite | scenes | rows | seeds | preset | scored | failed | missing |",
            "|:---|---:|---:|---:|:---|---:|---:|---:|",
        ]
        for n in names:
            sm = _suite_summary(datas[n])
            lines.append(
                f"| [{n}](#{n}) | {sm['scenes']} of {sm['all_scenes']} | {sm['rows']} | "
                f"{sm['seeds']} | {_presets_text(sm['presets'])} | {sm['scored']} of "
                f"{sm['expected']} | {sm['failed']} | {sm['missing']} |"
            )
        lines.append("")
    absent = [n for n in SUITE_ORDER if n not in names]
    if absent and not own_only:
        lines += [
            "Suites without runs in the CSV: " + ", ".join(f"`{n}`" for n in absent) + ".",
            "",
        ]
    figs = []
    for n in names:
        fp = suite_result_figures(datas[n], curves, figures_dir) if figures_dir else []
        figs += fp
        lines += [suite_section(datas[n], fp, out_dir, floors, partial[n]), ""]
    evaluated = {} if own_only else evaluate_findings(rows)
    if own_only:
        lines.append(
            "No suite of this CSV is one of the project's, so the paper's findings and the "
            "controls of its disagreements are not evaluated here (docs/results.md has them)."
        )
    else:
        ffigs = finding_figures(evaluated, figures_dir) if figures_dir else {}
        figs += list(ffigs.values())
        links = {k: _rel(p, out_dir) for k, p in ffigs.items()}
        lines.append(findings_markdown(rows, notes_link, links, evaluated))
        cfig = controls_figure(rows, Path(figures_dir) / CONTROLS_FIGURE) if figures_dir else None
        if cfig is not None:
            figs.append(cfig)
        lines += ["", controls_markdown(rows, notes_link, _rel(cfig, out_dir) if cfig else None)]
    text = "\n".join(lines).rstrip("\n") + "\n"
    mio.write_bytes_atomic(out_md, text.encode())
    if figures_dir:
        # figures of suites no longer in the CSV go with them; only files named as this function
        # names its figures are touched, so a shared folder keeps everything else
        made = {Path(p).resolve() for p in figs}
        for old_fig in Path(figures_dir).glob("*.png"):
            if old_fig.resolve() not in made and _is_results_figure(old_fig.name):
                old_fig.unlink()
    res = {
        "suites": names,
        "figures": [str(p) for p in figs],
        "readme": None,
        "partial_metrics": {n: pm for n, pm in partial.items() if pm},
    }
    if readme:
        rp = Path(readme)
        block = readme_block(
            datas.get(MAIN_SUITE),
            _rel(out_md, rp.parent),
            csv_path.as_posix(),
            floors,
            rows,
            evaluated,
        )
        old = rp.read_text(encoding="utf-8")
        new = replace_readme_block(old, block, rp)
        if new != old:
            mio.write_bytes_atomic(rp, new.encode())
        res["readme"] = str(rp)
    return res
