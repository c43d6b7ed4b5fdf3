"""`m4dgs import-clip`: a benchgen clip stripped to its frames, exposure times and depth goes
through the import (tracks chained from DIS flow) and trains; given tracks, EXIF exposure times,
video input and .flo flow files are read as their formats define them."""

from __future__ import annotations

import json
import shutil

import imageio.v2 as iio
import numpy as np
import pytest
from click.testing import CliRunner
from PIL import Image, TiffImagePlugin

from m4dgs.cli import main
from m4dgs.clip import Clip, frame_name
from m4dgs.core.errors import InputError
from m4dgs.footage import ImportOptions, exposure_levels, import_clip, read_flo
from m4dgs.run import RunDir
from m4dgs.training.pipeline import train


def strip(clip_dir, root):
    """The clip's input frames (renamed to a camera's file names), an exposure-time file in
    seconds ('name value' lines) and the depth prior as one .npy per frame."""
    clip = Clip.open(clip_dir)
    frames, depth = root / "frames", root / "depth"
    frames.mkdir(parents=True)
    depth.mkdir()
    lines = []
    for i, g in enumerate(clip.train_frames):
        name = f"IMG_{i + 8}.png"  # 8, 9, 10, ...: natural order, not string order
        shutil.copyfile(clip.path("input/ldr", frame_name(g, "png")), frames / name)
        lines.append(f"{name} {clip.meta.train_dt_of(g) / 500.0}")
        np.save(depth / f"d{i + 8:03d}.npy", clip.load_depth_prior(g))
    (root / "times.txt").write_text("\n".join(lines) + "\n")
    return clip, frames, root / "times.txt", depth


def test_stripped_benchgen_clip_imports_and_trains(tiny_clip_realistic, tmp_path, short_training):
    clip, frames, times, depth = strip(tiny_clip_realistic, tmp_path)
    out = tmp_path / "mine"
    r = CliRunner().invoke(
        main,
        ["import-clip", "--frames", str(frames), "--exposures", str(times), "--depth", str(depth)]
        + ["--out", str(out)],
    )
    assert r.exit_code == 0, r.output
    new = Clip.open(out)
    new.validate()
    T = len(clip.train_frames)
    assert new.train_frames == list(range(T)) and new.test_frames == [] and not new.has_gt
    # exposure ratios kept, unit = geometric mean of the levels
    old_dt = np.array(clip.train_dt)
    assert np.allclose(np.array(new.train_dt) / new.train_dt[0], old_dt / old_dt[0])
    assert np.isclose(np.exp(np.mean(np.log(new.meta.exposures.observed))), 1.0)
    assert new.meta.generator["exposure_seconds"][0] == pytest.approx(old_dt[0] / 500.0)
    assert new.meta.crf is None and new.meta.unit_exposure_value == 0.5
    for i, g in enumerate(clip.train_frames):
        assert np.array_equal(new.load_ldr(i), clip.load_ldr(g))
        assert np.allclose(new.load_depth_prior(i), clip.load_depth_prior(g), rtol=1e-6)
    # tracks chained through the flow span more than a frame pair
    ts = new.load_tracks_prior()
    assert ts.tracks.shape[0] > 50 and ts.visible.sum(1).max() >= 4
    assert new.meta.priors["tracks"]["max_length"] >= 4
    # ... and the clip trains
    run = train(out, tmp_path / "run", preset="tiny", overrides=short_training, progress=False)
    assert RunDir(run).done


def test_given_tracks_keep_their_positions(tiny_clip_realistic, tmp_path):
    clip, frames, times, depth = strip(tiny_clip_realistic, tmp_path)
    src = clip.load_tracks_prior()  # [N, T, 2], first pixel centre at 0.5
    tr = np.transpose(src.tracks, (1, 0, 2)) - 0.5  # [T, N, 2], integer pixel centres
    np.savez(tmp_path / "tracks.npz", tracks=tr, visibility=src.visible.T)
    opt = ImportOptions(frames=frames, exposures=times, depth=depth, tracks=tmp_path / "tracks.npz")
    new = Clip.open(import_clip(tmp_path / "mine", opt))
    got = new.load_tracks_prior()
    # positions outside the frame become invisible; tracks seen in fewer than 2 frames are dropped
    x, y = src.tracks[..., 0], src.tracks[..., 1]
    vis = src.visible & (x >= 0) & (x < clip.width) & (y >= 0) & (y < clip.height)
    keep = vis.sum(1) >= 2
    assert (src.visible & ~vis).any()  # the degraded prior has some: the rule is exercised
    assert np.array_equal(got.visible, vis[keep])
    v = got.visible
    assert np.allclose(got.tracks[v], src.tracks[keep][v], atol=1e-5)
    # 3D tracks (x, y, depth; SpatialTracker's layout): the same 2D tracks
    xyz = np.concatenate([tr, np.full(tr.shape[:2] + (1,), 7.0)], -1)
    np.savez(tmp_path / "tracks3.npz", tracks=xyz, visibility=src.visible.T)
    opt3 = ImportOptions(
        frames=frames, exposures=times, depth=depth, tracks=tmp_path / "tracks3.npz"
    )
    got3 = Clip.open(import_clip(tmp_path / "mine3", opt3)).load_tracks_prior()
    assert np.array_equal(got3.tracks, got.tracks) and np.array_equal(got3.visible, got.visible)
    # the same tracks through the command line (the prior-file options import-clip shares with
    # benchgen from-hdr), given with the first pixel's centre at 0.5 this time
    np.savez(tmp_path / "tracks05.npz", tracks=tr + 0.5, visibility=src.visible.T)
    r = CliRunner().invoke(
        main,
        ["import-clip", "--frames", str(frames), "--exposures", str(times), "--depth", str(depth)]
        + ["--tracks", str(tmp_path / "tracks05.npz"), "--track-pixel-centre", "0.5"]
        + ["--out", str(tmp_path / "mine-cli")],
    )
    assert r.exit_code == 0, r.output
    got_cli = Clip.open(tmp_path / "mine-cli").load_tracks_prior()
    assert np.array_equal(got_cli.visible, got.visible)
    assert np.allclose(got_cli.tracks[v], got.tracks[v], atol=1e-5)


def test_errors_name_what_is_missing_and_leave_nothing(tiny_clip_realistic, tmp_path):
    clip, frames, times, depth = strip(tiny_clip_realistic, tmp_path)
    out = tmp_path / "mine"
    with pytest.raises(InputError, match="depth prior is required"):
        import_clip(out, ImportOptions(frames=frames, exposures=times))
    short = tmp_path / "short.txt"
    short.write_text("0.01\n0.02\n")
    with pytest.raises(InputError, match=f"{short}: 2 exposure times for 5 frames"):
        import_clip(out, ImportOptions(frames=frames, exposures=short, depth=depth))
    with pytest.raises(InputError, match="no EXIF ExposureTime"):
        import_clip(out, ImportOptions(frames=frames, depth=depth))
    (depth / "d008.npy").unlink()
    with pytest.raises(InputError, match="4 depth files for 5 frames"):
        import_clip(out, ImportOptions(frames=frames, exposures=times, depth=depth))
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "depth",
        "frames",
        "short.txt",
        "times.txt",
    ]


def test_exif_exposure_times_and_video_input(tiny_clip_realistic, tmp_path):
    clip = Clip.open(tiny_clip_realistic)
    jpgs = tmp_path / "jpg"
    jpgs.mkdir()
    imgs = [clip.load_ldr(g) for g in clip.train_frames]
    secs = [clip.meta.train_dt_of(g) / 1000.0 for g in clip.train_frames]
    for i, (img, s) in enumerate(zip(imgs, secs)):
        im = Image.fromarray(img)
        exif = im.getexif()
        exif.get_ifd(0x8769)[33434] = TiffImagePlugin.IFDRational(s)
        im.save(jpgs / f"{i}.jpg", exif=exif, quality=95)
    depth = np.stack([clip.load_depth_prior(g) for g in clip.train_frames])
    np.save(tmp_path / "depth.npy", 1.0 / depth)  # as disparity
    opt = ImportOptions(
        frames=jpgs, depth=tmp_path / "depth.npy", depth_kind="disparity", max_frames=4
    )
    new = Clip.open(import_clip(tmp_path / "a", opt))
    assert np.allclose(new.meta.generator["exposure_seconds"], secs[:4], rtol=1e-3)
    assert np.allclose(new.load_depth_prior(1), depth[1], rtol=1e-5)

    video = tmp_path / "v.mp4"
    with iio.get_writer(video, fps=10, macro_block_size=1) as w:
        for img in imgs:
            w.append_data(img)
    (tmp_path / "t.json").write_text("[1, 4, 16, 1, 4]")
    opt = ImportOptions(
        video=video, exposures=tmp_path / "t.json", depth=tmp_path / "depth.npy", every=1
    )
    new = Clip.open(import_clip(tmp_path / "b", opt))
    assert new.meta.num_frames == 5 and (new.width, new.height) == (clip.width, clip.height)
    assert np.allclose(new.train_dt, [0.25, 1, 4, 0.25, 1])


def test_flo_files_and_exposure_levels(tmp_path):
    f = np.random.default_rng(0).normal(size=(6, 9, 2)).astype(np.float32)
    with open(tmp_path / "0_1.flo", "wb") as fh:
        np.array([202021.25], np.float32).tofile(fh)
        np.array([9, 6], np.int32).tofile(fh)
        f.tofile(fh)
    assert np.array_equal(read_flo(tmp_path / "0_1.flo"), f)
    (tmp_path / "bad.flo").write_bytes(b"abcd" + bytes(8))
    with pytest.raises(InputError, match="magic"):
        read_flo(tmp_path / "bad.flo")
    # metered times within 2 % are one level
    assert exposure_levels([0.01, 0.0101, 0.04, 0.0399, 0.16]) == pytest.approx(
        [0.01005, 0.03995, 0.16]
    )


def test_a_refused_clip_leaves_no_run_folder(tiny_clip_realistic, tmp_path, short_training):
    clip_dir = tmp_path / "clip"
    shutil.copytree(tiny_clip_realistic, clip_dir)
    (clip_dir / "priors/tracks.npz").unlink()
    with pytest.raises(InputError, match="tracks"):
        train(clip_dir, tmp_path / "run", preset="tiny", overrides=short_training, progress=False)
    assert not (tmp_path / "run").exists()
    # a folder that was there before is kept
    (tmp_path / "mine").mkdir()
    with pytest.raises(InputError):
        train(clip_dir, tmp_path / "mine", preset="tiny", overrides=short_training, progress=False)
    assert (tmp_path / "mine").is_dir()


def test_width_resizes_frames_and_scales_tracks_and_flow(tiny_clip_realistic, tmp_path):
    """--width half the frames' width: each frame is the mean of its 2x2 blocks, track positions
    (continuous pixel coordinates, pixel edges at integers) halve, a constant flow of (2, -1) px
    becomes (1, -0.5) px, and depth comes at the new size."""
    clip, frames, times, depth = strip(tiny_clip_realistic, tmp_path)
    H, W = clip.height, clip.width
    assert H % 2 == 0 and W % 2 == 0
    src = clip.load_tracks_prior()
    np.savez(
        tmp_path / "tracks.npz",
        tracks=np.transpose(src.tracks, (1, 0, 2)) - 0.5,  # [T, N, 2], integer pixel centres
        visibility=src.visible.T,
    )
    flow = tmp_path / "flow"
    flow.mkdir()
    f = np.broadcast_to(np.array([2.0, -1.0], np.float32), (H, W, 2))
    np.save(flow / "0_1.npy", f)
    np.save(flow / "1_0.npy", -f)
    opt = ImportOptions(
        frames=frames,
        exposures=times,
        depth=depth,
        tracks=tmp_path / "tracks.npz",
        flow=flow,
        width=W // 2,
    )
    new = Clip.open(import_clip(tmp_path / "half", opt))
    new.validate()
    assert (new.width, new.height) == (W // 2, H // 2)
    assert new.meta.generator["resized_from"] == [H, W]
    for i, g in enumerate(clip.train_frames):
        blocks = clip.load_ldr(g).astype(np.float64).reshape(H // 2, 2, W // 2, 2, 3).mean((1, 3))
        assert np.abs(new.load_ldr(i).astype(np.float64) - blocks).max() <= 1.0
        assert new.load_depth_prior(i).shape == (H // 2, W // 2)
    got = new.load_tracks_prior()
    v = got.visible
    x, y = src.tracks[..., 0], src.tracks[..., 1]  # outside the frame: invisible, as unscaled
    vis = src.visible & (x >= 0) & (x < W) & (y >= 0) & (y < H)
    keep = vis.sum(1) >= 2
    assert np.array_equal(v, vis[keep])
    assert np.allclose(got.tracks[v], src.tracks[keep][v] / 2, atol=1e-5)
    fs = new.load_flow_prior()
    assert fs.pairs.tolist() == [[0, 1], [1, 0]] and fs.flow.shape == (2, H // 2, W // 2, 2)
    assert np.allclose(fs.flow[0], [1.0, -0.5], atol=1e-6) and fs.valid.all()
    # flow of neither size names the file and the size it expects
    np.save(flow / "0_1.npy", np.zeros((H, W + 2, 2), np.float32))
    with pytest.raises(InputError, match=rf"0_1.npy: flow of shape .*expected \({H}, {W}, 2\)"):
        import_clip(tmp_path / "bad", opt)
    r = CliRunner().invoke(main, ["import-clip", "--width", "8", "--out", str(tmp_path / "x")])
    assert r.exit_code == 2 and "--width" in r.output


def test_larger_depth_maps_shrink_to_the_mean_of_their_valid_depths():
    """A depth map twice the frames' size: each frame pixel gets the mean of the valid (> 0) depths
    of its 2x2 block, 0 where the block has none; a smaller map is interpolated bilinearly."""
    from m4dgs.footage import _resize

    d = np.array(
        [
            [1.0, 3.0, 0.0, 0.0],
            [5.0, 0.0, 0.0, 0.0],
            [2.0, 2.0, 8.0, 4.0],
            [2.0, 2.0, 0.0, 6.0],
        ]
    )
    got = _resize(d, 2, 2, valid=d > 0)
    assert np.allclose(got, [[3.0, 0.0], [2.0, 6.0]])
    # without a mask (flow), a plain block mean
    assert np.allclose(_resize(d, 2, 2), [[2.25, 0.0], [2.0, 4.5]])
    up = _resize(np.array([[1.0, 3.0]]), 1, 4)  # bilinear, pixel centres at +0.5
    assert np.allclose(up, [[1.0, 1.5, 2.5, 3.0]])


def test_depth_of_every_source_frame_with_every_n(tmp_path):
    """9 source frames kept every 2nd are 5 frames (0, 2, 4, 6, 8): 9 depth maps, one per source
    frame, give those 5 (it once asked for 2 x 5 = 10)."""
    from m4dgs.footage import read_depth

    (tmp_path / "d").mkdir()
    for i in range(9):
        np.save(tmp_path / "d" / f"{i}.npy", np.full((4, 6), i + 1.0))
    np.save(tmp_path / "all.npy", np.stack([np.full((4, 6), i + 1.0) for i in range(9)]))
    for src in (tmp_path / "d", tmp_path / "all.npy"):
        d = read_depth(ImportOptions(depth=src, every=2), 5, 4, 6)
        assert d[:, 0, 0].tolist() == [1.0, 3.0, 5.0, 7.0, 9.0]
    with pytest.raises(InputError, match="depth"):
        read_depth(ImportOptions(depth=tmp_path / "d", every=2), 6, 4, 6)


def alternating_capture(clip_dir, root):
    """Every frame of the tiny clip as a camera would have captured it with exposures cycling
    through the observed levels (training frames: the input; test frames: their gt LDR at the
    level the cycle gives), the exposure times in seconds and the gt depth of every frame."""
    clip = Clip.open(clip_dir)
    obs = clip.meta.exposures.observed
    frames, depth = root / "frames", root / "depth"
    frames.mkdir(parents=True)
    depth.mkdir()
    lines, levels = [], {}
    for g in clip.meta.frames:
        if g in clip.train_frames:
            dt, img = clip.meta.train_dt_of(g), clip.load_ldr(g)
        else:
            dt = obs[g % len(obs)]
            img = clip.load_gt_ldr(dt, g)
        levels[g] = dt
        Image.fromarray(img).save(frames / f"c{g:02d}.png")
        lines.append(f"c{g:02d}.png {dt / 100.0}")
        np.save(depth / f"{g:02d}.npy", clip.load_gt_depth(g))
    (root / "times.txt").write_text("\n".join(lines) + "\n")
    return clip, frames, root / "times.txt", depth, levels


def test_alternate_split_holds_out_odd_frames_scored_at_their_own_exposure(
    tiny_clip_realistic, tmp_path, short_training
):
    from eval.cli import main as eval_main
    from eval.experiments.score import score_run

    clip, frames, times, depth, levels = alternating_capture(tiny_clip_realistic, tmp_path)
    out = tmp_path / "mine"
    r = CliRunner().invoke(
        main,
        ["import-clip", "--frames", str(frames), "--exposures", str(times), "--depth", str(depth)]
        + ["--split", "alternate", "--out", str(out)],
    )
    assert r.exit_code == 0, r.output
    new = Clip.open(out, validate="full")
    G = clip.meta.num_frames
    assert new.train_frames == list(range(0, G, 2)) and new.test_frames == list(range(1, G, 2))
    unit = float(np.exp(np.mean(np.log(sorted(set(levels.values()))))))
    assert new.meta.exposures.test_dt == pytest.approx([levels[g] / unit for g in new.test_frames])
    assert new.has_gt and not new.has_gt_part("hdr") and new.meta.exposures.novel == []
    for g in new.test_frames:
        (lv,) = new.meta.test_levels_of(g)
        assert np.array_equal(
            new.load_gt_ldr(lv, g), np.asarray(Image.open(frames / f"c{g:02d}.png"))
        )
    for g in new.train_frames:  # one depth map per frame given: the training ones taken
        assert np.allclose(new.load_depth_prior(g), clip.load_gt_depth(g), rtol=1e-6)
    assert list(new.load_tracks_prior().frames) == new.train_frames

    run = train(out, tmp_path / "run", preset="tiny", overrides=short_training, progress=False)
    m = score_run(run)
    # LDR-OE: the mean over the test images, each against its own frame (PSNR by hand)
    ps = []
    for g in new.test_frames:
        (lv,) = new.meta.test_levels_of(g)
        pred = np.asarray(
            Image.open(run / "renders/test/ldr" / f"{lv:g}" / frame_name(g, "png")), np.float64
        )
        gt = new.load_gt_ldr(lv, g).astype(np.float64)
        ps.append(-10.0 * np.log10(np.mean((pred / 255.0 - gt / 255.0) ** 2)))
    assert m["ldr_oe_psnr"] == pytest.approx(float(np.mean(ps)), abs=1e-6)
    assert sorted(m["per_level"]) == sorted(
        {f"{new.meta.test_levels_of(g)[0]:g}" for g in new.test_frames}
    )
    assert m["ldr_ne_psnr"] is None and m["hdr_psnr"] is None
    assert "hdr_tae_dis_flow" in m["conventions"] and m["hdr_tae"] is not None
    # another method's frames, LDR only at each test frame's own level: the same LDR-OE
    pred = tmp_path / "pred"
    for g in new.test_frames:
        (lv,) = new.meta.test_levels_of(g)
        d = pred / "test/ldr" / f"{lv:g}"
        d.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(
            run / "renders/test/ldr" / f"{lv:g}" / frame_name(g, "png"), d / frame_name(g, "png")
        )
    r = CliRunner().invoke(
        eval_main,
        ["score-frames", "--clip", str(out), "--pred", str(pred), "--name", "other"]
        + ["--out", str(tmp_path / "other")],
    )
    assert r.exit_code == 0, r.output
    other = json.loads((tmp_path / "other" / "metrics.json").read_text())
    assert other["ldr_oe_psnr"] == pytest.approx(m["ldr_oe_psnr"], abs=1e-9)


def test_alternate_split_refuses_a_test_exposure_no_training_frame_has(
    tiny_clip_realistic, tmp_path
):
    clip, frames, times, depth, levels = alternating_capture(tiny_clip_realistic, tmp_path)
    lines = times.read_text().splitlines()
    lines[3] = lines[3].split()[0] + " 0.5"  # test frame 3 at a level of its own
    times.write_text("\n".join(lines) + "\n")
    opt = ImportOptions(frames=frames, exposures=times, depth=depth, split="alternate")
    with pytest.raises(InputError, match=r"test frame 3 \(c03\.png\)"):
        import_clip(tmp_path / "mine", opt)
    assert not (tmp_path / "mine").exists()
