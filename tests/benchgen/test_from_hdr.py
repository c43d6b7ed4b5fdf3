"""`benchgen from-hdr`: an evaluation clip from an HDR video (here the tiny benchgen clip's own
ground-truth HDR frames), checked against the paper's recipe written out by hand: even frames train,
odd frames test, LDR = floor(255 ((H dt) / (H dt + 1))^(1 / 2.2) + 0.5) at alternating exposures;
the clip trains and scores with the metrics its ground truth allows."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from benchgen.cli import main
from benchgen.from_hdr import HdrVideoOptions, clip_from_hdr_video
from m4dgs.clip import Clip, frame_name
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError


def hdrnerf_codes(h: np.ndarray, dt: float) -> np.ndarray:
    """The paper's Syn-Exp-3 tone mapping (appendix, "Datasets"), by hand, in float64."""
    x = np.asarray(h, np.float64) * dt
    return np.floor(255.0 * (x / (x + 1.0)) ** (1.0 / 2.2) + 0.5)


@pytest.fixture(scope="module")
def video(tiny_clip_oracle, tmp_path_factory):
    """The tiny clip's gt HDR frames as an HDR video (names whose string order is not their
    order) and its gt depth of every frame as one .npy per frame."""
    src = Clip.open(tiny_clip_oracle)
    root = tmp_path_factory.mktemp("hdr-video")
    (root / "hdr").mkdir()
    (root / "depth").mkdir()
    for g in src.meta.frames:
        shutil.copyfile(src.path("gt/hdr", frame_name(g, "exr")), root / "hdr" / f"f{g + 8}.exr")
        np.save(root / "depth" / f"d{g + 8:03d}.npy", src.load_gt_depth(g))
    return src, root


def make(root, out, **kw):
    opt = HdrVideoOptions(hdr=root / "hdr", depth=root / "depth", allow_misplaced=True, **kw)
    return Clip.open(clip_from_hdr_video(out, opt), validate="full")


def test_the_paper_recipe_by_hand(video, tmp_path):
    src, root = video
    clip = make(root, tmp_path / "c", scale=3.0)
    G = src.meta.num_frames
    assert clip.meta.frames == list(range(G))
    assert clip.train_frames == list(range(0, G, 2)) and clip.test_frames == list(range(1, G, 2))
    assert clip.meta.exposures.observed == [0.125, 2.0, 32.0]
    assert clip.meta.exposures.novel == [0.5, 8.0]
    assert list(clip.train_dt) == [[0.125, 2.0, 32.0][i % 3] for i in range(len(clip.train_frames))]
    assert clip.meta.crf == "hdrnerf" and clip.meta.hdr_scale == 3.0
    assert clip.meta.unit_exposure_value == pytest.approx(0.5 ** (1 / 2.2), abs=1e-6)  # 0.73
    mism = 0
    for g in src.meta.frames:
        h = src.load_gt_hdr(g).astype(np.float64) * 3.0
        assert np.allclose(clip.load_gt_hdr(g), h, rtol=1e-6)
        if g in clip.train_frames:
            pairs = [(clip.load_ldr(g), clip.meta.train_dt_of(g))]
        else:
            pairs = [(clip.load_gt_ldr(lv, g), lv) for lv in (0.125, 0.5, 2.0, 8.0, 32.0)]
        for got, dt in pairs:
            d = np.abs(got.astype(np.float64) - hdrnerf_codes(h, dt))
            assert d.max() <= 1  # float32 against float64 at a rounding boundary
            mism += int((d > 0).sum())
    assert mism < 1e-3 * G * 5 * clip.width * clip.height * 3
    # ground truth: HDR and LDR only, no gt flow (eval uses DIS on the ground truth)
    for part in ("depth", "cameras.json", "masks/dynamic", "tracks.npz", "flow.npz"):
        assert not clip.has_gt_part(part)
    # the depth prior: the given maps of the training (even) frames; tracks on those frames
    for g in clip.train_frames:
        assert np.allclose(clip.load_depth_prior(g), src.load_gt_depth(g), rtol=1e-6)
    assert list(clip.load_tracks_prior().frames) == clip.train_frames
    gen = clip.meta.generator
    assert gen["tool"] == "benchgen from-hdr" and gen["source_frames"][:2] == ["f8.exr", "f9.exr"]
    assert clip.meta.gt["placement"]["targets"]  # measured from the PNGs


def test_the_chosen_scale_follows_the_brightness_of_the_video(video, tmp_path):
    src, root = video
    a = make(root, tmp_path / "a")
    dim = tmp_path / "dim"
    (dim / "hdr").mkdir(parents=True)
    for p in sorted((root / "hdr").iterdir()):
        mio.write_exr(dim / "hdr" / p.name, mio.read_exr(p) / np.float32(1000.0))
    (dim / "depth").symlink_to(root / "depth")
    b = make(dim, tmp_path / "b")
    assert b.meta.hdr_scale == pytest.approx(1000.0 * a.meta.hdr_scale, rel=1e-4)
    same = np.mean([np.mean(a.load_ldr(g) == b.load_ldr(g)) for g in a.train_frames])
    assert same > 0.999
    # the middle level's median code lands in the placement window [0.35, 0.65]
    mid = a.meta.gt["placement"]["targets"]
    assert any("median" in k and v["met"] for k, v in mid.items())


def test_ldr_only_first_then_the_priors(video, tmp_path):
    src, root = video
    out = tmp_path / "mine"
    r = CliRunner().invoke(
        main, ["from-hdr", "--hdr", str(root / "hdr"), "--out", str(out), "--ldr-only"]
    )
    assert r.exit_code == 0, r.output
    assert not (out / "clip.json").exists() and "run a depth model" in r.output
    first = {p.name: mio.read_png(p) for p in sorted((out / "input/ldr").iterdir())}
    assert sorted(first) == [frame_name(g, "png") for g in range(0, src.meta.num_frames, 2)]
    # one depth map per training frame this time (the files the depth model wrote)
    depth = tmp_path / "depth5"
    depth.mkdir()
    for i, g in enumerate(range(0, src.meta.num_frames, 2)):
        np.save(depth / f"{i}.npy", src.load_gt_depth(g))
    r = CliRunner().invoke(
        main,
        ["from-hdr", "--hdr", str(root / "hdr"), "--out", str(out), "--depth", str(depth)]
        + ["--allow-misplaced"],
    )
    assert r.exit_code == 0, r.output
    clip = Clip.open(out, validate="full")
    for g in clip.train_frames:
        assert np.array_equal(clip.load_ldr(g), first[frame_name(g, "png")])
        assert np.allclose(clip.load_depth_prior(g), src.load_gt_depth(g), rtol=1e-6)


def test_bad_input_is_named(video, tmp_path):
    src, root = video
    bad = tmp_path / "bad"
    shutil.copytree(root / "hdr", bad / "hdr")
    h = mio.read_exr(bad / "hdr" / "f10.exr")
    h[0, 0, 1] = np.nan
    mio.write_exr(bad / "hdr" / "f10.exr", h)
    with pytest.raises(InputError, match=r"f10\.exr: field 'pixels': contains NaN"):
        clip_from_hdr_video(tmp_path / "x", HdrVideoOptions(hdr=bad / "hdr", depth=root / "depth"))
    with pytest.raises(InputError, match="--ldr-only"):
        clip_from_hdr_video(tmp_path / "y", HdrVideoOptions(hdr=root / "hdr"))
    with pytest.raises(InputError, match="at least 6"):
        clip_from_hdr_video(
            tmp_path / "z", HdrVideoOptions(hdr=root / "hdr", depth=root / "depth", max_frames=5)
        )
    inside = tmp_path / "w"
    shutil.copytree(root / "depth", inside / "depth")
    with pytest.raises(InputError, match="inside --out"):
        clip_from_hdr_video(inside, HdrVideoOptions(hdr=root / "hdr", depth=inside / "depth"))
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()
    # a mis-exposed clip fails unless allowed (here: everything far too bright)
    r = CliRunner().invoke(
        main,
        ["from-hdr", "--hdr", str(root / "hdr"), "--out", str(tmp_path / "v")]
        + ["--depth", str(root / "depth"), "--scale", "1e6"],
    )
    assert r.exit_code == 1 and "exposure-placement targets" in r.output
    assert "--scale" in r.output


def test_given_gt_flow_sets_the_floor_and_the_clip_trains_and_scores(
    video, tmp_path, short_training
):
    from eval.experiments.score import score_run
    from m4dgs.training.pipeline import train

    src, root = video
    # the exact flow of the source clip between consecutive training frames (global g, g + 2
    # there: its own training frames are the even ones too), by training-frame position
    fs = src.load_gt_flow()
    flow_dir = tmp_path / "gtflow"
    flow_dir.mkdir()
    tf = list(range(0, src.meta.num_frames, 2))
    for i in range(len(tf) - 1):
        for a, b in ((i, i + 1), (i + 1, i)):
            f, _ = fs.get(tf[a], tf[b])
            np.save(flow_dir / f"{a}_{b}.npy", f)
    clip = make(root, tmp_path / "c", gt_flow=flow_dir)
    assert clip.has_gt_part("flow.npz")
    assert math.isfinite(clip.meta.gt["hdr_tae_floor"])
    run = train(
        clip.root, tmp_path / "run", preset="tiny", overrides=short_training, progress=False
    )
    m = score_run(run)
    assert m["ldr_oe_psnr"] > 5 and m["hdr_psnr"] > 5 and math.isfinite(m["hdr_tae"])
    assert "hdr_tae_given_flow" in m["conventions"]
    assert m["depth_absrel"] is None and m["ate"] is None and m["mask_iou"] is None
    # without a given flow, HDR-TAE uses DIS flow on the ground truth (the same for every method)
    plain = make(root, tmp_path / "p")
    shutil.copytree(run, tmp_path / "run2")
    cfg = json.loads((tmp_path / "run2" / "run.json").read_text())
    cfg["clip"] = str(plain.root)
    (tmp_path / "run2" / "run.json").write_text(json.dumps(cfg))
    m2 = score_run(tmp_path / "run2", clip=plain.root)
    assert "hdr_tae_gt_dis_flow" in m2["conventions"] and math.isfinite(m2["hdr_tae"])


def test_a_benchgen_clip_s_own_hdr_gives_back_its_inputs(video, tmp_path):
    """benchgen make tone-maps its (scaled) gt/hdr with the same response, split and alternating
    schedule: from-hdr on those frames at scale 1 writes the same PNGs byte for byte, and the scale
    it chooses itself from them is 1 (the same placement targets on the same frames)."""
    src, root = video
    clip = make(root, tmp_path / "c", scale=1.0)
    assert list(clip.train_dt) == list(src.train_dt)
    for g in src.train_frames:
        assert np.array_equal(clip.load_ldr(g), src.load_ldr(g))
    for g in src.test_frames:
        for lv in (0.125, 0.5, 2.0, 8.0, 32.0):
            assert np.array_equal(clip.load_gt_ldr(lv, g), src.load_gt_ldr(lv, g))
    auto = make(root, tmp_path / "a")
    assert auto.meta.hdr_scale == pytest.approx(1.0, rel=1e-3)


def test_width_area_averages_the_hdr_frames(video, tmp_path):
    src, root = video
    clip = make(root, tmp_path / "half", scale=2.0, width=src.width // 2)
    assert (clip.width, clip.height) == (src.width // 2, src.height // 2)
    assert clip.meta.generator["resized_from"] == [src.height, src.width]
    for g in (0, 1):
        h = src.load_gt_hdr(g).astype(np.float64) * 2.0
        blocks = h.reshape(src.height // 2, 2, src.width // 2, 2, 3).mean(axis=(1, 3))
        assert np.allclose(clip.load_gt_hdr(g), blocks, rtol=1e-5, atol=1e-6)
