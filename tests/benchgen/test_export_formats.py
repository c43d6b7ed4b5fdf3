"""`benchgen export --format` and `m4dgs import-clip --format` (docs/clip-format.md
"Other formats"): an export and its import give the clip back, the exported cameras put the
ground-truth 3D points on their ground-truth pixels when projected as each format's own
documentation says (code written here, not this project's camera code), hand-made folders in each
format import, and bad folders fail in one line naming the file and the field."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from benchgen.cli import main as benchgen_main
from m4dgs.cli import main as m4dgs_main
from m4dgs.clip import Clip, frame_name
from m4dgs.core import io as mio

FORMATS = ("mono4dgs-hdr", "nerfies")


def _export_import(clip_dir: Path, fmt: str, tmp: Path):
    exp, imp = tmp / f"exp-{fmt}", tmp / f"imp-{fmt}"
    r = CliRunner().invoke(
        benchgen_main, ["export", str(clip_dir), "--format", fmt, "--out", str(exp)]
    )
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(
        m4dgs_main, ["import-clip", "--format", fmt, str(exp), "--out", str(imp)]
    )
    assert r.exit_code == 0, r.output
    return exp, imp


def _files(root: Path, sub: str):
    return sorted(p.relative_to(root) for p in (root / sub).rglob("*") if p.is_file())


@pytest.fixture(scope="module")
def exported(tiny_clip_oracle, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("formats")
    return {fmt: _export_import(Path(tiny_clip_oracle), fmt, tmp) for fmt in FORMATS}


@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip(tiny_clip_oracle, exported, fmt):
    src_dir = Path(tiny_clip_oracle)
    _, imp = exported[fmt]
    src, back = Clip.open(src_dir), Clip.open(imp, validate="full")
    a, b = src.meta, back.meta
    assert (a.split, a.exposures, a.crf) == (b.split, b.exposures, b.crf)
    assert (a.width, a.height, a.fps, a.unit_exposure_value, a.hdr_scale) == (
        b.width,
        b.height,
        b.fps,
        b.unit_exposure_value,
        b.hdr_scale,
    )
    # frames byte for byte: training frames, test frames at every level, HDR ground truth, and
    # (Nerfies) the held-out views with their masks
    subs = ["input/ldr", "gt/ldr", "gt/hdr"]
    if fmt == "nerfies":
        subs += ["gt/views", "gt/masks/dynamic"]
        assert back.view_names() == src.view_names() and src.view_names()
    for sub in subs:
        files = _files(src_dir, sub)
        if sub == "gt/views":  # depth is a float map, compared below
            files = [f for f in files if "/depth/" not in str(f)]
        assert files and files == [
            f for f in _files(imp, sub) if sub != "gt/views" or "/depth/" not in str(f)
        ], sub
        for f in files:
            assert (src_dir / f).read_bytes() == (imp / f).read_bytes(), f
    # cameras to float precision
    ca, cb = src.load_gt_cameras(), back.load_gt_cameras()
    assert ca.frames.tolist() == cb.frames.tolist()
    np.testing.assert_allclose(cb.K, ca.K, rtol=1e-12, atol=0)
    np.testing.assert_allclose(cb.c2w, ca.c2w, rtol=0, atol=1e-12)
    for view in back.view_names():
        va, vb = src.load_view_cameras(view), back.load_view_cameras(view)
        np.testing.assert_allclose(vb.K, va.K, rtol=1e-12, atol=0)
        np.testing.assert_allclose(vb.c2w, va.c2w, rtol=0, atol=1e-12)
        for g in src.test_frames:
            np.testing.assert_array_equal(
                src.load_view_depth(view, g), back.load_view_depth(view, g)
            )
    # priors: depth exactly, tracks to float precision
    for g in src.train_frames:
        np.testing.assert_array_equal(src.load_depth_prior(g), back.load_depth_prior(g))
    ta, tb = src.load_tracks_prior(), back.load_tracks_prior()
    np.testing.assert_array_equal(ta.visible, tb.visible)
    np.testing.assert_allclose(tb.tracks, ta.tracks, rtol=0, atol=1e-4)
    if fmt == "nerfies":
        for g in a.frames:
            np.testing.assert_array_equal(src.load_gt_depth(g), back.load_gt_depth(g))


# --------------------------------------------------------------------------------------------------
# independent checks: each format read as its own documentation describes it
# --------------------------------------------------------------------------------------------------
def _gt_points(clip_dir: Path):
    z = np.load(clip_dir / "gt/tracks.npz")
    return z["points3d"].astype(np.float64), z["tracks"].astype(np.float64), z["visible"]


def test_nerfies_cameras_project_gt_points(tiny_clip_oracle, exported):
    """Nerfies camera JSON: local = orientation @ (p - position); x, y = local.xy / local.z;
    pixel = (focal x + skew y + cx, focal * pixel_aspect_ratio * y + cy), pixel centres at +0.5
    (google/nerfies camera model) -- the clip's gt/tracks.npz pixels use the same centres."""
    exp, _ = exported["nerfies"]
    p3, px, vis = _gt_points(Path(tiny_clip_oracle))
    meta = json.loads((exp / "metadata.json").read_text())
    ds = json.loads((exp / "dataset.json").read_text())
    checked = 0
    for iid in ds["ids"]:
        e = meta[iid]
        if e["camera_id"] != 0:
            continue
        g = e["warp_id"]
        cam = json.loads((exp / "camera" / f"{iid}.json").read_text())
        R = np.array(cam["orientation"])
        local = (p3[:, g] - np.array(cam["position"])) @ R.T
        x, y = local[:, 0] / local[:, 2], local[:, 1] / local[:, 2]
        u = cam["focal_length"] * x + cam["skew"] * y + cam["principal_point"][0]
        v = cam["focal_length"] * cam["pixel_aspect_ratio"] * y + cam["principal_point"][1]
        m = vis[:, g]
        err = np.hypot(u - px[:, g, 0], v - px[:, g, 1])[m]
        assert m.sum() > 10 and err.max() < 1e-3, (iid, err.max())
        assert np.all(local[m, 2] > 0)
        assert cam["image_size"] == [72, 40]
        checked += 1
    assert checked == 9
    # the splits DyCheck reads: train = the path's training frames, val = test frames + views
    val = json.loads((exp / "splits/val.json").read_text())
    assert sorted(set(val["camera_ids"])) == [1, 2, 3]  # the held-out views
    assert all((exp / "covisible/1x/val" / f"{n}.png").is_file() for n in val["frame_names"])
    path = json.loads((exp / "splits/val_path.json").read_text())
    assert set(path["camera_ids"]) == {0} and len(path["frame_names"]) == 4
    assert sorted(ds["val_ids"]) == sorted(val["frame_names"] + path["frame_names"])
    assert all(
        f"{c}_{t:05d}" == n
        for n, t, c in zip(val["frame_names"], val["time_ids"], val["camera_ids"])
    )
    assert len(ds["train_ids"]) == ds["num_exemplars"] == 5


def test_nerfies_view_cameras_see_gt_points_at_their_depth(tiny_clip_oracle, exported):
    """The validation cameras (held-out views, camera_id >= 1): the ground-truth 3D points of a test
    instant, projected through a view's camera JSON as Nerfies does, land on pixels whose depth/1x
    z-depth (rendered from that view) is the point's own z: most points agree to 2 % (the rest are
    occluded in the view, or sit on a depth edge within their pixel)."""
    exp, _ = exported["nerfies"]
    p3, _, vis = _gt_points(Path(tiny_clip_oracle))
    meta = json.loads((exp / "metadata.json").read_text())
    views = [i for i, e in meta.items() if e["camera_id"] >= 1]
    assert len(views) == 3 * 4  # 3 views x 4 test frames
    agree = []
    for iid in views:
        g = meta[iid]["warp_id"]
        cam = json.loads((exp / "camera" / f"{iid}.json").read_text())
        depth = np.load(exp / "depth/1x" / f"{iid}.npy")[..., 0]
        local = (p3[vis[:, g], g] - np.array(cam["position"])) @ np.array(cam["orientation"]).T
        z = local[:, 2]
        u = cam["focal_length"] * local[:, 0] / z + cam["principal_point"][0]
        v = cam["focal_length"] * cam["pixel_aspect_ratio"] * local[:, 1] / z
        v = v + cam["principal_point"][1]
        w, h = cam["image_size"]
        m = (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        d = depth[v[m].astype(int), u[m].astype(int)]
        agree.append(np.abs(d - z[m]) <= 0.02 * z[m])
    agree = np.concatenate(agree)
    assert agree.size > 100 and agree.mean() > 0.8, agree.mean()  # 0.89 measured
    assert all((exp / "covisible/1x/val" / f"{i}.png").is_file() for i in views)


def test_mono4dgs_hdr_layout_and_cameras(tiny_clip_oracle, exported):
    """The official loader's layout: images/ and train/ the training frames, exposures.json log2
    exposure per file name, test/ at an observed and test_ne/ at a novel level, train_exr/ and
    test_exr/ the HDR frames in the order of the names. cameras_gt.json (the clip's gt camera file:
    K and camera-to-world, OpenCV) projects the ground-truth points with p_cam = inverse(c2w) p,
    pixel = K p_cam / z."""
    clip_dir = Path(tiny_clip_oracle)
    exp, _ = exported["mono4dgs-hdr"]
    src = Clip.open(clip_dir)
    ex = json.loads((exp / "exposures.json").read_text())
    assert ex["train_exp_num"] == len(src.meta.exposures.observed)
    images = sorted(p.name for p in (exp / "images").iterdir())
    assert images == sorted(p.name for p in (exp / "train").iterdir()) == sorted(ex["train"])
    for i, name in enumerate(images):
        assert 2 ** ex["train"][name] == pytest.approx(src.meta.exposures.train_dt[i], rel=1e-12)
        assert (exp / "images" / name).read_bytes() == (clip_dir / "input/ldr" / name).read_bytes()
    assert sorted(ex["test"]) == sorted(p.name for p in (exp / "test").iterdir())
    assert sorted(ex["test_ne"]) == sorted(p.name for p in (exp / "test_ne").iterdir())
    for key, folder, levels in (
        ("test", "test", src.meta.exposures.observed),
        ("test_ne", "test_ne", src.meta.exposures.novel),
    ):
        used = set()
        for name, lg in ex[key].items():
            level = min(levels, key=lambda v: abs(math.log2(v) - lg))
            assert abs(math.log2(level) - lg) < 1e-12
            used.add(level)
            gt = clip_dir / "gt/ldr" / f"{level:g}" / name
            assert (exp / folder / name).read_bytes() == gt.read_bytes()
        assert used == set(levels)  # every level is scored on some test frame
    assert len(list((exp / "train_exr").iterdir())) == len(images)
    assert len(list((exp / "test_exr").iterdir())) == len(ex["test"])
    z = np.load(exp / "prior_depth" / images[0].replace(".png", ".npz"))
    assert z["dep"].shape == (40, 72)
    taps = list(exp.glob("*_tap.npz"))
    assert len(taps) == 1 and np.load(taps[0])["tracks"].shape[0] == len(images)

    cams = json.loads((exp / "cameras_gt.json").read_text())
    p3, px, vis = _gt_points(clip_dir)
    for i, g in enumerate(cams["frames"]):
        K, c2w = np.array(cams["K"][i]), np.array(cams["c2w"][i])
        w2c = np.linalg.inv(c2w)
        pc = p3[:, g] @ w2c[:3, :3].T + w2c[:3, 3]
        uv = (pc @ K.T)[:, :2] / pc[:, 2:3]
        m = vis[:, g]
        assert m.sum() > 10 and np.abs(uv - px[:, g])[m].max() < 1e-3


# --------------------------------------------------------------------------------------------------
# folders made by hand in each format
# --------------------------------------------------------------------------------------------------
def _frames(n, h=24, w=32, seed=0):
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 256, (h + n, w + n, 3), dtype=np.uint8)
    return [np.ascontiguousarray(base[i : i + h, i : i + w]) for i in range(n)]


def _tracks_npz(path, T, N=20, centre=0.0):
    rng = np.random.default_rng(1)
    xy = rng.uniform(2, 20, (T, N, 2)).astype(np.float32) + np.float32(centre)
    np.savez(path, tracks=xy, visibility=np.ones((T, N), bool))
    return xy


def test_mono4dgs_hdr_folder_made_by_hand(tmp_path):
    """The paper's naming (not frame numbers): training frame i becomes frame 2i, test frame j frame
    2j + 1; test/ is the LDR-OE ground truth at its own exposure, test_ne/ is kept and listed; the
    folder's depth and track files are its priors (tracks: pixel centres at integers)."""
    src = tmp_path / "Dog"
    fr = _frames(7)
    names = [f"frame_{i:04d}.png" for i in range(7)]
    train, test = names[0::2], names[1::2]
    exps = [-3.0, 1.0, 5.0]
    ex = {"train_exp_num": 3, "train": {}, "test": {}, "test_ne": {}}
    for i, n in enumerate(train):
        mio.write_png(src / "images" / n, fr[2 * i])
        ex["train"][n] = exps[i % 3]
        (src / "depthcrafter_depth").mkdir(exist_ok=True)
        np.savez(
            src / "depthcrafter_depth" / n.replace(".png", ".npz"), dep=np.full((24, 32), 2.0 + i)
        )
    for j, n in enumerate(test):
        mio.write_png(src / "test" / n, fr[2 * j + 1])
        mio.write_png(src / "test_ne" / n, fr[2 * j + 1][::-1].copy())
        ex["test"][n] = exps[j % 3]
        ex["test_ne"][n] = -1.0
    (src / "exposures.json").write_text(json.dumps(ex))
    xy = _tracks_npz(src / "uniform_dep=depthcrafter_bootstapir_tap.npz", len(train))
    out = tmp_path / "clip"
    r = CliRunner().invoke(
        m4dgs_main, ["import-clip", "--format", "mono4dgs-hdr", str(src), "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    c = Clip.open(out, validate="full")
    assert c.train_frames == [0, 2, 4, 6] and c.test_frames == [1, 3, 5]
    assert c.meta.exposures.train_dt == [0.125, 2.0, 32.0, 0.125]
    assert c.meta.exposures.test_dt == [0.125, 2.0, 32.0]
    assert c.meta.crf is None and c.meta.unit_exposure_value == 0.5  # no HDR: real data
    assert (out / "input/ldr/00002.png").read_bytes() == (src / "images" / train[1]).read_bytes()
    np.testing.assert_array_equal(c.load_gt_ldr(2.0, 3), fr[3])
    np.testing.assert_array_equal(c.load_gt_ldr(0.5, 5), fr[5][::-1])
    assert c.meta.gt["test_ne"] == {"1": 0.5, "3": 0.5, "5": 0.5}
    assert float(c.load_depth_prior(4).mean()) == 4.0
    np.testing.assert_allclose(c.load_tracks_prior().tracks, np.swapaxes(xy, 0, 1) + 0.5)

    # that clip (real data: one level per test frame, no HDR, no cameras) exported and imported
    # again is the same clip
    exp, again = tmp_path / "exp", tmp_path / "again"
    r = CliRunner().invoke(
        benchgen_main, ["export", str(out), "--format", "mono4dgs-hdr", "--out", str(exp)]
    )
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (exp / "test_ne").iterdir()) == [
        "00001.png",
        "00003.png",
        "00005.png",
    ]
    assert not (exp / "test_levels").exists()  # one level per test frame: test/ is all there is
    r = CliRunner().invoke(
        m4dgs_main, ["import-clip", "--format", "mono4dgs-hdr", str(exp), "--out", str(again)]
    )
    assert r.exit_code == 0, r.output
    b = Clip.open(again, validate="full")
    assert (b.meta.split, b.meta.exposures) == (c.meta.split, c.meta.exposures)
    assert b.meta.gt["test_ne"] == c.meta.gt["test_ne"]
    for sub in ("input/ldr", "gt/ldr/0.125", "gt/ldr/2", "gt/ldr/32", "gt/ldr/0.5"):
        files = _files(out, sub)
        assert files and files == _files(again, sub)
        assert all((out / f).read_bytes() == (again / f).read_bytes() for f in files)
    np.testing.assert_allclose(
        b.load_tracks_prior().tracks, c.load_tracks_prior().tracks, atol=1e-4
    )


def _nerfies_camera(t, f=30.0):
    # a DyCheck-style camera: OpenGL-looking world, the camera looking down -z of the world
    ang = 0.05 * t
    Ry = np.array(
        [[math.cos(ang), 0, math.sin(ang)], [0, 1, 0], [-math.sin(ang), 0, math.cos(ang)]]
    )
    return {
        "orientation": (np.diag([1.0, -1.0, -1.0]) @ Ry).tolist(),
        "position": [0.1 * t, 0.0, 3.0],
        "focal_length": f,
        "principal_point": [32.0, 24.0],
        "skew": 0.0,
        "pixel_aspect_ratio": 1.0,
        "radial_distortion": [0.0, 0.0, 0.0],
        "tangential_distortion": [0.0, 0.0],
        "image_size": [64, 48],
    }


def _nerfies_folder(root: Path, n=6):
    """A Nerfies capture at rgb/2x/: a monocular camera 0 (even times train, odd validate) and a
    second camera at the training times (a Nerfies 'vrig' validation camera)."""
    fr = _frames(n)
    ids, train, val, meta = [], [], [], {}
    for t in range(n):
        for c in (0, 1):
            iid = f"{c}_{t:05d}"
            if c == 1 and t % 2:
                continue
            mio.write_png(root / "rgb/2x" / f"{iid}.png", fr[t])
            (root / "camera").mkdir(parents=True, exist_ok=True)
            (root / "camera" / f"{iid}.json").write_text(json.dumps(_nerfies_camera(t + c)))
            (root / "depth/2x").mkdir(parents=True, exist_ok=True)
            np.save(root / "depth/2x" / f"{iid}.npy", np.full((24, 32, 1), 1.5, np.float32))
            meta[iid] = {"warp_id": t, "appearance_id": t, "camera_id": c}
            ids.append(iid)
            (train if c == 0 and t % 2 == 0 else val).append(iid)
    (root / "dataset.json").write_text(
        json.dumps(
            {
                "count": len(ids),
                "num_exemplars": len(train),
                "ids": ids,
                "train_ids": train,
                "val_ids": val,
            }
        )
    )
    (root / "metadata.json").write_text(json.dumps(meta))
    (root / "scene.json").write_text(
        json.dumps({"center": [0, 0, 0], "scale": 1.0, "near": 0.1, "far": 9})
    )
    return fr


def test_nerfies_folder_made_by_hand(tmp_path):
    src = tmp_path / "cap"
    fr = _nerfies_folder(src)
    xy = _tracks_npz(tmp_path / "tracks.npz", 3)
    out = tmp_path / "clip"
    r = CliRunner().invoke(
        m4dgs_main,
        [
            "import-clip",
            "--format",
            "nerfies",
            str(src),
            "--tracks",
            str(tmp_path / "tracks.npz"),
            "--out",
            str(out),
        ],
    )
    assert r.exit_code == 0, r.output
    c = Clip.open(out, validate="full")
    assert c.train_frames == [0, 2, 4] and c.test_frames == [1, 3, 5]
    assert c.meta.exposures.train_dt == [1.0, 1.0, 1.0] and c.meta.exposures.test_dt == [1.0] * 3
    np.testing.assert_array_equal(c.load_ldr(2), fr[2])
    np.testing.assert_array_equal(c.load_gt_ldr(1.0, 3), fr[3])
    # rgb/2x: the cameras' image domain halved; the Nerfies camera -> OpenCV camera-to-world
    cams = c.load_gt_cameras()
    cam = _nerfies_camera(3)
    np.testing.assert_allclose(cams.K[3], [[15, 0, 16], [0, 15, 12], [0, 0, 1]])
    np.testing.assert_allclose(cams.c2w[3][:3, :3], np.array(cam["orientation"]).T)
    np.testing.assert_allclose(cams.c2w[3][:3, 3], cam["position"])
    assert float(c.load_depth_prior(0).mean()) == 1.5  # the capture's depth as the prior
    # --tracks as for any footage: --track-pixel-centre 0 by default
    np.testing.assert_allclose(c.load_tracks_prior().tracks, np.swapaxes(xy, 0, 1) + 0.5)
    assert c.view_names() == []  # camera 1 images the training times: not a clip view
    assert "camera1" in c.meta.gt["views_not_imported"]


# --------------------------------------------------------------------------------------------------
# bad input: one line naming the file and the field
# --------------------------------------------------------------------------------------------------
def _one_line_error(args, *needles):
    r = CliRunner().invoke(m4dgs_main, args)
    assert r.exit_code == 1, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1, r.output
    for n in needles:
        assert n in lines[0], lines[0]


def test_bad_nerfies_folders(tmp_path):
    src = tmp_path / "cap"
    _nerfies_folder(src)
    args = ["import-clip", "--format", "nerfies", str(src), "--out", str(tmp_path / "o")]
    cam = src / "camera/0_00002.json"
    good = cam.read_text()
    d = json.loads(good)
    d["radial_distortion"] = [0.1, 0, 0]
    cam.write_text(json.dumps(d))
    _one_line_error(args, str(cam), "'radial_distortion'")
    d = json.loads(good)
    del d["orientation"]
    cam.write_text(json.dumps(d))
    _one_line_error(args, str(cam), "'orientation'", "missing")
    d = json.loads(good)
    d["image_size"] = [640, 480]
    cam.write_text(json.dumps(d))
    _one_line_error(args, str(cam), "'image_size'")
    d = json.loads(good)
    d["orientation"] = [[1, 0, 0], [0, 1, 0], [0, 0, 2]]
    cam.write_text(json.dumps(d))
    _one_line_error(args, str(cam), "'orientation'", "not a rotation")
    cam.write_text(good)
    md = src / "metadata.json"
    m = json.loads(md.read_text())
    m["0_00004"]["warp_id"] = "four"
    md.write_text(json.dumps(m))
    _one_line_error(args, str(md), "'0_00004.warp_id'")
    assert not (tmp_path / "o").exists()


def test_bad_mono4dgs_hdr_folders(tmp_path, tiny_clip_oracle, exported):
    exp, _ = exported["mono4dgs-hdr"]
    import shutil

    src = tmp_path / "m"
    shutil.copytree(exp, src)
    args = ["import-clip", "--format", "mono4dgs-hdr", str(src), "--out", str(tmp_path / "o")]
    exf = src / "exposures.json"
    ex = json.loads(exf.read_text())
    del ex["train"]["00004.png"]
    exf.write_text(json.dumps(ex))
    _one_line_error(args, str(exf), "'train.00004.png'", "missing")
    ex["train"]["00004.png"] = "bright"
    exf.write_text(json.dumps(ex))
    _one_line_error(args, str(exf), "'train.00004.png'")
    del ex["train"]
    exf.write_text(json.dumps(ex))
    _one_line_error(args, str(exf), "'train'", "missing")
    _one_line_error(["import-clip", str(src), "--out", str(tmp_path / "o")], "--format")
    assert not (tmp_path / "o").exists()


def test_export_refuses(tmp_path, tiny_clip_oracle):
    out = tmp_path / "full"
    (out / "x").mkdir(parents=True)
    r = CliRunner().invoke(
        benchgen_main, ["export", str(tiny_clip_oracle), "--format", "nerfies", "--out", str(out)]
    )
    assert r.exit_code == 1 and "--force" in r.output and len(r.output.strip().splitlines()) == 1


def test_export_needs_cameras_for_nerfies(tmp_path, tiny_clip_oracle):
    """A clip without cameras (from an HDR video, or real footage) has no Nerfies export; the
    Mono4DGS-HDR export needs none."""
    import shutil

    clip = tmp_path / "nocam"
    shutil.copytree(tiny_clip_oracle, clip)
    (clip / "gt/cameras.json").unlink()
    shutil.rmtree(clip / "gt/views")
    args = ["export", str(clip), "--out", str(tmp_path / "o")]
    r = CliRunner().invoke(benchgen_main, args + ["--format", "nerfies"])
    assert r.exit_code == 1 and len(r.output.strip().splitlines()) == 1, r.output
    assert str(clip / "gt/cameras.json") in r.output and not (tmp_path / "o").exists()
    r = CliRunner().invoke(benchgen_main, args + ["--format", "mono4dgs-hdr"])
    assert r.exit_code == 0, r.output
    assert not (tmp_path / "o/cameras_gt.json").exists()


def _paper_style_folder(clip: Clip, src: Path) -> None:
    """The clip written out as the paper's preprocessed data look: frame names, not numbers; one
    observed and one novel level per test frame; HDR in train_exr/ and test_exr/; a
    depthcrafter_depth/ folder; no track file."""
    ex = clip.meta.exposures
    table = {"train_exp_num": len(ex.observed), "train": {}, "test": {}, "test_ne": {}}
    for i, g in enumerate(clip.train_frames):
        n = f"frame_{i:03d}.png"
        copy = (src / "images" / n, src / "train_exr" / f"frame_{i:03d}.exr")
        for p in copy:
            p.parent.mkdir(parents=True, exist_ok=True)
        copy[0].write_bytes(clip.path("input/ldr", frame_name(g, "png")).read_bytes())
        copy[1].write_bytes(clip.path("gt/hdr", frame_name(g, "exr")).read_bytes())
        table["train"][n] = math.log2(clip.meta.train_dt_of(g))
        (src / "depthcrafter_depth").mkdir(exist_ok=True)
        np.savez(src / "depthcrafter_depth" / f"frame_{i:03d}.npz", dep=clip.load_depth_prior(g))
    for j, g in enumerate(clip.test_frames):
        n = f"test_{j:03d}.png"
        oe, ne = ex.observed[j % len(ex.observed)], ex.novel[j % len(ex.novel)]
        for folder, lv, key in (("test", oe, "test"), ("test_ne", ne, "test_ne")):
            (src / folder).mkdir(exist_ok=True)
            (src / folder / n).write_bytes(
                clip.path("gt/ldr", f"{lv:g}", frame_name(g, "png")).read_bytes()
            )
            table[key][n] = math.log2(lv)
        (src / "test_exr").mkdir(exist_ok=True)
        (src / "test_exr" / f"test_{j:03d}.exr").write_bytes(
            clip.path("gt/hdr", frame_name(g, "exr")).read_bytes()
        )
    (src / "exposures.json").write_text(json.dumps(table))


def _import_paper_style(tiny_clip_oracle, tmp_path):
    clip = Clip.open(tiny_clip_oracle)
    _paper_style_folder(clip, tmp_path / "Syn")
    out = tmp_path / "clip"
    args = ["import-clip", "--format", "mono4dgs-hdr", str(tmp_path / "Syn"), "--out", str(out)]
    r = CliRunner().invoke(m4dgs_main, args)
    assert r.exit_code == 0, r.output
    return clip, out


def test_paper_style_folder_imports(tiny_clip_oracle, tmp_path):
    """The paper's naming and one level per test frame: frames 2i / 2j + 1, HDR kept, DIS tracks."""
    clip, out = _import_paper_style(tiny_clip_oracle, tmp_path)
    ex = clip.meta.exposures
    c = Clip.open(out, validate="full")
    assert c.train_frames == clip.train_frames and c.test_frames == clip.test_frames
    assert c.meta.exposures.train_dt == ex.train_dt
    assert c.meta.exposures.test_dt == [ex.observed[j % len(ex.observed)] for j in range(4)]
    assert c.meta.unit_exposure_value == 0.73  # HDR ground truth: the paper's synthetic data
    for g in clip.meta.frames:
        a, b = out / "gt/hdr" / frame_name(g, "exr"), clip.path("gt/hdr", frame_name(g, "exr"))
        assert a.read_bytes() == b.read_bytes()
    assert c.meta.priors["tracks"]["num"] > 20  # chained through DIS flow


def test_paper_style_folder_trains(tiny_clip_oracle, tmp_path, short_training):
    """... and our trainer runs on it (a short training: ~6 s on an idle core, more when shared)."""
    from m4dgs.run import RunDir
    from m4dgs.training.pipeline import train

    _, out = _import_paper_style(tiny_clip_oracle, tmp_path)
    run = train(out, tmp_path / "run", preset="tiny", overrides=short_training, progress=False)
    assert RunDir(run).done


def _rot(axis, deg):
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    t = math.radians(deg)
    return np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * k @ k


def test_nerfies_export_with_estimated_cameras(tiny_clip_oracle, tmp_path):
    """Estimated cameras of the training frames only, here the truth in another frame (x0.5,
    turned 30 degrees, moved): the training images get them as given; every other image (the
    path's test frames, the held-out views) gets its true camera in that frame, so the true 3D
    points, moved into that frame, project through the camera JSON (read as Nerfies does, written
    here) onto their true pixels, and the views' depth files hold the points' z in its units."""
    clip = Clip.open(tiny_clip_oracle)
    gt = clip.load_gt_cameras()
    s, R, t = 2.0, _rot([0.3, 1.0, 0.2], 30.0), np.array([0.5, -1.0, 2.0])  # c_gt = s R c + t
    rows = [list(gt.frames).index(g) for g in clip.train_frames]
    est = []
    for i in rows:
        c = np.eye(4)
        c[:3, :3] = R.T @ gt.c2w[i][:3, :3]
        c[:3, 3] = R.T @ (gt.c2w[i][:3, 3] - t) / s
        est.append(c)
    f = tmp_path / "cameras_ba.json"
    f.write_text(
        json.dumps(
            {
                "frames": clip.train_frames,
                "K": gt.K[rows].tolist(),
                "c2w": np.stack(est).tolist(),
            }
        )
    )
    exp = tmp_path / "exp"
    r = CliRunner().invoke(
        benchgen_main,
        ["export", str(tiny_clip_oracle), "--format", "nerfies", "--out", str(exp)]
        + ["--cameras", str(f)],
    )
    assert r.exit_code == 0, r.output
    extra = json.loads((exp / "extra.json").read_text())
    assert extra["cameras"] == "estimated"
    assert extra["similarity_to_truth"]["s"] == pytest.approx(s, rel=1e-9)
    p3, px, vis = _gt_points(Path(tiny_clip_oracle))
    p_est = (p3 - t) @ R / s  # the points in the estimated frame
    meta = json.loads((exp / "metadata.json").read_text())
    checked, agree = {"train": 0, "other": 0}, []
    for iid, e in meta.items():
        g = e["warp_id"]
        cam = json.loads((exp / "camera" / f"{iid}.json").read_text())
        local = (p_est[:, g] - np.array(cam["position"])) @ np.array(cam["orientation"]).T
        x, y = local[:, 0] / local[:, 2], local[:, 1] / local[:, 2]
        u = cam["focal_length"] * x + cam["skew"] * y + cam["principal_point"][0]
        v = cam["focal_length"] * cam["pixel_aspect_ratio"] * y + cam["principal_point"][1]
        if e["camera_id"] == 0:
            m = vis[:, g]
            assert np.hypot(u - px[:, g, 0], v - px[:, g, 1])[m].max() < 1e-3, iid
            checked["train" if g in clip.train_frames else "other"] += 1
            if g in clip.train_frames:  # as given
                np.testing.assert_allclose(cam["position"], est[clip.train_frames.index(g)][:3, 3])
        else:
            depth = np.load(exp / "depth/1x" / f"{iid}.npy")[..., 0]
            w, h = cam["image_size"]
            ok = vis[:, g] & (local[:, 2] > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
            d = depth[v[ok].astype(int), u[ok].astype(int)]
            agree.append(np.abs(d - local[ok, 2]) <= 0.02 * local[ok, 2])
            checked["other"] += 1
    assert checked == {"train": 5, "other": 4 + 12}
    agree = np.concatenate(agree)  # as with the true cameras (occluded points, depth edges)
    assert agree.size > 100 and agree.mean() > 0.8, agree.mean()
    bad = tmp_path / "few.json"
    bad.write_text(json.dumps({"frames": [0], "K": [gt.K[0].tolist()], "c2w": [est[0].tolist()]}))
    r = CliRunner().invoke(
        benchgen_main,
        ["export", str(tiny_clip_oracle), "--format", "nerfies", "--out", str(tmp_path / "x")]
        + ["--cameras", str(bad)],
    )
    assert r.exit_code != 0 and "few.json" in r.output and "training frame" in r.output
