"""The runs CSV (results/runs.csv): one row per (suite, scene, row, seed) with the run's metrics,
its CRF-curve and clip-floor companions (<stem>-crf.csv, <stem>-floors.csv); reading, writing and
merging them. The rows come from run folders through eval.experiments.export."""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Dict, List, Optional, Sequence

from eval.records.suite import metric_columns
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
    "nv-main",
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
    """The metric columns of the CSV: every key a suite table may show (eval.records.suite)."""
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


def row_key(r: dict) -> tuple:
    return (r["suite"], r["scene"], r["row"], int(r["seed"]))


def read_runs_csv(path) -> List[dict]:
    """Rows of a runs CSV: metric cells as floats (None when empty), seed as int, the rest text;
    none for a missing or empty file. A header that lacks a key column (suite, scene, row, seed)
    or status is not a runs CSV's: InputError naming the file and the missing columns."""
    from m4dgs.core.errors import InputError

    p = Path(path)
    if not p.exists():
        return []
    with open(p, newline="", encoding="utf-8") as f:
        rd = csv.DictReader(f)
        if rd.fieldnames is None:
            return []
        lacking = [k for k in KEY + ("status",) if k not in rd.fieldnames]
        if lacking:
            raise InputError(
                f"{p}: not a runs CSV (its header lacks the column(s) {', '.join(lacking)}; "
                "a runs CSV is written by `m4dgs-eval suite export`)"
            )
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
            out[row_key(d)] = {
                "crf": d["crf"],
                "log2_x": grid,
                "learned": [parse_number(v) for v in r[n:]],
            }
    return out


def _sorted(rows: List[dict]) -> List[dict]:
    return sorted(rows, key=row_key)


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
    idx = {row_key(r): r for r in old}
    for r in new:
        k = row_key(r)
        was = idx[k].get("status") if k in idx else None
        if r["status"] != SCORED and was == SCORED:
            continue
        if r["status"] == MISSING and was == FAILED:
            continue
        idx[k] = r
    return _sorted(list(idx.values()))


def one_line(text: str, limit: int = 240) -> str:
    """One line of at most `limit` characters (an error message on the page)."""
    t = " ".join(str(text).split())
    return t if len(t) <= limit else t[: limit - 3] + "..."
