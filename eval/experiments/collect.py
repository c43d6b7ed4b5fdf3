"""The runs of a suite (its job list under an experiment root) or of a folder of runs, as the
entries that tables and the export read: {"scene", "row", "label", "seed", "run_dir", "clip_dir",
"metrics", "calibration" (the calibration row a 2D prediction is, eval.calibration.ROWS, or None
for a trained row), "same_every_seed" (a calibration row whose prediction no trainer seed
changes)}."""

from __future__ import annotations

import os
from pathlib import Path

from eval.calibration import SEED_FREE_ROWS
from eval.experiments.run_files import read_run_info
from eval.experiments.runner import job_list, seeds_present, split_run_name
from m4dgs.core import io as mio


# --------------------------------------------------------------------------------------------------
def collect_suite(suite, out, scenes=None, preset: str = "small", seeds=None) -> list:
    """Entries {"scene", "row", "label", "seed", "run_dir", "clip_dir", "metrics" (dict or None)} of
    a suite's jobs, for trainer seeds 0 .. seeds-1 (None: up to the largest seed with a run folder
    under OUT, for every row)."""
    if seeds is None:
        seeds = seeds_present(suite, out, preset, scenes)
    entries = []
    for j in job_list(suite, out, preset, scenes, seeds):
        mp = Path(j.run_dir) / "metrics.json"
        entries.append(
            {
                "scene": j.scene,
                "row": j.row,
                "label": j.label,
                "seed": j.seed,
                "run_dir": j.run_dir,
                "clip_dir": j.clip_dir,
                "metrics": mio.read_json(mp) if mp.exists() else None,
                "calibration": j.calibration,
                "same_every_seed": j.calibration in SEED_FREE_ROWS,
            }
        )
    return entries


def metrics_files(top) -> list:
    """The metrics.json files in TOP and every folder below it, sorted. Symbolic links to folders
    are followed (a run or scene folder linked into the tree counts like a real one); a folder
    reached twice (linked beside itself, or a link back up the tree) is read once, where the
    sorted walk meets it first."""
    found, seen = [], set()
    for d, dirs, files in os.walk(top, followlinks=True):
        st = os.stat(d)
        if (st.st_dev, st.st_ino) in seen:
            dirs.clear()
            continue
        seen.add((st.st_dev, st.st_ino))
        dirs.sort()
        if "metrics.json" in files and os.path.isfile(os.path.join(d, "metrics.json")):
            found.append(Path(d) / "metrics.json")
    return sorted(found)


def collect_runs_dir(runs_dir) -> list:
    """Entries of every run under RUNS_DIR with a metrics.json (metrics_files: linked run and
    scene folders included); rows = the variant names (run.json / metrics.json), or the run folder
    names where two runs of one scene and seed share a variant. A folder named <row>-seed-<n> is
    trainer seed n of <row> (m4dgs-eval run --seeds)."""
    entries = []
    for mp in metrics_files(runs_dir):
        rd = mp.parent
        m = mio.read_json(mp)
        run_meta = m.get("run") or {}
        info = read_run_info(rd)
        variant = run_meta.get("variant") or info.get("variant") or rd.name
        scene = run_meta.get("clip_name") or rd.parent.name
        row, seed = split_run_name(rd.name)
        entries.append(
            {
                "scene": scene,
                "row": row,
                "label": variant,
                "seed": seed,
                "run_dir": str(rd),
                "clip_dir": run_meta.get("clip"),
                "metrics": m,
                "calibration": info.get("calibration"),
                "same_every_seed": info.get("calibration") in SEED_FREE_ROWS,
            }
        )
    seen = {}
    for e in entries:
        seen.setdefault((e["scene"], e["label"], e["seed"]), []).append(e)
    if any(len(v) > 1 for v in seen.values()):
        for e in entries:
            e["label"] = e["row"]
    return entries
