"""bench/hdr_error_bands.py on frames whose error is placed by construction: all of it in the
brightest 1 %, none of it there, a global scale, and on a run folder of a tiny clip."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest


def _frame(seed=0):
    rng = np.random.default_rng(seed)
    return (rng.lognormal(0.0, 1.5, size=(40, 50, 1)) * np.ones((1, 1, 3))).astype(np.float32)


def test_error_in_the_highlights_only(load_bench):
    b = load_bench("hdr_error_bands")
    gt = _frame()
    peak = gt.max(-1)
    top = peak >= np.quantile(peak, 0.99)
    pred = gt.copy()
    pred[top] *= 0.5  # only the brightest 1 % wrong
    r = b.error_bands(pred, gt, saturation_exposure=1e9, dt_min=0.125)
    assert r["sq_err"] > 0 and r["sq_err_top1"] == pytest.approx(r["sq_err"])
    assert r["sq_err_never"] == 0 and r["n_never"] == 0
    assert r["mid_ratio"] == pytest.approx(1.0)
    # the pixels past the response's saturation at the shortest exposure are the never-observed ones
    sat = float(np.quantile(peak, 0.99)) * 0.125
    r2 = b.error_bands(pred, gt, saturation_exposure=sat, dt_min=0.125)
    assert r2["n_never"] == 3 * int((peak * 0.125 > sat).sum()) > 0
    assert r2["sq_err_never"] <= r2["sq_err_top1"] + 1e-12


def test_global_scale_shows_in_the_mid_tones(load_bench):
    b = load_bench("hdr_error_bands")
    gt = _frame(1)
    r = b.error_bands(gt * 1.1, gt, saturation_exposure=1e9, dt_min=0.125)
    assert r["mid_ratio"] == pytest.approx(1.1, rel=1e-5)
    # the same PSNR as the metric on one image (eval.metrics.hdr_psnr)
    from eval.metrics import hdr_psnr

    assert -10 * np.log10(r["sq_err"] / r["n"]) == pytest.approx(hdr_psnr(gt * 1.1, gt), abs=1e-6)


def test_run_bands_on_a_run_folder(tiny_clip_oracle, tmp_path, load_bench):
    """A run folder whose test renders are the ground truth: no error anywhere, scale 1."""
    from m4dgs.clip import Clip
    from m4dgs.core import io as mio

    b = load_bench("hdr_error_bands")
    clip = Clip.open(tiny_clip_oracle)
    run = tmp_path / "run"
    (run / "renders" / "test" / "hdr").mkdir(parents=True)
    for g in clip.test_frames:
        mio.write_exr(run / "renders" / "test" / "hdr" / f"{g:05d}.exr", clip.load_gt_hdr(g))
    (run / "run.json").write_text(json.dumps({"clip_abs": str(Path(tiny_clip_oracle).resolve())}))
    r = b.run_bands(run)
    assert r["frames"] == len(clip.test_frames) and r["pooled_hdr_psnr"] == float("inf")
    assert r["share_top1"] == 0 and r["mid_tone_scale"] == pytest.approx(1.0)
    assert r["mse_top1"] == 0 and r["mse_rest"] == 0
    with pytest.raises(ValueError, match="no run.json"):
        b.run_bands(tmp_path)
    with pytest.raises(ValueError, match="no renders"):
        (tmp_path / "empty" / "renders" / "test" / "hdr").mkdir(parents=True)
        (tmp_path / "empty" / "run.json").write_text((run / "run.json").read_text())
        b.run_bands(tmp_path / "empty")


def test_reference_ratios_pair_scene_and_seed(load_bench):
    """--ref: each run's error beside the reference row's run of the same scene and seed."""
    b = load_bench("hdr_error_bands")

    def row(path, top1, rest):
        return {"run": path, "mse_top1": top1, "mse_rest": rest}

    rows = [
        row("R/runs/s/scene-a/alternating-seed-0", 2.0, 10.0),
        row("R/runs/s/scene-a/alternating-seed-1", 4.0, 10.0),
        row("R/runs/s/scene-b/alternating-seed-0", 1.0, 5.0),
        row("R/runs/s/scene-a/random-values-seed-1", 6.0, 9.0),
        row("R/runs/s/scene-b/random-values-seed-0", 3.0, 5.0),
    ]
    out = {r["run"].split("/", 3)[-1]: r for r in b.reference_ratios(rows, "alternating")}
    assert set(out) == {"scene-a/random-values-seed-1", "scene-b/random-values-seed-0"}
    a = out["scene-a/random-values-seed-1"]
    assert a["ref"].endswith("scene-a/alternating-seed-1")  # its own seed, not seed 0
    assert (a["top1"], a["rest"]) == (pytest.approx(1.5), pytest.approx(0.9))
    assert (out["scene-b/random-values-seed-0"]["top1"]) == pytest.approx(3.0)
    with pytest.raises(ValueError, match="no alternating-seed-1 run of scene-b"):
        b.reference_ratios(
            rows + [row("R/runs/s/scene-b/random-values-seed-1", 1, 1)], "alternating"
        )
    # seed 0's folder is the row's name alone (eval.experiments.runner.seed_run_name), any other
    # name too
    assert b.run_key("R/runs/s/scene-a/latest") == ("scene-a", "latest", 0)
    plain = [
        row("R/runs/s/scene-c/alternating", 2.0, 4.0),
        row("R/runs/s/scene-c/random-values", 5.0, 2.0),
    ]
    (c,) = b.reference_ratios(plain, "alternating")
    assert c["ref"].endswith("scene-c/alternating") and c["top1"] == pytest.approx(2.5)
