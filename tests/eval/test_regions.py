"""`m4dgs-eval regions`: a run's squared error split over bright / dynamic / static pixels.

The masks are checked against hand-built answers, the per-region sums against the whole-frame error,
and an end-to-end split of a prediction with a known error against the scorer's own PSNRs (the
split's whole-frame PSNR must be the score's; the error must sit where it was put)."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from eval.cli import main
from eval.experiments.frames import score_frames
from eval.experiments.score import PSNR_CAP_DB
from eval.inspect.regions import (
    REGIONS,
    _pool,
    check_comparable,
    depth_edges,
    psnr_without,
    region_masks,
    region_sse,
    split_run,
)
from eval.metrics.image import masked_psnr
from m4dgs.clip import Clip, frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError


def test_masks_are_disjoint_cover_the_frame_and_follow_the_options():
    hdr = np.ones((7, 9, 3))
    hdr[3, 4, 1] = 50.0  # one lamp pixel (one channel is enough: max over channels)
    dyn = np.zeros((7, 9), bool)
    dyn[:, :3] = True
    dyn[3, 4] = True  # a lamp pixel marked dynamic goes to bright
    m = region_masks(hdr, dyn, bright_above=20.0)
    assert set(m) == set(REGIONS)
    total = sum(v.astype(int) for v in m.values())
    assert (total == 1).all()  # disjoint and covering
    assert m["bright"].sum() == 1 and m["bright"][3, 4]
    assert m["dynamic"].sum() == 21 and not m["dynamic"][3, 4]
    # grown by 2 four-connected steps: the diamond |dy| + |dx| <= 2 (13 pixels)
    m2 = region_masks(hdr, dyn, bright_above=20.0, dilate=2)
    yy, xx = np.mgrid[:7, :9]
    assert np.array_equal(m2["bright"], np.abs(yy - 3) + np.abs(xx - 4) <= 2)
    # the brightest fraction: ceil(0.05 * 63) = 4 pixels, ties at the cut included
    ramp = np.arange(63, dtype=float).reshape(7, 9)[..., None].repeat(3, -1)
    top = region_masks(ramp, None, bright_top=0.05)["bright"]
    assert top.sum() == 4 and top.ravel()[-4:].all()
    # neither option: no bright region; no mask: everything else static
    m0 = region_masks(hdr, None)
    assert not m0["bright"].any() and not m0["dynamic"].any() and m0["static"].all()
    with pytest.raises(ValueError):
        region_masks(hdr, dyn, bright_above=1.0, bright_top=0.1)
    with pytest.raises(ValueError):
        region_masks(hdr, np.zeros((3, 3), bool))


def test_region_sums_add_up_and_psnr_without_leaves_the_region_out():
    rng = np.random.default_rng(0)
    gt = rng.random((6, 8, 3))
    pred = gt.copy()
    m = region_masks(np.ones((6, 8, 3)), rng.random((6, 8)) < 0.3)
    err = rng.normal(0, 0.05, gt.shape)
    pred = np.clip(gt + err, 0, 1)
    sse = region_sse(pred, gt, m)
    assert sum(sse.values()) == pytest.approx(((pred - gt) ** 2).sum())
    d = (pred - gt)[~m["dynamic"]]
    assert psnr_without(pred, gt, m["dynamic"]) == pytest.approx(
        10 * math.log10(1.0 / (d**2).mean())
    )
    # an error only inside a region: leaving it out gives the cap; leaving out all: NaN
    p2 = np.where(m["dynamic"][..., None], gt + 0.1, gt)
    assert psnr_without(p2, gt, m["dynamic"]) == PSNR_CAP_DB
    assert math.isnan(psnr_without(p2, gt, np.ones((6, 8), bool)))


def test_levels_pool_like_the_scores():
    """Levels pool as ldr_oe_psnr does: a plain mean over levels for a synthetic clip, weighted by
    frame counts for a real clip (a test frame per captured exposure)."""

    def part(psnr, frames):
        return {
            "frames": frames,
            "pixels": {r: frames for r in REGIONS},
            "sse": {r: 1.0 for r in REGIONS},
            "psnr": psnr,
            "psnr_without": {r: psnr for r in REGIONS},
            "psnr_only": {r: psnr for r in REGIONS},
        }

    parts = [part(30.0, 1), part(20.0, 3)]
    assert _pool(parts, "observed")["psnr"] == pytest.approx(25.0)
    pooled = _pool(parts, "observed", weighted=True)
    assert pooled["psnr"] == pytest.approx(22.5) and pooled["frames"] == 4
    assert pooled["sse"]["static"] == 2.0 and pooled["psnr_without"]["bright"] == pytest.approx(
        22.5
    )


def _write_pred(clip: Clip, root, codes: int):
    """Test renders from the ground truth with +`codes` 8-bit codes (clipped) on every LDR level
    and x1.5 on the HDR frames, both inside the ground truth's dynamic mask only."""
    ex = clip.meta.exposures
    for g in clip.test_frames:
        dyn = clip.load_gt_dynamic_mask(g)[..., None]
        h = clip.load_gt_hdr(g)
        mio.write_exr(root / "test/hdr" / frame_name(g, "exr"), np.where(dyn, 1.5 * h, h))
        for lv in list(ex.observed) + list(ex.novel):
            gt = clip.load_gt_ldr(lv, g).astype(int)
            p = np.where(dyn, np.clip(gt + codes, 0, 255), gt).astype(np.uint8)
            mio.write_png(root / "test/ldr" / level_name(lv) / frame_name(g, "png"), p)
    return root


def test_split_of_a_known_error_matches_the_scorer_and_sits_in_the_dynamic_region(
    tiny_clip_realistic, tmp_path
):
    clip = Clip.open(tiny_clip_realistic)
    assert any(clip.load_gt_dynamic_mask(g).any() for g in clip.test_frames)
    pred = _write_pred(clip, tmp_path / "pred", codes=6)
    run_dir, m = score_frames(tiny_clip_realistic, pred, "dyn-err", tmp_path / "runs" / "dyn-err")
    res = split_run(run_dir, bright_top=0.01, dilate=1)
    d = res["domains"]
    # the whole-frame PSNRs are the scorer's (its code path: eval.experiments.score)
    assert d["LDR-OE"]["psnr"] == pytest.approx(m["ldr_oe_psnr"], abs=1e-9)
    assert d["LDR-NE"]["psnr"] == pytest.approx(m["ldr_ne_psnr"], abs=1e-9)
    assert d["hdr"]["psnr"] == pytest.approx(m["hdr_psnr"], abs=1e-9)
    for lv in clip.meta.exposures.observed:
        assert d[f"ldr {level_name(lv)}"]["psnr"] == pytest.approx(
            m["per_level"][level_name(lv)]["psnr"], abs=1e-9
        )
    n_px = clip.width * clip.height * len(clip.test_frames)
    for name, dom in d.items():
        assert sum(dom["pixels"].values()) == n_px * (
            len(clip.meta.exposures.observed)
            if name == "LDR-OE"
            else len(clip.meta.exposures.novel)
            if name == "LDR-NE"
            else 1
        )
        # the error was put in dynamic pixels only; bright ones taken out of them are error-free
        assert dom["sse"]["static"] == 0.0 and dom["sse"]["dynamic"] > 0
        if dom["sse"]["bright"] == 0.0:
            assert dom["psnr_without"]["dynamic"] == PSNR_CAP_DB
    # per frame of one level, from the frame's error sums: the PSNR with a region left out is the
    # masked PSNR of the rest, the PSNR of a region alone the masked PSNR of the region
    lv = clip.meta.exposures.observed[0]
    frames = []
    for g in clip.test_frames:
        mk = region_masks(
            clip.load_gt_hdr(g), clip.load_gt_dynamic_mask(g), bright_top=0.01, dilate=1
        )
        p = mio.read_png(run_dir / "renders/test/ldr" / level_name(lv) / frame_name(g, "png"))
        frames.append((p / 255.0, clip.load_gt_ldr(lv, g) / 255.0, mk))
    for r in ("bright", "dynamic", "static"):  # no edge region without --edges
        without = [psnr_without(p, gt, mk[r]) for p, gt, mk in frames]
        alone = [min(masked_psnr(p, gt, mk[r]), PSNR_CAP_DB) for p, gt, mk in frames if mk[r].any()]
        got = d[f"ldr {level_name(lv)}"]
        assert got["psnr_without"][r] == pytest.approx(
            float(np.mean([x for x in without if not math.isnan(x)])), abs=1e-6
        )
        assert got["psnr_only"][r] == pytest.approx(float(np.mean(alone)), abs=1e-6)
    # the brightest 1 % (grown by 1 px) is at least 1 % of every frame
    assert d["hdr"]["pixels"]["bright"] >= 0.01 * n_px
    assert d["LDR-OE"]["psnr_only"]["static"] == PSNR_CAP_DB  # no error put there
    # without a bright region the dynamic region alone is the scorer's dynamic-pixel PSNR
    d = split_run(run_dir)["domains"]
    assert d["LDR-OE"]["psnr_only"]["dynamic"] == pytest.approx(m["dyn_ldr_psnr"], abs=1e-9)
    assert d["LDR-OE"]["psnr_only"]["dynamic"] < PSNR_CAP_DB


def test_cli_prints_the_split_and_the_extra_error_over_a_reference(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    a, _ = score_frames(
        tiny_clip_realistic, _write_pred(clip, tmp_path / "pa", 2), "a", tmp_path / "runs" / "a"
    )
    b, _ = score_frames(
        tiny_clip_realistic, _write_pred(clip, tmp_path / "pb", 8), "b", tmp_path / "runs" / "b"
    )
    out = tmp_path / "split.json"
    res = CliRunner().invoke(
        main, ["regions", str(b), "--ref", str(a), "--bright-above", "20", "--json", str(out)]
    )
    assert res.exit_code == 0, res.output
    assert "against" in res.output and "| LDR-OE |" in res.output
    js = mio.read_json(out)
    # b's extra error over a is all in the dynamic region: 100 % of the change
    ra, rb = js["ref"]["domains"]["LDR-OE"], js["runs"][0]["domains"]["LDR-OE"]
    extra = {r: rb["sse"][r] - ra["sse"][r] for r in REGIONS}
    assert extra["static"] == 0.0 and extra["dynamic"] > 0
    bad = CliRunner().invoke(
        main, ["regions", str(b), "--bright-above", "20", "--bright-top", "0.1"]
    )
    assert bad.exit_code != 0 and "not both" in bad.output


def test_a_reference_of_another_scene_is_refused(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    check_comparable(clip, clip)
    other = tmp_path / "other"
    shutil.copytree(tiny_clip_realistic, other)
    meta = mio.read_json(other / "clip.json")
    meta["name"] = "another-scene"
    mio.write_json(other / "clip.json", meta)
    with pytest.raises(InputError, match="name"):
        check_comparable(clip, Clip.open(other))


def test_cli_without_a_clip_says_how_to_give_one(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    pred = _write_pred(clip, tmp_path / "pred", 1)  # a prediction folder: no run.json
    res = CliRunner().invoke(main, ["regions", str(pred)])
    assert res.exit_code != 0 and "run.json" in res.output and "clip folder" in res.output
    ok = CliRunner().invoke(main, ["regions", str(pred), "--clip", str(tiny_clip_realistic)])
    assert ok.exit_code == 0, ok.output
    assert "| ldr " in ok.output and "| hdr |" in ok.output


def test_a_missing_render_names_the_file(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    pred = _write_pred(clip, tmp_path / "pred", 1)
    g = clip.test_frames[0]
    (pred / "test/hdr" / frame_name(g, "exr")).unlink()
    with pytest.raises(InputError, match=frame_name(g, "exr")):
        split_run(pred, clip)


def test_region_pairs_difference_each_pair_as_the_scorer_does_with_a_t_interval(
    tiny_clip_realistic, tmp_path
):
    """`region-pairs` over a suite of existing clips: two seeds of rows a (2 codes of error in the
    moving pixels) and b (8, then 4 codes); each pair's differences are the scorer's
    (eval.experiments.score: ldr_oe_psnr, dyn_ldr_psnr), the mean's interval the Student-t one of
    two values, and a row without renders is named, not counted, a scene never run passed over."""
    import yaml

    from eval.experiments.runner import seed_run_name
    from eval.inspect.regions import suite_region_pairs

    clip = Clip.open(tiny_clip_realistic)
    scene = clip.meta.name
    shutil.copytree(tiny_clip_realistic, tmp_path / "clips" / scene)
    shutil.copytree(tiny_clip_realistic, tmp_path / "clips" / "zz-not-run")  # a scene never run
    suite = tmp_path / "mine.yaml"
    rows = [{"name": n, "variant": "full"} for n in ("a", "b", "c")]
    suite.write_text(
        yaml.safe_dump(
            {"name": "mine", "scenes": {"clips": "clips"}, "rows": rows, "reference": "a"}
        )
    )
    root = tmp_path / "root"
    scores = {}
    for row, seed, codes in (("a", 0, 2), ("a", 1, 2), ("b", 0, 8), ("b", 1, 4)):
        name = seed_run_name(row, seed)
        pred = _write_pred(clip, tmp_path / "pred" / name, codes)
        _, scores[row, seed] = score_frames(
            tiny_clip_realistic, pred, name, root / "runs/mine" / scene / name
        )
    (root / "runs/mine" / scene / "c").mkdir()  # a run not rendered yet
    js = tmp_path / "pairs.json"
    res = CliRunner().invoke(
        main,
        ["region-pairs", str(suite), "--root", str(root), "--ref", "a", "--rows", "b,c"]
        + ["--seeds", "2", "--json", str(js)],
    )
    assert res.exit_code == 0, res.output
    got = {(p["row"], p["seed"]): p["diffs"] for p in mio.read_json(js)["pairs"]}
    assert set(got) == {("b", 0), ("b", 1)}
    dyn = []
    for seed in (0, 1):
        d, a, b = got["b", seed], scores["a", seed], scores["b", seed]
        assert d["PSNR"] == pytest.approx(b["ldr_oe_psnr"] - a["ldr_oe_psnr"], abs=1e-9)
        assert d["dynamic alone"] == pytest.approx(b["dyn_ldr_psnr"] - a["dyn_ldr_psnr"], abs=1e-9)
        assert d["static alone"] == 0.0  # no error put in the static pixels of either run
        assert d["dynamic alone"] < 0
        dyn.append(d["dynamic alone"])
    # the mean of two pairs and its 95 % Student-t half-width: t(0.975, 1) = 12.7062 x |x1 - x2| / 2
    mean, half = sum(dyn) / 2, 12.7062047 * abs(dyn[0] - dyn[1]) / 2
    assert f"| Δ dynamic alone | {mean:+.2f} ± {half:.2f} (2) | 0 of 2 |" in res.output
    assert (
        "c - a, LDR-OE (dB)" in res.output and "no pair with both runs' test renders" in res.output
    )
    assert "zz-not-run" not in res.output  # passed over, not listed as missing
    assert (
        "without test renders (left out): " in res.output
        and str(root / "runs/mine" / scene / "c") in res.output
    )
    # no bright region: nothing of it, and no "w/o" rows (of two regions, one left out is the other)
    assert "bright" not in res.output.split("Regions:")[1].split("\n", 1)[1]
    assert "w/o" not in res.output
    lit = CliRunner().invoke(
        main,
        ["region-pairs", str(suite), "--root", str(root), "--ref", "a", "--rows", "b"]
        + ["--seeds", "2", "--bright-top", "0.01", "--domain", "hdr"],
    )
    assert lit.exit_code == 0, lit.output
    assert "b - a, hdr (dB)" in lit.output and "| Δ bright alone |" in lit.output
    assert "| Δ w/o bright |" in lit.output
    # a row the suite does not have, and a domain the runs lack, are named
    with pytest.raises(InputError, match="'nope'"):
        suite_region_pairs(str(suite), root, "a", ["nope"])
    with pytest.raises(InputError, match="no runs of suite"):
        suite_region_pairs(str(suite), tmp_path / "elsewhere", "a", ["b"])
    bad = CliRunner().invoke(
        main,
        ["region-pairs", str(suite), "--root", str(root), "--ref", "a", "--rows", "b"]
        + ["--domain", "LDR-XX"],
    )
    assert bad.exit_code != 0 and "LDR-XX" in bad.output


def test_region_pairs_against_another_suite_gives_the_difference_in_differences(
    tiny_clip_realistic, tmp_path
):
    """`region-pairs SUITE --against BASE:REF:ROW`: per (scene, seed) pair, (row - ref) of SUITE
    minus (ROW - REF) of BASE, checked against the scorer's own PSNRs of the four runs of each
    pair (ldr_oe_psnr, dyn_ldr_psnr); a seed only one suite has is left out; a malformed spec is
    refused."""
    import yaml

    from eval.experiments.runner import seed_run_name

    clip = Clip.open(tiny_clip_realistic)
    scene = clip.meta.name
    shutil.copytree(tiny_clip_realistic, tmp_path / "clips" / scene)
    root = tmp_path / "root"
    scores = {}
    # control: a (2 codes) / b (8, 4 codes) at seeds 0, 1; base: r (2) / s (5) at seed 0 only
    plan = {"control": [("a", 0, 2), ("a", 1, 2), ("b", 0, 8), ("b", 1, 4)]}
    plan["base"] = [("r", 0, 2), ("s", 0, 5)]
    for name, runs in plan.items():
        rows = [{"name": n, "variant": "full"} for n in dict.fromkeys(r for r, _, _ in runs)]
        doc = {
            "name": name,
            "scenes": {"clips": "clips"},
            "rows": rows,
            "reference": rows[0]["name"],
        }
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(doc))
        for row, seed, codes in runs:
            run = seed_run_name(row, seed)
            pred = _write_pred(clip, tmp_path / "pred" / name / run, codes)
            _, scores[name, row, seed] = score_frames(
                tiny_clip_realistic, pred, run, root / "runs" / name / scene / run
            )
    js = tmp_path / "changes.json"
    args = ["region-pairs", str(tmp_path / "control.yaml"), "--root", str(root), "--ref", "a"]
    args += ["--rows", "b", "--seeds", "2", "--json", str(js)]
    res = CliRunner().invoke(main, args + ["--against", f"{tmp_path / 'base.yaml'}:r:s"])
    assert res.exit_code == 0, res.output
    doc = mio.read_json(js)
    changes = {(c["row"], c["seed"]): c["diffs"] for c in doc["changes"]}
    assert set(changes) == {("b", 0)}  # the base has no seed 1
    sc = {k: v for k, v in scores.items() if k[2] == 0}
    want_psnr = (sc["control", "b", 0]["ldr_oe_psnr"] - sc["control", "a", 0]["ldr_oe_psnr"]) - (
        sc["base", "s", 0]["ldr_oe_psnr"] - sc["base", "r", 0]["ldr_oe_psnr"]
    )
    want_dyn = (sc["control", "b", 0]["dyn_ldr_psnr"] - sc["control", "a", 0]["dyn_ldr_psnr"]) - (
        sc["base", "s", 0]["dyn_ldr_psnr"] - sc["base", "r", 0]["dyn_ldr_psnr"]
    )
    assert changes["b", 0]["PSNR"] == pytest.approx(want_psnr, abs=1e-9)
    assert changes["b", 0]["dynamic alone"] == pytest.approx(want_dyn, abs=1e-9)
    assert want_dyn < 0  # 8 codes against 2 loses more than 5 against 2
    assert changes["b", 0]["static alone"] == 0.0
    assert "(b - a) - (" in res.output and ": s - r), LDR-OE (dB)" in res.output
    bad = CliRunner().invoke(main, args + ["--against", "base:r"])
    assert bad.exit_code != 0 and "SUITE:REF:ROW" in bad.output


def _edges_by_loops(z: np.ndarray, rel: float) -> np.ndarray:
    """The edge region spelt out pixel by pixel: a pixel is an edge when one of its 4-neighbours'
    depths is more than (1 + rel) times the nearer of the two (no depth: farther than all)."""
    h, w = z.shape
    far = np.where(np.isfinite(z) & (z > 0), z, np.inf)
    out = np.zeros((h, w), bool)
    for y in range(h):
        for x in range(w):
            for dy, dx in ((0, 1), (1, 0), (0, -1), (-1, 0)):
                v, u = y + dy, x + dx
                if 0 <= v < h and 0 <= u < w:
                    a, b = far[y, x], far[v, u]
                    if np.isinf(a) and np.isinf(b):
                        continue
                    if max(a, b) > (1 + rel) * min(a, b):
                        out[y, x] = True
    return out


def test_depth_edges_mark_both_sides_of_a_jump_and_the_rim_against_the_sky():
    z = np.ones((5, 6))
    z[:, 3:] = 2.0  # a jump between columns 2 and 3
    z[0, 0] = 1.04  # a 4 % step: not an edge at 5 %
    e = depth_edges(z, 0.05)
    assert e[:, 2].all() and e[:, 3].all() and e.sum() == 10
    z[4, 4:] = np.inf  # sky: its rim is an edge, sky beside sky is not
    z[3, 5] = 0.0
    e = depth_edges(z[..., None], 0.05)  # a depth channel axis is accepted
    assert np.array_equal(e, _edges_by_loops(z, 0.05))
    assert e[4, 3] and e[3, 4] and e[3, 5] and not e[4, 5]  # (4, 5): sky beside sky only
    rng = np.random.default_rng(1)
    zr = np.exp(rng.normal(0, 0.05, (9, 11)))
    assert np.array_equal(depth_edges(zr, 0.06), _edges_by_loops(zr, 0.06))
    with pytest.raises(ValueError):
        depth_edges(z, 0.0)


def test_edge_region_comes_after_bright_and_before_dynamic():
    hdr = np.ones((4, 6, 3))
    hdr[0, 2, 0] = 50.0
    z = np.ones((4, 6))
    z[:, 3:] = 3.0  # edge columns 2 and 3
    dyn = np.zeros((4, 6), bool)
    dyn[:, 2:5] = True
    m = region_masks(hdr, dyn, bright_above=20.0, depth=z, edges=0.05)
    assert set(m) == set(REGIONS)
    assert (sum(v.astype(int) for v in m.values()) == 1).all()
    assert m["bright"].sum() == 1 and m["edge"].sum() == 7 and not m["edge"][0, 2]
    assert np.array_equal(m["dynamic"], dyn & ~m["bright"] & ~m["edge"])
    assert m["dynamic"].sum() == 4  # column 4
    assert not region_masks(hdr, dyn, depth=z)["edge"].any()  # no edges without the option
    with pytest.raises(ValueError, match="depth"):
        region_masks(hdr, dyn, edges=0.05)


def test_an_error_on_the_depth_edges_lands_in_the_edge_region(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    ex = clip.meta.exposures
    pred = tmp_path / "pred"
    masks = {}
    for g in clip.test_frames:
        z = clip.load_gt_depth(g)
        z = z[..., 0] if z.ndim == 3 else z
        masks[g] = (
            _edges_by_loops(z, 0.05)
            & ~region_masks(clip.load_gt_hdr(g), None, bright_top=0.01)["bright"]
        )
        mio.write_exr(pred / "test/hdr" / frame_name(g, "exr"), clip.load_gt_hdr(g))
        for lv in list(ex.observed) + list(ex.novel):
            gt = clip.load_gt_ldr(lv, g).astype(int)
            p = np.where(masks[g][..., None], np.clip(gt + 6, 0, 255), gt).astype(np.uint8)
            mio.write_png(pred / "test/ldr" / level_name(lv) / frame_name(g, "png"), p)
    assert any(m.any() for m in masks.values())
    res = split_run(pred, clip, bright_top=0.01, edges=0.05)
    d = res["domains"]["LDR-OE"]
    assert d["sse"]["edge"] > 0
    assert d["sse"]["static"] == d["sse"]["dynamic"] == d["sse"]["bright"] == 0.0
    lv = ex.observed[0]
    alone = [
        min(
            masked_psnr(
                mio.read_png(pred / "test/ldr" / level_name(lv) / frame_name(g, "png")) / 255.0,
                clip.load_gt_ldr(lv, g) / 255.0,
                masks[g],
            ),
            PSNR_CAP_DB,
        )
        for g in clip.test_frames
        if masks[g].any()
    ]
    assert res["domains"][f"ldr {level_name(lv)}"]["psnr_only"]["edge"] == pytest.approx(
        float(np.mean(alone)), abs=1e-6
    )
    # the CLI names the region and prints its columns; a clip without depth is refused
    ok = CliRunner().invoke(
        main, ["regions", str(pred), "--clip", str(tiny_clip_realistic), "--edges", "0.05"]
    )
    assert ok.exit_code == 0, ok.output
    assert "edge = both pixels" in ok.output and "edge px %" in ok.output
    assert "bright px %" not in ok.output  # no bright option: no bright columns
    nodepth = tmp_path / "nodepth"
    shutil.copytree(tiny_clip_realistic, nodepth)
    shutil.rmtree(nodepth / "gt/depth")
    with pytest.raises(InputError, match="gt/depth"):
        split_run(pred, Clip.open(nodepth), edges=0.05)
