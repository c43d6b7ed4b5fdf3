"""`eval score-frames`: another method's frames scored without an m4dgs model. Predictions are made
from the clip's ground truth in every accepted file format, with metric values known in advance
(identical images: the PSNR cap; a one-code-value error everywhere: 20 log10 255 dB; the
ground-truth HDR sequence: the HDR-TAE floor benchgen recorded when it rendered the clip)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile
from click.testing import CliRunner

from benchgen.cli import main as benchgen_main
from eval.cli import main
from eval.experiments.frames import (
    import_frames,
    plan_inputs,
    read_image,
    score_frames,
    scored_clip,
)
from eval.experiments.score import PSNR_CAP_DB
from m4dgs.cli import main as m4dgs_main
from m4dgs.clip import Clip, frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError


def _png16(path, img8):
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), (img8.astype(np.uint16) * 257)[..., ::-1])


def make_pred(clip: Clip, root, train: bool = True):
    """A prediction folder from the ground truth: observed level 1 as 16-bit PNG, level 2 as float
    EXR, novel levels as 8-bit PNG with the lowest bit flipped (|error| = 1 code everywhere)."""
    ex = clip.meta.exposures
    obs, nov = list(ex.observed), list(ex.novel)
    for g in clip.test_frames:
        mio.write_exr(root / "test/hdr" / frame_name(g, "exr"), clip.load_gt_hdr(g))
        for i, lv in enumerate(obs):
            gt = clip.load_gt_ldr(lv, g)
            d = root / "test/ldr" / level_name(lv)
            if i == 0:
                _png16(d / frame_name(g, "png"), gt)
            else:
                mio.write_exr(d / frame_name(g, "exr"), gt.astype(np.float32) / 255.0)
        for lv in nov:
            mio.write_png(
                root / "test/ldr" / level_name(lv) / frame_name(g, "png"),
                clip.load_gt_ldr(lv, g) ^ 1,
            )
    if train:
        for g in clip.train_frames:
            mio.write_exr(root / "train/hdr" / frame_name(g, "exr"), clip.load_gt_hdr(g))
            p = root / "train/ldr" / frame_name(g, "tif")
            p.parent.mkdir(parents=True, exist_ok=True)
            tifffile.imwrite(p, clip.load_ldr(g))
    return root


def test_frames_from_the_ground_truth_score_the_known_values(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    pred = make_pred(clip, tmp_path / "pred")
    out = tmp_path / "runs" / "gt-copy"
    run_dir, m = score_frames(tiny_clip_realistic, pred, "gt-copy", out)
    assert (
        run_dir == out
        and json.loads((out / "metrics.json").read_text())["hdr_psnr"] == m["hdr_psnr"]
    )
    ex = clip.meta.exposures
    for lv in ex.observed:
        assert m["per_level"][level_name(lv)]["psnr"] == PSNR_CAP_DB
    one_code = 20 * math.log10(255.0)
    for lv in ex.novel:
        assert m["per_level"][level_name(lv)]["psnr"] == pytest.approx(one_code, abs=1e-6)
    assert m["ldr_oe_psnr"] == PSNR_CAP_DB and m["ldr_ne_psnr"] == pytest.approx(one_code, abs=1e-6)
    assert m["ldr_oe_ssim"] == pytest.approx(1.0) and m["ldr_train_psnr"] == PSNR_CAP_DB
    assert m["hdr_psnr"] == PSNR_CAP_DB and m["hdr_ssim"] == pytest.approx(1.0)
    assert m["hdr_train_psnr"] == PSNR_CAP_DB
    assert m["hdr_tae"] == pytest.approx(clip.meta.gt["hdr_tae_floor"], rel=1e-4)
    # the truth scored against itself: HDR-TAE is the clip's floor, HDR-TCE is zero
    assert m["hdr_tae"] > 0.01 and m["hdr_tce"] == pytest.approx(0.0, abs=1e-6)
    # nothing a model would give
    assert m["fps"] is None and m["crf_error"] is None and m["num_gaussians"] is None
    inp = m["options"]["input"]
    n_test = len(clip.test_frames)
    assert inp["ldr_uint16"] == n_test and inp["ldr_float"] == n_test * (len(ex.observed) - 1)
    assert inp["ldr_uint8"] == n_test * len(ex.novel) + len(clip.train_frames)
    assert inp["hdr_negative"] == 0 and m["run"]["external"] is True

    # the score folder joins `eval table RUNS_DIR` under its name
    res = CliRunner().invoke(
        main, ["table", "--columns", "all", str(tmp_path / "runs"), "--format", "csv"]
    )
    assert res.exit_code == 0, res.output
    assert "gt-copy" in res.output


def test_test_frames_alone_score_without_training_metrics(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    pred = make_pred(clip, tmp_path / "pred", train=False)
    _, m = score_frames(tiny_clip_realistic, pred, "test-only", tmp_path / "s")
    assert m["hdr_psnr"] == PSNR_CAP_DB
    assert m["hdr_tae"] is None and m["ldr_train_psnr"] is None and m["hdr_train_psnr"] is None


def test_missing_frames_are_listed_in_one_error(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    pred = make_pred(clip, tmp_path / "pred")
    g0, g1 = clip.test_frames[:2]
    lv = level_name(clip.meta.exposures.novel[0])
    gone = [
        pred / "test/hdr" / frame_name(g0, "exr"),
        pred / "test/ldr" / lv / frame_name(g0, "png"),
        pred / "test/ldr" / lv / frame_name(g1, "png"),
        pred / "train/hdr" / frame_name(clip.train_frames[3], "exr"),  # optional set given in part
    ]
    for p in gone:
        p.unlink()
    with pytest.raises(InputError, match=r"4 file\(s\) missing") as e:
        score_frames(tiny_clip_realistic, pred, "broken", tmp_path / "s")
    for p in gone:
        assert str(p.with_suffix("")) in str(e.value)
    assert not (tmp_path / "s" / "metrics.json").exists()


def test_bad_inputs_name_the_file(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    pred = make_pred(clip, tmp_path / "pred", train=False)
    g = clip.test_frames[0]
    p = pred / "test/hdr" / frame_name(g, "exr")
    mio.write_exr(p, np.zeros((clip.height + 1, clip.width, 3), np.float32))
    with pytest.raises(InputError, match=f"{p}.*pixels"):
        score_frames(tiny_clip_realistic, pred, "bad-size", tmp_path / "a")
    x = clip.load_gt_hdr(g).copy()
    x[0, 0, 0] = np.nan
    mio.write_exr(p, x)
    with pytest.raises(InputError, match=f"{p}: NaN"):
        score_frames(tiny_clip_realistic, pred, "nan", tmp_path / "b")
    with pytest.raises(InputError, match="--name"):
        score_frames(tiny_clip_realistic, pred, "a/b", tmp_path / "c")


def test_read_image_keeps_16_bit_and_channel_names(tmp_path):
    rng = np.random.default_rng(0)
    a = rng.integers(0, 65536, (5, 7, 3), dtype=np.uint16)
    cv2.imwrite(str(tmp_path / "a.png"), a[..., ::-1])
    px, kind = read_image(tmp_path / "a.png")
    assert kind == "uint16" and px.dtype == np.uint16 and np.array_equal(px, a)
    grey = rng.integers(0, 256, (5, 7), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "g.png"), grey)
    px, kind = read_image(tmp_path / "g.png")
    assert kind == "uint8" and np.array_equal(px, np.repeat(grey[..., None], 3, -1))


def test_cli_score_frames_and_force(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    pred = make_pred(clip, tmp_path / "pred", train=False)
    args = ["score-frames", "--clip", str(tiny_clip_realistic), "--pred", str(pred)]
    args += ["--name", "mine", "--out", str(tmp_path / "s")]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    assert json.loads(r.output.strip().splitlines()[-1])["hdr_psnr"] == PSNR_CAP_DB
    r = CliRunner().invoke(main, args)
    assert r.exit_code != 0 and "--force" in r.output
    r = CliRunner().invoke(main, args + ["--force"])
    assert r.exit_code == 0, r.output


# --------------------------------------------------------------------------------------------------
# held-out views (DIR/views/<view>/...)
# --------------------------------------------------------------------------------------------------
def write_views(clip: Clip, root, views=None):
    """Every test frame of each view from the view's ground truth: HDR as EXR, LDR at every level as
    the ground-truth PNG bytes."""
    for v in views or clip.view_names():
        src = clip.root / "gt/views" / v
        for g in clip.test_frames:
            mio.write_exr(
                root / "views" / v / "hdr" / frame_name(g, "exr"), clip.load_view_hdr(v, g)
            )
            for lv in clip.meta.test_levels_of(g):
                rel = Path("ldr") / level_name(lv) / frame_name(g, "png")
                (root / "views" / v / rel).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(src / rel, root / "views" / v / rel)
    return root


def test_views_land_at_their_frame_and_level(tiny_clip_oracle, tmp_path):
    clip = Clip.open(tiny_clip_oracle)
    views = clip.view_names()
    assert len(views) == 3 and len(clip.test_frames) == 4
    pred = write_views(clip, make_pred(clip, tmp_path / "pred", train=False))
    # one pair of frames swapped at one level of one view
    v, lv = views[1], level_name(clip.meta.exposures.novel[0])
    g0, g1 = clip.test_frames[:2]
    a, b = (pred / "views" / v / "ldr" / lv / frame_name(g, "png") for g in (g0, g1))
    ab, bb = a.read_bytes(), b.read_bytes()
    a.write_bytes(bb)
    b.write_bytes(ab)
    out = tmp_path / "s"
    _, m = score_frames(tiny_clip_oracle, pred, "with-views", out)
    r = out / "renders/views"
    n_levels = len(clip.meta.exposures.observed) + len(clip.meta.exposures.novel)
    for view in views:
        for g in clip.test_frames:
            np.testing.assert_array_equal(
                mio.read_exr(r / view / "hdr" / frame_name(g, "exr")), clip.load_view_hdr(view, g)
            )
            for level in clip.meta.exposures.observed + clip.meta.exposures.novel:
                got = mio.read_png(r / view / "ldr" / level_name(level) / frame_name(g, "png"))
                want = clip.load_view_ldr(view, level, g)
                swapped = view == v and level_name(level) == lv and g in (g0, g1)
                assert np.array_equal(got, want) != swapped, (view, level, g)
    # the swapped frames are each other's truth, and they differ
    other = {g0: g1, g1: g0}
    for g in (g0, g1):
        got = mio.read_png(r / v / "ldr" / lv / frame_name(g, "png"))
        assert np.array_equal(got, clip.load_view_ldr(v, float(lv), other[g]))
    assert not np.array_equal(
        clip.load_view_ldr(v, float(lv), g0), clip.load_view_ldr(v, float(lv), g1)
    )
    inp = m["options"]["input"]
    assert inp["views"] == sorted(views) and inp["layout"] == "m4dgs"
    # HDR: test frames and views; LDR: 16-bit / float / 8-bit test frames as before + the view PNGs
    n_test = len(clip.test_frames)
    assert inp["hdr"] == n_test * (1 + len(views))
    assert (
        inp["ldr_uint8"] == n_test * len(clip.meta.exposures.novel) + len(views) * n_test * n_levels
    )
    assert m["hdr_psnr"] == PSNR_CAP_DB  # the test frames score as before


def test_a_view_missing_a_frame_and_an_unknown_view_are_named(tiny_clip_oracle, tmp_path):
    clip = Clip.open(tiny_clip_oracle)
    views = clip.view_names()
    pred = write_views(clip, tmp_path / "pred", views=views[:1])
    g = clip.test_frames[2]
    lv = level_name(clip.meta.exposures.observed[0])
    gone = [
        pred / "views" / views[0] / "hdr" / frame_name(g, "exr"),
        pred / "views" / views[0] / "ldr" / lv / frame_name(g, "png"),
    ]
    for p in gone:
        p.unlink()
    with pytest.raises(InputError, match=r"2 file\(s\) missing") as e:
        plan_inputs(clip, pred)
    for p in gone:
        assert str(p.with_suffix("")) + ".{" in str(e.value)
    (pred / "views" / "top").mkdir()
    with pytest.raises(InputError, match="unknown view") as e:
        plan_inputs(clip, pred)
    assert "top" in str(e.value) and all(v in str(e.value) for v in views)


def test_a_views_only_folder_needs_no_test_frames(tiny_clip_oracle, tmp_path):
    """A baseline that renders only the held-out views (no DIR/test): planned and imported; without
    DIR/views the test frames stay required."""
    clip = Clip.open(tiny_clip_oracle)
    views = clip.view_names()
    pred = write_views(clip, tmp_path / "pred", views=views[1:])
    plan = plan_inputs(clip, pred)
    assert all(k.startswith("views/") for k in plan)
    assert sorted({k.split("/")[1] for k in plan}) == sorted(views[1:])
    report = import_frames(clip, pred, tmp_path / "s", "dibr-like")
    assert report["views"] == sorted(views[1:]) and not (tmp_path / "s/renders/test").exists()
    g = clip.test_frames[-1]
    lv = clip.meta.exposures.observed[-1]
    got = mio.read_png(
        tmp_path / "s/renders/views" / views[2] / "ldr" / level_name(lv) / frame_name(g, "png")
    )
    np.testing.assert_array_equal(got, clip.load_view_ldr(views[2], lv, g))
    with pytest.raises(InputError, match="test/hdr"):
        plan_inputs(clip, tmp_path / "pred" / "views")  # neither test/ nor views/: as before


def test_a_views_only_folder_scores_end_to_end(tiny_clip_oracle, tmp_path):
    clip = Clip.open(tiny_clip_oracle)
    pred = write_views(clip, tmp_path / "pred")
    _, m = score_frames(tiny_clip_oracle, pred, "views-only", tmp_path / "s")
    assert m["ldr_oe_psnr"] is None and m["hdr_psnr"] is None and m["dyn_ldr_psnr"] is None
    # the views are the truth: every masked and unmasked PSNR at the cap, for every view
    for v in clip.view_names():
        assert m[f"nv_{v}_ldr_oe_mpsnr"] == 100.0 and m[f"nv_{v}_hdr_psnr"] == 100.0
    assert m["nv_ldr_ne_psnr"] == 100.0 and 0 < m["nv_covisible"] <= 1


# --------------------------------------------------------------------------------------------------
# --layout: other methods' render folders as they write them
# --------------------------------------------------------------------------------------------------
def _export(clip_dir, fmt, out):
    r = CliRunner().invoke(
        benchgen_main, ["export", str(clip_dir), "--format", fmt, "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    return out


def _level_of(log2_dt, levels):
    """The level an exposures.json value (log2 of the exposure time) names."""
    lv = min(levels, key=lambda v: abs(math.log2(v) - log2_dt))
    assert abs(math.log2(lv) - log2_dt) < 1e-9
    return lv


def _paper_folder(root):
    """A data folder as the paper's preprocessed data look: frame_<i>.png, the even ones training
    frames, the odd ones test frames (test/ at its own exposure, test_ne/ at another)."""
    rng = np.random.default_rng(3)
    names = [f"frame_{i:04d}.png" for i in range(7)]
    ex = {"train_exp_num": 3, "train": {}, "test": {}, "test_ne": {}}
    for i, n in enumerate(names):
        img = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
        if i % 2 == 0:
            mio.write_png(root / "images" / n, img)
            ex["train"][n] = [-3.0, 1.0, 5.0][(i // 2) % 3]
            (root / "depthcrafter_depth").mkdir(exist_ok=True)
            np.savez(
                root / "depthcrafter_depth" / n.replace(".png", ".npz"), dep=np.full((24, 32), 2.0)
            )
        else:
            mio.write_png(root / "test" / n, img)
            mio.write_png(root / "test_ne" / n, img[::-1].copy())
            ex["test"][n] = [-3.0, 1.0, 5.0][(i // 2) % 3]
            ex["test_ne"][n] = -1.0
    (root / "exposures.json").write_text(json.dumps(ex))
    return ex


def test_official_layout_scores_real_footage(tmp_path):
    """The official code's world_gs/ of a workspace made from paper-style data: test_ldr/<name>
    is each test frame at its exposures.json "test" exposure, train_ldr/<name> each training frame;
    names that are not numbers are matched in sorted order (training frame i = frame 2i, test
    frame j = frame 2j + 1)."""
    ws = tmp_path / "Dog"
    ex = _paper_folder(ws)
    clip_dir = tmp_path / "clip"
    r = CliRunner().invoke(
        m4dgs_main, ["import-clip", "--format", "mono4dgs-hdr", str(ws), "--out", str(clip_dir)]
    )
    assert r.exit_code == 0, r.output
    out = ws / "exp" / "world_gs"  # <workspace>/<experiment>/world_gs, as the official code writes
    for n in ex["test"]:
        (out / "test_ldr").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(ws / "test" / n, out / "test_ldr" / n)
        # a novel-exposure render, as jpg (lossy: scored below the cap)
        p = out / "test_ne_ldr" / n.replace(".png", ".jpg")
        p.parent.mkdir(parents=True, exist_ok=True)
        assert cv2.imwrite(str(p), mio.read_png(ws / "test_ne" / n)[..., ::-1])
    # as the official code saves them: JPEG (here at full chroma resolution: the frames are noise)
    q = [cv2.IMWRITE_JPEG_QUALITY, 100, cv2.IMWRITE_JPEG_SAMPLING_FACTOR]
    q += [cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444]
    for n in ex["train"]:
        (out / "train_ldr").mkdir(exist_ok=True)
        jpg = str(out / "train_ldr" / n.replace(".png", ".jpg"))
        assert cv2.imwrite(jpg, mio.read_png(ws / "images" / n)[..., ::-1], q)
    args = ["score-frames", "--clip", str(clip_dir), "--pred", str(out), "--name", "official"]
    args += ["--out", str(tmp_path / "s"), "--layout", "mono4dgs-hdr"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    m = json.loads((tmp_path / "s/metrics.json").read_text())
    assert m["ldr_oe_psnr"] == PSNR_CAP_DB and 30 < m["ldr_train_psnr"] < PSNR_CAP_DB
    assert {k: v["frames"] for k, v in m["per_level"].items()} == {
        "0.125": 1,
        "2": 1,
        "32": 1,
        "0.5": 3,  # test_ne/: the novel exposure of every test frame, LDR-NE
    }
    # LDR-NE is the mean PSNR of the decoded JPEGs against test_ne/, computed here
    ne = []
    for n in ex["test_ne"]:
        pred = cv2.imread(str(out / "test_ne_ldr" / n.replace(".png", ".jpg")))[..., ::-1]
        gt = mio.read_png(ws / "test_ne" / n)
        mse = float(np.mean((pred / 255.0 - gt / 255.0) ** 2))
        ne.append(10 * np.log10(1 / mse))
    assert m["ldr_ne_psnr"] == pytest.approx(float(np.mean(ne)), abs=1e-6)
    assert m["ldr_ne_psnr"] < PSNR_CAP_DB
    assert m["options"]["input"]["layout"] == "mono4dgs-hdr"
    assert sorted(m["options"]["input"]["given"]) == ["test_ldr", "test_ne_ldr", "train_ldr"]
    assert m["options"]["input"]["ldr_uint8"] == 3 + 3 + 4  # test PNGs, test_ne and training JPEGs
    # frame_0003 is test frame 3, at exposure 2^1
    np.testing.assert_array_equal(
        mio.read_png(tmp_path / "s/renders/test/ldr/2/00003.png"),
        mio.read_png(ws / "test/frame_0003.png"),
    )

    # two test frames swapped: each scores below the cap at its level
    a, b = out / "test_ldr/frame_0001.png", out / "test_ldr/frame_0003.png"
    ab, bb = a.read_bytes(), b.read_bytes()
    a.write_bytes(bb)
    b.write_bytes(ab)
    _, m = score_frames(
        clip_dir, out, "official", tmp_path / "s", layout="mono4dgs-hdr", force=True
    )
    pl = m["per_level"]
    assert pl["0.125"]["psnr"] < 20 and pl["2"]["psnr"] < 20 and pl["32"]["psnr"] == PSNR_CAP_DB

    # the workspace's exposures.json says at which exposure each render is: another split is refused
    ex["test"]["frame_0005.png"] = 2.0
    (ws / "exposures.json").write_text(json.dumps(ex))
    with pytest.raises(InputError, match=r"exposures.json: field 'test.frame_0005.png'"):
        plan_inputs(Clip.open(clip_dir), out, "mono4dgs-hdr")


def _official_renders(clip: Clip, ws: Path):
    """A perfect method's world_gs/ for a workspace exported from `clip`, written from the
    workspace's exposures.json (the official loader's facts): test_ldr/<name> at the "test"
    exposure of <name>, test_ne_ldr/<name> at its "test_ne" exposure, test_hdr_exr/<stem>.exr.
    Returns (the folder, {frame: levels rendered})."""
    ex = json.loads((ws / "exposures.json").read_text())
    out = ws / "exp" / "world_gs"
    at = {}
    for key, folder, levels in (
        ("test", "test_ldr", clip.meta.exposures.observed),
        ("test_ne", "test_ne_ldr", clip.meta.exposures.novel),
    ):
        for n, v in ex[key].items():
            g, lv = int(Path(n).stem), _level_of(v, levels)
            at.setdefault(g, []).append(lv)
            p = out / folder / n
            p.parent.mkdir(parents=True, exist_ok=True)
            mio.write_png(p, clip.load_gt_ldr(lv, g))
    for n in ex["test"]:
        mio.write_exr(
            out / "test_hdr_exr" / n.replace(".png", ".exr"), clip.load_gt_hdr(int(n[:5]))
        )
    return out, at


def test_official_layout_of_an_exported_clip(tiny_clip_oracle, tmp_path):
    """A benchgen clip exported for the official code: its renders, named like the workspace's
    test/ files, land at the level exposures.json gives them (test: an observed level, test_ne: a
    novel one); the score sees those levels only."""
    clip = Clip.open(tiny_clip_oracle)
    ws = _export(tiny_clip_oracle, "mono4dgs-hdr", tmp_path / "ws")
    out, at = _official_renders(clip, ws)
    report = import_frames(clip, out, tmp_path / "s", "official", "mono4dgs-hdr")
    assert report["given"] == ["test_hdr_exr", "test_ldr", "test_ne_ldr"]
    r = tmp_path / "s/renders/test"
    for g in clip.test_frames:
        have = sorted(p.parent.name for p in r.glob(f"ldr/*/{frame_name(g, 'png')}"))
        assert have == sorted(level_name(lv) for lv in at[g]) and len(have) == 2
        for lv in at[g]:
            got = mio.read_png(r / "ldr" / level_name(lv) / frame_name(g, "png"))
            np.testing.assert_array_equal(got, clip.load_gt_ldr(lv, g))
        np.testing.assert_array_equal(
            mio.read_exr(r / "hdr" / frame_name(g, "exr")), clip.load_gt_hdr(g)
        )
    # every level is scored on some test frame, each test frame at the levels it was rendered at
    seen = scored_clip(clip, tmp_path / "s/renders")
    assert all(sorted(seen.meta.test_levels_of(g)) == sorted(at[g]) for g in clip.test_frames)
    assert {lv for g in at for lv in at[g]} == set(
        clip.meta.exposures.observed + clip.meta.exposures.novel
    )


def _nerfies_results(exp: Path, res: Path):
    """A perfect DyCheck-style method's results/rgb/: for every frame name of the validation
    splits, the export's rgb/1x/<name>.png. Returns the names."""
    names = []
    for split in ("val", "val_path"):
        names += json.loads((exp / "splits" / f"{split}.json").read_text())["frame_names"]
    for n in names:
        (res / "rgb").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(exp / "rgb/1x" / f"{n}.png", res / "rgb" / f"{n}.png")
    return names


def test_nerfies_layout_maps_val_renders_onto_the_views(tiny_clip_oracle, tmp_path):
    """DyCheck writes results/rgb/<frame name>.png per image of a split (frame names of
    splits/<split>.json, "<camera id>_<time id:05d>"); the Nerfies export's validation cameras
    1, 2, ... are the held-out views, camera 0's validation images the test frames. A perfect
    method renders rgb/1x/<id>.png of the export."""
    clip = Clip.open(tiny_clip_oracle)
    exp = _export(tiny_clip_oracle, "nerfies", tmp_path / "exp")
    meta = json.loads((exp / "metadata.json").read_text())
    res = tmp_path / "work" / "results"
    names = _nerfies_results(exp, res)
    assert len(names) == len(clip.test_frames) * (1 + len(clip.view_names()))
    # one view's two frames swapped
    v1 = [n for n in names if meta[n]["camera_id"] == 1][:2]
    a, b = (res / "rgb" / f"{n}.png" for n in v1)
    ab, bb = a.read_bytes(), b.read_bytes()
    a.write_bytes(bb)
    b.write_bytes(ab)
    report = import_frames(clip, res, tmp_path / "s", "nerfies", "nerfies")
    assert report["views"] == sorted(clip.view_names()) and report.get("hdr", 0) == 0
    r = tmp_path / "s/renders"
    for n in names:
        e = meta[n]
        g, cam, lv = e["warp_id"], e["camera_id"], e["exposure"]
        if cam == 0:
            got = mio.read_png(r / "test/ldr" / level_name(lv) / frame_name(g, "png"))
            want = clip.load_gt_ldr(lv, g)
        else:
            view = clip.view_names()[cam - 1]
            assert e["view"] == view
            got = mio.read_png(r / "views" / view / "ldr" / level_name(lv) / frame_name(g, "png"))
            want = clip.load_view_ldr(view, lv, g)
        assert np.array_equal(got, want) == (n not in v1), n
    # one level per test frame: the score sees that one
    seen = scored_clip(clip, r)
    assert all(len(seen.meta.test_levels_of(g)) == 1 for g in clip.test_frames)

    (res / "rgb" / "7_00001.png").write_bytes(ab)
    with pytest.raises(InputError, match="camera\\(s\\) 7") as e:
        plan_inputs(clip, res, "nerfies")
    assert all(v in str(e.value) for v in clip.view_names())


def test_official_layout_of_an_exported_clip_scores_end_to_end(tiny_clip_oracle, tmp_path):
    clip = Clip.open(tiny_clip_oracle)
    out, _ = _official_renders(clip, _export(tiny_clip_oracle, "mono4dgs-hdr", tmp_path / "ws"))
    _, m = score_frames(tiny_clip_oracle, out, "official", tmp_path / "s", layout="mono4dgs-hdr")
    assert m["ldr_oe_psnr"] == m["ldr_ne_psnr"] == m["hdr_psnr"] == PSNR_CAP_DB
    assert sum(v["frames"] for v in m["per_level"].values()) == 2 * len(clip.test_frames)


def test_nerfies_layout_scores_end_to_end(tiny_clip_oracle, tmp_path):
    exp = _export(tiny_clip_oracle, "nerfies", tmp_path / "exp")
    _nerfies_results(exp, tmp_path / "results")
    _, m = score_frames(
        tiny_clip_oracle, tmp_path / "results", "dy", tmp_path / "s", layout="nerfies"
    )
    assert m["ldr_oe_psnr"] == PSNR_CAP_DB and m["hdr_psnr"] is None
    # DyCheck's val cameras are the held-out views, at the one level the method renders: scored
    # there (the truth, so at the cap), and HDR and the other levels left out, not failed
    assert m["nv_ldr_oe_mpsnr"] == PSNR_CAP_DB and m["nv_hdr_psnr"] is None
    assert m["nv_ldr_ne_psnr"] is None or m["nv_ldr_oe_psnr"] is None  # one level: one split
