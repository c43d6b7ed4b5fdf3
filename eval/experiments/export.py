"""Export the runs of suites (run folders under a root) into the runs CSV and its companions:

    m4dgs-eval export SUITE [SUITE...] --root RUNS --csv results/runs.csv

A scored run replaces the row of the same key, a run without metrics.json ("missing", or "failed"
with its error) never replaces a scored row, rows of other suites, scenes or seeds stay
(eval.records.runs_csv.merge_rows)."""

from __future__ import annotations

import csv
from collections import Counter
from pathlib import Path
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

from eval.experiments.collect import collect_suite
from eval.experiments.runner import read_failure
from eval.records.runs_csv import (
    CRF_GRID,
    CRF_KEY,
    FAILED,
    FLOOR_COLUMNS,
    META,
    MISSING,
    SCORED,
    crf_csv_path,
    floors_csv_path,
    merge_rows,
    metric_keys,
    read_crf_csv,
    read_floors_csv,
    read_runs_csv,
    row_key,
    write_crf_csv,
    write_floors_csv,
    write_runs_csv,
)
from eval.records.suite import load_eval_suite
from m4dgs.core import io as mio


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
    """(runs rows, CRF rows, clip floors) of one suite's jobs under ROOT
    (eval.experiments.collect.collect_suite): every job, a scored one with its metrics, a job
    without metrics.json with status "failed" (and its error) when its run folder records a failed
    attempt, else "missing"; the floors {(scene, generator): {...}} of the scored runs' clips
    (clip_floors). Without `scenes`, only the scenes with at least one run folder of the suite (the
    subset that was run); with `scenes`, every job of those scenes. add_missing: first compute, for
    every scored run, the metrics its metrics.json lacks because an earlier version scored it
    (eval.experiments.score.add_missing_metrics; written into the run's metrics.json)."""
    s = load_eval_suite(suite)
    entries = collect_suite(suite, root, scenes, seeds=seeds)
    if scenes is None:  # scenes without any run folder were not run: not part of the subset
        ran = {e["scene"] for e in entries if Path(e["run_dir"]).exists()}
        entries = [e for e in entries if e["scene"] in ran]
    if add_missing:
        from eval.experiments.score import add_missing_metrics

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
            # preset when the run folder is gone (eval.experiments.campaign.recorded_runs)
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
    extra = _extra_columns([csv_path])
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
            curves.pop(row_key(r), None)
        for c in crfs:
            curves[row_key(c)] = {"crf": c["crf"], "log2_x": CRF_GRID, "learned": c["values"]}
        new_rows += rows
        failed = sum(r["status"] == FAILED for r in rows)
        summary[name] = {
            "scored": len(scored),
            "failed": failed,
            "missing": len(rows) - len(scored) - failed,
        }
    _write_merged(csv_path, merge_rows(old, new_rows), extra, curves, floors, summary, say)
    return summary


def _extra_columns(paths) -> List[str]:
    """The columns of existing runs CSVs that are neither META nor a metric of this version (an
    older file's), in order, once each: kept when the CSV is written again."""
    extra: List[str] = []
    for path in paths:
        if Path(path).exists():
            with open(path, newline="", encoding="utf-8") as f:
                head = next(csv.reader(f), [])
            extra += [c for c in head if c not in META and c not in metric_keys() + extra]
    return extra


def _write_merged(csv_path, merged, extra, curves, floors, summary, say) -> None:
    """Warn where a suite of `summary` mixes code, generator or host, then write the runs CSV,
    its CRF CSV and (when there are any) its clip floors."""
    _warn_mixed(merged, summary, csv_path, say)
    Path(csv_path).parent.mkdir(parents=True, exist_ok=True)
    write_runs_csv(csv_path, merged, extra)
    write_crf_csv(crf_csv_path(csv_path), curves)
    if floors:
        write_floors_csv(floors_csv_path(csv_path), floors)


def _warn_mixed(merged: List[dict], suites, csv_path, say) -> None:
    """Say where a suite's scored rows in `merged` come from more than one code version, clip
    generator version or host (runs whose row does not say, from older code, count as none)."""
    for name in suites:
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


def merge_csv(src, csv_path, suites: Optional[Sequence[str]] = None, log=None) -> dict:
    """Merge the rows of another runs CSV `src` (another machine's export, or a campaign's rows
    kept apart until it ends) into csv_path, with their CRF curves and clip floors, by the rules
    of `export`: a scored row replaces the row of the same (suite, scene, row, seed), a missing or
    failed one never replaces a scored one, other rows stay. A scored row's curve replaces the
    destination's (or removes it when src has none); a clip floor is added only where
    csv_path has none for that (scene, generator), so the floors of the clips already behind its
    rows stay. suites: only the rows of these suites (default: every suite in src).

    Returns {suite: {"scored", "failed", "missing"}} of the rows taken from src; raises
    InputError when src does not exist or has no row to take."""
    from m4dgs.core.errors import InputError

    say = log or (lambda s: None)
    if not Path(src).is_file():
        raise InputError(f"{src}: no such runs CSV")
    if Path(src).resolve() == Path(csv_path).resolve():
        raise InputError(f"{src}: the CSV to merge is the destination itself")
    new_rows = read_runs_csv(src)
    if suites:
        new_rows = [r for r in new_rows if r["suite"] in set(suites)]
    if not new_rows:
        want = f" of suite(s) {', '.join(suites)}" if suites else ""
        raise InputError(f"{src}: no rows{want} to merge")
    old = read_runs_csv(csv_path)
    extra = _extra_columns([csv_path, src])
    curves = read_crf_csv(crf_csv_path(csv_path))
    src_curves = read_crf_csv(crf_csv_path(src))
    summary: dict = {}
    for r in new_rows:
        c = summary.setdefault(r["suite"], {"scored": 0, "failed": 0, "missing": 0})
        status = r["status"] if r["status"] in (SCORED, FAILED) else MISSING
        c[{SCORED: "scored", FAILED: "failed", MISSING: "missing"}[status]] += 1
        if r["status"] == SCORED:
            curves.pop(row_key(r), None)
            if row_key(r) in src_curves:
                curves[row_key(r)] = src_curves[row_key(r)]
    floors = read_floors_csv(floors_csv_path(csv_path))
    for k, v in read_floors_csv(floors_csv_path(src)).items():
        floors.setdefault(k, v)
    _write_merged(csv_path, merge_rows(old, new_rows), extra, curves, floors, summary, say)
    return summary
