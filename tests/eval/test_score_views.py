"""score_run's whole-scene steps on fake run folders made from the tiny clip's ground truth, with
answers known in advance: a perfect prediction reads the PSNR cap (100 dB) at the test frames and at
the held-out views and no highlight error; HDR halved is off by exactly one stop with a peak ratio
of 0.5, and its view scores match numpy by hand; an all-black frame scores low under the p99
convention; a views-only folder has no test-frame metric; add_missing_metrics adds the new keys to
an older metrics.json without touching the rest. Then the tables: the `views` and `hdr-scene`
layouts, and the peak ratio shown in stops, its best the value closest to 0."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from eval.experiments.run_files import missing_renders
from eval.experiments.score import METRIC_KEYS, add_missing_metrics, score_run
from m4dgs.clip import Clip, frame_name, level_name
from m4dgs.core import io as mio

LUMA = np.array([0.2126, 0.7152, 0.0722])
NEW_KEYS = [
    "hdr_psnr_p99",
    "highlight_stops",
    "highlight_peak_ratio",
    "highlight_peak_ratio_resolved",
    "camera_deg_s",
    "emf",
]


def _fake_run(clip, run, *, test=True, views=True, hdr_scale=1.0, ldr_scale=1.0):
    """A run folder whose renders are the clip's ground truth (HDR x hdr_scale; view LDR codes x
    ldr_scale, rounded)."""
    levels = list(clip.meta.exposures.observed) + list(clip.meta.exposures.novel)
    for g in clip.test_frames:
        if test:
            h = (clip.load_gt_hdr(g) * hdr_scale).astype(np.float32)
            mio.write_exr(run / "renders/test/hdr" / frame_name(g, "exr"), h)
            for lv in levels:
                p = run / "renders/test/ldr" / level_name(lv) / frame_name(g, "png")
                p.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy(clip.root / "gt/ldr" / level_name(lv) / frame_name(g, "png"), p)
        for v in clip.view_names() if views else []:
            base = run / "renders/views" / v
            h = (clip.load_view_hdr(v, g) * hdr_scale).astype(np.float32)
            mio.write_exr(base / "hdr" / frame_name(g, "exr"), h)
            for lv in levels:
                img = clip.load_view_ldr(v, lv, g).astype(np.float64)
                mio.write_png(
                    base / "ldr" / level_name(lv) / frame_name(g, "png"),
                    np.round(img * ldr_scale).astype(np.uint8),
                )
    run.mkdir(parents=True, exist_ok=True)
    return run


def _score(clip, run):
    return score_run(run, clip=clip, fps=False, model=False, render_missing=False)


def _p99_psnr_by_hand(pred, gt):
    s = np.percentile(gt @ LUMA, 99)

    def t(x):
        return np.log(1 + 5000 * np.maximum(x, 0) / s) / np.log(5001)

    mse = np.mean((t(pred.astype(np.float64)) - t(gt.astype(np.float64))) ** 2)
    return min(10 * np.log10(1 / mse), 100.0)


def test_a_perfect_prediction_reads_the_cap_everywhere(tiny_clip_oracle, tmp_path):
    clip = Clip.open(tiny_clip_oracle)
    assert clip.view_names() == ["small", "medium", "large"]
    m = _score(clip, _fake_run(clip, tmp_path / "run"))
    assert m["ldr_oe_psnr"] == 100.0 and m["hdr_psnr_p99"] == 100.0
    assert m["highlight_stops"] == 0.0 and m["highlight_peak_ratio"] == 1.0
    assert m["highlight_peak_ratio_resolved"] == 1.0
    assert m["highlight_pixels"] > 0  # the tiny clip has a few (frames 1 and 5)
    assert 0 < m["highlight_pixels_resolved"] <= m["highlight_pixels"]
    for k in ("nv_ldr_oe_mpsnr", "nv_ldr_ne_psnr", "nv_hdr_mpsnr", "nv_hdr_psnr_p99"):
        assert m[k] == 100.0, k
    assert m["nv_large_ldr_oe_mpsnr"] == 100.0 and m["nv_small_ldr_oe_mssim"] == pytest.approx(1)
    assert 0 < m["nv_covisible"] <= 1
    cm = clip.meta.gt["camera_motion"]
    assert m["camera_deg_s"] == cm["camera_deg_s"] and m["emf"] == cm["emf"]
    for c in ("nv_views", "nv_masked", "hdr_psnr_p99", "highlight_stops", "camera_motion"):
        assert c in m["conventions"], c
    assert set(NEW_KEYS + ["nv_ldr_oe_mpsnr", "nv_covisible"]) <= set(METRIC_KEYS)
    # the file on disk says the same
    assert mio.read_json(tmp_path / "run/metrics.json")["nv_hdr_psnr_p99"] == 100.0


def test_halved_hdr_and_darkened_views_match_by_hand(tiny_clip_oracle, tmp_path):
    clip = Clip.open(tiny_clip_oracle)
    m = _score(clip, _fake_run(clip, tmp_path / "run", hdr_scale=0.5, ldr_scale=0.5))
    # every highlight pixel is exactly one stop too dark, and so is the peak
    assert m["highlight_stops"] == pytest.approx(1.0, abs=1e-6)
    assert m["highlight_peak_ratio"] == pytest.approx(0.5, abs=1e-6)
    assert m["highlight_peak_ratio_resolved"] == pytest.approx(0.5, abs=1e-6)
    assert 10 < m["hdr_psnr_p99"] < 100
    by_view = {}
    for v in clip.view_names():
        by_view[v] = np.mean(
            [
                _p99_psnr_by_hand(clip.load_view_hdr(v, g) * 0.5, clip.load_view_hdr(v, g))
                for g in clip.test_frames
            ]
        )
    assert m["nv_large_hdr_psnr_p99"] == pytest.approx(by_view["large"], rel=1e-6)
    assert m["nv_hdr_psnr_p99"] == pytest.approx(np.mean(list(by_view.values())), rel=1e-6)
    # LDR-OE over the co-visible pixels of the small view: MSE over them, per frame and level
    vals = []
    for g in clip.test_frames:
        covis = clip.load_view_covis("small", g)
        for lv in clip.meta.exposures.observed:
            gt = clip.load_view_ldr("small", lv, g).astype(np.float64)
            pred = np.round(gt * 0.5)
            mse = np.mean(((pred - gt) / 255.0)[covis] ** 2)
            vals.append(min(10 * np.log10(1 / mse), 100.0) if mse > 0 else 100.0)
    assert m["nv_small_ldr_oe_mpsnr"] == pytest.approx(np.mean(vals), rel=1e-6)
    assert m["nv_ldr_oe_mpsnr"] < 100


def test_an_all_black_frame_scores_low_under_the_p99_convention(tiny_clip_oracle, tmp_path):
    clip = Clip.open(tiny_clip_oracle)
    m = _score(clip, _fake_run(clip, tmp_path / "run", hdr_scale=0.0, views=False))
    assert m["hdr_psnr_p99"] < 15
    assert m["highlight_stops"] > 10  # log2 of 1e-12 against the truth


def test_a_views_only_prediction_has_no_test_frame_metric(tiny_clip_oracle, tmp_path):
    clip = Clip.open(tiny_clip_oracle)
    m = _score(clip, _fake_run(clip, tmp_path / "run", test=False))
    for k in ("ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr", "hdr_psnr_p99", "highlight_stops"):
        assert m[k] is None, k
    assert m["dyn_ldr_psnr"] is None and m["per_level"] == {}
    assert m["nv_ldr_oe_mpsnr"] == 100.0 and m["nv_medium_hdr_psnr"] == 100.0


def test_test_frames_without_views_give_nv_none(tiny_clip_oracle, tmp_path):
    clip = Clip.open(tiny_clip_oracle)
    run = _fake_run(clip, tmp_path / "run", views=False)
    m = _score(clip, run)
    assert m["ldr_oe_psnr"] == 100.0
    nv = [k for k in m if k.startswith("nv_")]
    assert "nv_large_ldr_oe_mpsnr" in nv and "nv_covisible" in nv
    assert all(m[k] is None for k in nv)
    # an m4dgs run would have them rendered: the render list names every view frame
    levels = len(clip.meta.exposures.observed) + len(clip.meta.exposures.novel)
    miss = missing_renders(run, clip)
    views = [p for p in miss if "views" in p.parts]
    assert len(views) == len(clip.view_names()) * len(clip.test_frames) * (1 + levels)


def test_add_missing_metrics_adds_the_new_keys_to_an_older_file(tiny_clip_oracle, tmp_path):
    clip = Clip.open(tiny_clip_oracle)
    run = _fake_run(clip, tmp_path / "run")
    m = _score(clip, run)
    old = {k: v for k, v in m.items() if k not in NEW_KEYS and not k.startswith("nv_")}
    old["ldr_oe_psnr"] = 12.5  # a value the addition must leave alone
    old["conventions"] = {"psnr": m["conventions"]["psnr"]}
    mio.write_json(run / "metrics.json", old)
    got, added = add_missing_metrics(run, clip=clip)
    assert set(NEW_KEYS + ["nv_ldr_oe_mpsnr", "nv_large_ldr_oe_mpsnr"]) <= set(added)
    assert got["hdr_psnr_p99"] == 100.0 and got["nv_ldr_oe_mpsnr"] == 100.0
    assert got["highlight_peak_ratio"] == 1.0 and got["emf"] == m["emf"]
    assert got["highlight_peak_ratio_resolved"] == 1.0
    assert got["ldr_oe_psnr"] == 12.5 and "nv_masked" in got["conventions"]
    assert mio.read_json(run / "metrics.json")["nv_hdr_psnr_p99"] == 100.0
    assert add_missing_metrics(run, clip=clip)[1] == []

    # a run without view renders yet: the views' keys stay out (added once rendered)
    shutil.rmtree(run / "renders/views")
    mio.write_json(run / "metrics.json", old)
    got, added = add_missing_metrics(run, clip=clip)
    assert "hdr_psnr_p99" in added and not any(k.startswith("nv_") for k in got)


def test_the_views_and_hdr_scene_layouts():
    from eval.conventions import all_conventions
    from eval.records.suite import TableDef, table_spec
    from eval.tables import render_markdown

    rows = [
        {"method": "a", "scene": "s", "nv_ldr_oe_mpsnr": 21.0, "nv_large_ldr_oe_mpsnr": 18.5},
        {"method": "b", "scene": "s", "nv_ldr_oe_mpsnr": 23.0, "nv_large_ldr_oe_mpsnr": 17.25},
    ]
    md = render_markdown(
        rows, table_spec(TableDef("Views", "views")), conventions=all_conventions()
    )
    assert "Views LDR-OE mPSNR↑" in md and "Views LDR-OE large mPSNR↑" in md
    assert "| a | n/a | 21.00 |" in md and "**23.00**" in md and "**18.50**" in md
    assert "co-visible pixels" in md  # the masked scores' convention under the table

    rows = [
        {"method": m, "scene": "s", "highlight_peak_ratio": r, "highlight_stops": e}
        for m, r, e in (("dark", 0.5, 1.0), ("near", 1.2, 0.3), ("hot", 3.0, 1.6))
    ]
    md = render_markdown(rows, table_spec(TableDef("Scene HDR", "hdr-scene")))
    assert "HDR peak (stops)→0" in md and "HDR highlight err (stops)↓" in md
    # the ratio in stops (log2 0.5 = -1, log2 1.2 = 0.26, log2 3 = 1.58); the best is the one
    # closest to 0, not the smallest
    assert "| 1.000 | -1.00 |" in md and "**0.26**" in md and "| 1.600 | 1.58 |" in md
    assert "**-1.00**" not in md and "**0.300**" in md


def test_peak_ratio_aggregates_in_stops():
    """Two seeds at half and twice the truth's peak: in stops their mean is 0 (geometric mean 1),
    where an arithmetic mean of the ratios would read 1.25; the paired difference to a reference
    run that is right is the log ratio, and a runaway run does not set the mean alone."""
    from eval.records.suite import TableDef, table_spec
    from eval.tables import aggregate, cell_stats

    spec = table_spec(TableDef("Scene HDR", "hdr-scene"))
    spec.reference, spec.intervals = "ref", True
    rows = [
        {"method": "a", "scene": "s", "seed": 0, "highlight_peak_ratio": 0.5},
        {"method": "a", "scene": "s", "seed": 1, "highlight_peak_ratio": 2.0},
        {"method": "b", "scene": "s", "seed": 0, "highlight_peak_ratio": 1.0},
        {"method": "b", "scene": "s", "seed": 1, "highlight_peak_ratio": 64.0},
        {"method": "ref", "scene": "s", "seed": 0, "highlight_peak_ratio": 1.0},
        {"method": "ref", "scene": "s", "seed": 1, "highlight_peak_ratio": 1.0},
        {"method": "gone", "scene": "s", "seed": 0, "highlight_peak_ratio": 0.0},
    ]
    agg = {a["method"]: a for a in aggregate(rows, spec)}
    assert agg["a"]["highlight_peak_ratio"] == pytest.approx(0.0)
    assert agg["b"]["highlight_peak_ratio"] == pytest.approx(3.0)  # log2(sqrt(64)), not 32.5
    assert agg["gone"]["highlight_peak_ratio"] is None  # a zero peak has no log: n/a
    col = [c.key for c in spec.columns].index("highlight_peak_ratio")
    order = [a["method"] for a in aggregate(rows, spec)]
    stats = cell_stats(rows, spec)
    d = stats[order.index("b")][col].diff
    assert d.mean == pytest.approx(3.0) and d.n == 2
    assert stats[order.index("a")][col].ci.mean == pytest.approx(0.0)
    # the input rows are not changed
    assert rows[1]["highlight_peak_ratio"] == 2.0
