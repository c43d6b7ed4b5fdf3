"""A suite's calibration rows (`calibration: ROW` in a suite file, eval.records.suite): instead of
training, the row's 2D prediction is written and scored exactly like another method's frames
(eval.experiments.frames.score_frames), so that it lands in the tables beside the trained rows.

- copy-nearest, flow-merge: the temporal test frames (eval.calibration.frames.write_prediction),
  and the same images at the held-out views (a 2D row ignores the viewpoint).
- dibr: the held-out views only (eval.experiments.dibr_views.write_dibr_views, with the trainer's
  camera initialisation of the job's seed, taken from the suite's share folder when a trained row
  of the same clip and seed computed it); the temporal test frames' scores are None.

The prediction is written to a temporary folder beside the run folder and imported by
score_frames into the run folder's renders/, with the row's estimated response as
<run>/response.json. Like a trained run, a calibration run is done when its metrics.json exists.

copy-nearest and flow-merge predict the same frames for every trainer seed
(eval.calibration.SEED_FREE_ROWS): the runner makes seed 0's and gives the other seeds a copy of it
(copy_seed_free_run) instead of predicting and scoring the same frames again."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Optional

from eval.calibration import ROWS, TEMPORAL_ROWS
from m4dgs.clip import Clip
from m4dgs.core import io as mio


def make_calibration_run(
    row: str,
    name: str,
    clip_dir,
    run_dir,
    *,
    preset: str = "small",
    overrides: Optional[dict] = None,
    share_dir=None,
    lpips_weights=None,
) -> dict:
    """Write calibration row `row`'s prediction of the clip and score it into `run_dir` as table
    row `name` (metrics.json, run.json marked external); returns the metrics. `overrides` (the
    job's, e.g. its trainer seed) and `share_dir` reach dibr's camera initialisation."""
    if row not in ROWS:
        raise ValueError(f"unknown calibration row {row!r}; known: {', '.join(ROWS)}")
    from eval.experiments.frames import score_frames  # deferred: loads torch and the metrics

    run_dir = Path(run_dir)
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    if (run_dir / "renders").is_symlink():  # a copy's link (copy_seed_free_run): made here now
        (run_dir / "renders").unlink()
    with tempfile.TemporaryDirectory(dir=run_dir.parent, prefix=f".{run_dir.name}-pred-") as tmp:
        pred = Path(tmp) / "pred"
        if row in TEMPORAL_ROWS:
            from eval.calibration.frames import write_prediction

            write_prediction(Clip.open(clip_dir), pred, row)
            response = pred / "response.json"
        else:
            from eval.experiments.dibr_views import write_dibr_views

            write_dibr_views(
                clip_dir,
                pred / "views",
                preset=preset,
                work=Path(tmp) / "camera-init",
                overrides=dict(overrides or {}) or None,
                share_dir=share_dir,
                response_json=Path(tmp) / "response.json",
            )
            response = Path(tmp) / "response.json"
        _, metrics = score_frames(
            clip_dir, pred, name, run_dir, force=True, lpips_weights=lpips_weights
        )
        if response.exists():
            shutil.copyfile(response, run_dir / "response.json")
    # the preset of the suite's runs it is compared with (dibr: of its camera initialisation), so
    # that the runs CSV files the row with them
    info = mio.read_json(run_dir / "run.json")
    mio.write_json(run_dir / "run.json", {**info, "preset": preset, "calibration": row})
    metrics["run"] = {**(metrics.get("run") or {}), "preset": preset}
    mio.write_json(run_dir / "metrics.json", metrics)
    return metrics


def copy_seed_free_run(src, run_dir) -> dict:
    """Another trainer seed's run of a seed-free calibration row (eval.calibration.SEED_FREE_ROWS),
    from the finished run `src` of the same row and clip: run.json (with `same_as`, the source
    folder relative to this one), response.json and metrics.json copied, renders/ a relative link
    to the source's. metrics.json is written last, so an interrupted copy is made again. Returns
    the metrics."""
    src, run_dir = Path(src), Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    rel = Path("..") / src.name if src.parent == run_dir.parent else src.resolve()
    info = mio.read_json(src / "run.json")
    mio.write_json(run_dir / "run.json", {**info, "same_as": str(rel)})
    if (src / "response.json").exists():
        shutil.copyfile(src / "response.json", run_dir / "response.json")
    renders = run_dir / "renders"
    if renders.is_symlink():
        renders.unlink()
    elif renders.exists():
        shutil.rmtree(renders)
    if (src / "renders").exists():
        renders.symlink_to(rel / "renders", target_is_directory=True)
    metrics = mio.read_json(src / "metrics.json")
    mio.write_json(run_dir / "metrics.json", metrics)
    return metrics
