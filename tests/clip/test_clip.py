"""Clip folder contract: a well-formed clip round-trips; each kind of malformed clip is rejected
with an error that names the file and the field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from m4dgs.clip import (
    Cameras,
    Clip,
    ClipError,
    ClipMeta,
    ClipWriter,
    Exposures,
    FlowSet,
    Split,
    TrackSet,
    frame_name,
    level_name,
)
from m4dgs.core import io as mio

W, H, G = 8, 6, 5


def make_clip(root: Path, with_gt: bool = True) -> Path:
    rng = np.random.default_rng(0)
    train, test = [0, 2, 4], [1, 3]
    meta = ClipMeta(
        name="unit",
        width=W,
        height=H,
        fps=30.0,
        frames=list(range(G)),
        split=Split(train, test),
        exposures=Exposures(
            train_dt=[0.125, 2.0, 32.0], observed=[0.125, 2.0, 32.0], novel=[0.5, 8.0]
        ),
        hdr_scale=1.5,
    )
    w = ClipWriter(root, meta)
    for g in train:
        w.write_input_ldr(g, rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
        w.write_prior_depth(g, rng.uniform(1, 3, (H, W)).astype(np.float32))
    w.write_prior_tracks(
        TrackSet(rng.uniform(0, W, (4, 3, 2)), np.ones((4, 3), bool), np.array(train))
    )
    w.write_prior_flow(
        FlowSet(np.array([[0, 2], [2, 0]]), rng.normal(size=(2, H, W, 2)), np.ones((2, H, W), bool))
    )
    if with_gt:
        for g in range(G):
            w.write_gt_hdr(g, rng.uniform(0, 10, (H, W, 3)).astype(np.float32))
            w.write_gt_depth(g, rng.uniform(1, 3, (H, W)).astype(np.float32))
            w.write_gt_dynamic_mask(g, rng.uniform(size=(H, W)) > 0.5)
        for lv in meta.exposures.observed + meta.exposures.novel:
            for g in test:
                w.write_gt_ldr(lv, g, rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
        K = np.tile(np.array([[10.0, 0, 4], [0, 10, 3], [0, 0, 1]]), (G, 1, 1))
        w.write_gt_cameras(Cameras(np.arange(G), K, np.tile(np.eye(4), (G, 1, 1))))
        w.write_gt_flow(
            FlowSet(
                np.array([[0, 2], [2, 0]]), rng.normal(size=(2, H, W, 2)), np.ones((2, H, W), bool)
            )
        )
        w.write_gt_tracks(
            TrackSet(
                rng.uniform(0, W, (4, G, 2)),
                np.ones((4, G), bool),
                np.arange(G),
                points3d=rng.normal(size=(4, G, 3)),
                dynamic=np.array([1, 0, 0, 1], bool),
            )
        )
    w.finalize()
    return root


@pytest.fixture()
def clip_dir(tmp_path):
    return make_clip(tmp_path / "clip")


def test_roundtrip(clip_dir):
    clip = Clip.open(clip_dir, validate="full")
    assert clip.meta.num_exposure_levels == 3
    assert clip.train_frames == [0, 2, 4] and clip.test_frames == [1, 3]
    assert clip.load_ldr(2).shape == (H, W, 3) and clip.load_ldr(2).dtype == np.uint8
    assert clip.load_gt_hdr(3).dtype == np.float32
    fl, va = clip.load_flow_prior().get(2, 0)
    assert fl.shape == (H, W, 2) and va.shape == (H, W)
    assert clip.load_gt_tracks().points3d.shape == (4, G, 3)
    assert clip.meta.train_dt_of(4) == 32.0
    assert (clip_dir / "gt/ldr" / level_name(0.5) / frame_name(1, "png")).exists()
    # ClipMeta survives a JSON round trip unchanged
    assert ClipMeta.from_dict(json.loads((clip_dir / "clip.json").read_text())) == clip.meta


def test_real_clip_without_gt(tmp_path):
    clip = Clip.open(make_clip(tmp_path / "real", with_gt=False), validate="full")
    assert not clip.has_gt
    with pytest.raises(ClipError, match="no ground truth"):
        clip.load_gt_hdr(0)


def test_exr_roundtrip_of_strided_arrays(tmp_path):
    a = np.random.default_rng(1).normal(size=(H, W, 2)).astype(np.float32)
    # a strided view: must be made contiguous before writing
    mio.write_exr(tmp_path / "x.exr", a[..., 1])
    np.testing.assert_array_equal(mio.read_exr(tmp_path / "x.exr"), a[..., 1])


def _edit_meta(clip_dir, fn):
    p = clip_dir / "clip.json"
    d = json.loads(p.read_text())
    fn(d)
    p.write_text(json.dumps(d))


def _expect(clip_dir, file_part: str, field_part: str, validate="full"):
    with pytest.raises(ClipError) as ei:
        Clip.open(clip_dir, validate=validate)
    msg = str(ei.value)
    assert file_part in msg and field_part in msg, msg


def test_missing_frame(clip_dir):
    (clip_dir / "input/ldr" / frame_name(2, "png")).unlink()
    _expect(clip_dir, "input/ldr/00002.png", "missing frame")


def test_missing_depth_prior(clip_dir):
    (clip_dir / "priors/depth" / frame_name(4, "exr")).unlink()
    _expect(clip_dir, "priors/depth/00004.exr", "<file>")


def test_wrong_shape_png(clip_dir):
    mio.write_png(clip_dir / "input/ldr" / frame_name(0, "png"), np.zeros((H + 1, W, 3), np.uint8))
    _expect(clip_dir, "input/ldr/00000.png", "'pixels'")


def test_wrong_shape_flow(clip_dir):
    mio.write_npz(
        clip_dir / "priors/flow.npz",
        pairs=np.array([[0, 2]]),
        flow=np.zeros((1, H, W, 3), np.float32),
        valid=np.ones((1, H, W), bool),
    )
    _expect(clip_dir, "priors/flow.npz", "'flow'")


def test_wrong_shape_tracks(clip_dir):
    mio.write_npz(
        clip_dir / "priors/tracks.npz",
        tracks=np.zeros((4, 2, 2), np.float32),
        visible=np.ones((4, 2), bool),
        frames=np.array([0, 2]),
    )
    _expect(clip_dir, "priors/tracks.npz", "'frames'")


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nonfinite_exr(clip_dir, bad):
    d = np.ones((H, W, 3), np.float32)
    d[1, 2, 0] = bad
    mio.write_exr(clip_dir / "gt/hdr" / frame_name(3, "exr"), d)
    _expect(clip_dir, "gt/hdr/00003.exr", "NaN or inf")


def test_nonfinite_depth_prior(clip_dir):
    d = np.ones((H, W), np.float32)
    d[0, 0] = np.nan
    mio.write_exr(clip_dir / "priors/depth" / frame_name(0, "exr"), d)
    _expect(clip_dir, "priors/depth/00000.exr", "NaN or inf")


@pytest.mark.parametrize("value", [0.0, -2.0])
def test_nonpositive_exposure(clip_dir, value):
    _edit_meta(clip_dir, lambda d: d["exposures"]["train_dt"].__setitem__(1, value))
    _expect(clip_dir, "clip.json", "exposures.train_dt[1]", validate="meta")


def test_nonpositive_observed_level(clip_dir):
    _edit_meta(clip_dir, lambda d: d["exposures"]["novel"].__setitem__(0, 0))
    _expect(clip_dir, "clip.json", "exposures.novel[0]", validate="meta")


def test_unknown_schema_version(clip_dir):
    _edit_meta(clip_dir, lambda d: d.__setitem__("schema_version", 99))
    _expect(clip_dir, "clip.json", "schema_version", validate="meta")


@pytest.mark.parametrize("which,index", [("train", 7), ("test", -1)])
def test_split_out_of_range(clip_dir, which, index):
    _edit_meta(clip_dir, lambda d: d["split"][which].__setitem__(-1, index))
    _expect(clip_dir, "clip.json", f"split.{which}", validate="meta")


def test_train_dt_length_mismatch(clip_dir):
    _edit_meta(clip_dir, lambda d: d["exposures"]["train_dt"].pop())
    _expect(clip_dir, "clip.json", "exposures.train_dt", validate="meta")


def test_missing_field_and_unknown_field(clip_dir):
    _edit_meta(clip_dir, lambda d: d.pop("width"))
    _expect(clip_dir, "clip.json", "'width'", validate="meta")
    make_clip(clip_dir)
    _edit_meta(clip_dir, lambda d: d.__setitem__("colour", 1))
    _expect(clip_dir, "clip.json", "'colour'", validate="meta")


def test_flow_pair_outside_training_frames(clip_dir):
    mio.write_npz(
        clip_dir / "priors/flow.npz",
        pairs=np.array([[0, 3]]),
        flow=np.zeros((1, H, W, 2), np.float32),
        valid=np.ones((1, H, W), bool),
    )
    _expect(clip_dir, "priors/flow.npz", "pairs[0]")


def test_camera_not_rigid(clip_dir):
    p = clip_dir / "gt/cameras.json"
    d = json.loads(p.read_text())
    d["c2w"][2][0][0] = 3.0
    p.write_text(json.dumps(d))
    _expect(clip_dir, "gt/cameras.json", "'c2w'")


def test_unfinished_clip_has_no_meta(tmp_path):
    (tmp_path / "c").mkdir()
    _expect(tmp_path / "c", "clip.json", "<file>", validate="meta")


def test_atomic_write_leaves_no_temp_files(tmp_path):
    mio.write_json(tmp_path / "a.json", {"x": 1})
    mio.write_png(tmp_path / "b.png", np.zeros((2, 2, 3), np.uint8))
    mio.write_npz(tmp_path / "c.npz", a=np.zeros(3))
    mio.write_exr(tmp_path / "d.exr", np.zeros((2, 2), np.float32))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.png", "c.npz", "d.exr"]


# -- content that makes training meaningless is refused before any compute
@pytest.mark.parametrize(
    "depth, needle",
    [(np.zeros((H, W)), "have a depth > 0"), (-np.ones((H, W)), "negative depths")],
)
def test_depth_prior_content(clip_dir, depth, needle):
    mio.write_exr(clip_dir / "priors/depth" / frame_name(2, "exr"), depth.astype(np.float32))
    _expect(clip_dir, "priors/depth/00002.exr", needle)


def test_tracks_off_image(clip_dir):
    tr = np.random.default_rng(1).uniform(0, 1, (4, 3, 2))  # normalised, then shifted far away
    mio.write_npz(
        clip_dir / "priors/tracks.npz",
        tracks=(tr * 10 * W).astype(np.float32),
        visible=np.ones((4, 3), bool),
        frames=np.array([0, 2, 4]),
    )
    _expect(clip_dir, "priors/tracks.npz", "outside")


def test_tracks_off_image_bound_tells_units_from_visibility_mistakes(clip_dir):
    """Tracks at twice the resolution (about half the points beyond the margin) are refused; a
    tail of visible points far outside, as a tracker's visibility mistakes leave in a fast pan
    (benchgen's window-pan-handheld: 5.7 %), loads as it is."""
    from m4dgs.clip import load_trackset

    rng = np.random.default_rng(2)
    n, frames = 400, np.array([0, 2, 4])
    inside = rng.uniform([0, 0], [W, H], (n, 3, 2))
    path = clip_dir / "priors/tracks.npz"
    mio.write_npz(path, tracks=(2 * inside).astype(np.float32), visible=np.ones((n, 3), bool),
                  frames=frames)  # fmt: skip
    _expect(clip_dir, "priors/tracks.npz", "outside")
    tail = inside.copy()
    tail[:24, 1, 0] = W + 0.5 * W  # 24 of 400 tracks on one frame: 2 % of the visible points
    tail[24:70, 2, 0] = -0.6 * W  # and 46 more on another: 5.8 % in all
    mio.write_npz(path, tracks=tail.astype(np.float32), visible=np.ones((n, 3), bool),
                  frames=frames)  # fmt: skip
    ts = load_trackset(path, 3, W, H)
    assert np.array_equal(ts.tracks, tail.astype(np.float32)) and ts.visible.all()


def test_tracks_never_visible_twice(clip_dir):
    vis = np.zeros((4, 3), bool)
    vis[:, 0] = True
    mio.write_npz(
        clip_dir / "priors/tracks.npz",
        tracks=np.ones((4, 3, 2), np.float32),
        visible=vis,
        frames=np.array([0, 2, 4]),
    )
    _expect(clip_dir, "priors/tracks.npz", "two or more frames")


def test_flow_absurd_magnitude(clip_dir):
    f = np.zeros((2, H, W, 2), np.float32)
    f[1, 0, 0, 0] = 1e30
    mio.write_npz(
        clip_dir / "priors/flow.npz",
        pairs=np.array([[0, 2], [2, 0]]),
        flow=f,
        valid=np.ones((2, H, W), bool),
    )
    _expect(clip_dir, "priors/flow.npz", "flow[1]")


def test_train_dt_not_an_observed_level(clip_dir):
    _edit_meta(clip_dir, lambda d: d["exposures"]["train_dt"].__setitem__(1, 1e6))
    _expect(clip_dir, "clip.json", "exposures.train_dt[1]", validate="meta")


@pytest.mark.parametrize("key, value", [("fps", float("nan")), ("crf", "no-such-curve")])
def test_meta_values(clip_dir, key, value):
    _edit_meta(clip_dir, lambda d: d.__setitem__(key, value))
    _expect(clip_dir, "clip.json", key, validate="meta")
