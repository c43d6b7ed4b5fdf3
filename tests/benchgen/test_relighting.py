"""benchgen.relighting: the change of light on static surfaces over time, against answers known
by construction (a texture under a light whose strength follows a known curve)."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from benchgen.relighting import clip_relighting, static_relighting
from m4dgs.core.io import write_exr

T, H, W = 20, 24, 40


def _texture(seed=0):
    rng = np.random.default_rng(seed)
    return 0.2 + rng.random((H, W + T))  # wider than the frame: the camera pans over it


def _scene(gain, pan=0):
    """Luminance [T, H, W] of a textured wall lit by gain[t], the camera panning `pan` px a frame,
    and the exact tracks of every pixel of the first frame that stays in view."""
    tex = _texture()
    lum = np.stack([gain[t] * tex[:, t * pan : t * pan + W] for t in range(T)])
    ys, xs = np.mgrid[2 : H - 2, 2 + T * pan : W - 2].reshape(2, -1)  # points on the wall
    tracks = np.stack([np.stack([xs - t * pan, ys], -1) for t in range(T)], 1).astype(np.float32)
    visible = np.ones(tracks.shape[:2], bool)
    return lum, tracks, visible, np.zeros(len(xs), bool)


def test_constant_light_is_one_even_when_the_camera_moves():
    lum, tracks, visible, dynamic = _scene(np.ones(T), pan=1)
    r = static_relighting(lum, tracks, visible, dynamic)
    assert r["points"] == len(tracks) and math.isclose(r["median_ratio"], 1.0, abs_tol=1e-9)
    assert r["relit_fraction"] == 0.0


@pytest.mark.parametrize("pan", [0, 1])
def test_a_light_that_brightens_gives_the_ratio_of_its_percentiles(pan):
    gain = np.linspace(1.0, 8.0, T)
    lum, tracks, visible, dynamic = _scene(gain, pan)
    r = static_relighting(lum, tracks, visible, dynamic)
    want = np.percentile(gain, 90) / np.percentile(gain, 10)
    assert math.isclose(r["median_ratio"], want, rel_tol=1e-9) and r["relit_fraction"] == 1.0


def test_moving_points_unseen_frames_and_short_tracks_are_left_out():
    lum, tracks, visible, dynamic = _scene(np.ones(T))
    n = len(tracks)
    # a moving point whose pixel flickers, and a static one seen on too few frames, both on a
    # pixel made to flicker: neither may count
    lum[::2, 5, 5] *= 50.0
    extra = np.tile(np.array([5.0, 5.0], np.float32), (2, T, 1))
    tracks = np.concatenate([tracks, extra])
    vis_short = np.zeros((1, T), bool)
    vis_short[0, :9] = True
    visible = np.concatenate([visible, np.ones((1, T), bool), vis_short])
    dynamic = np.concatenate([dynamic, [True, False]])
    # and a static point on the same pixel, seen only on the frames where it is dark
    tracks = np.concatenate([tracks, extra[:1]])
    vis_odd = np.zeros((1, T), bool)
    vis_odd[0, 1::2] = True
    visible = np.concatenate([visible, vis_odd])
    dynamic = np.concatenate([dynamic, [False]])
    r = static_relighting(lum, tracks, visible, dynamic)
    assert r["points"] == n + 1  # the original points and the one seen on its 10 dark frames
    # the original points next to the flickering pixel see it through the box mean; the last one
    # saw only dark frames and so a constant light
    assert math.isclose(r["median_ratio"], 1.0, abs_tol=1e-9)
    only_last = static_relighting(lum, tracks[-1:], visible[-1:], dynamic[-1:])
    assert only_last["points"] == 1 and math.isclose(only_last["median_ratio"], 1.0, abs_tol=1e-12)
    flicker = static_relighting(lum, tracks[-1:], np.ones((1, T), bool), dynamic[-1:])
    assert flicker["median_ratio"] > 5.0  # the same point seen on every frame does see the flicker


def test_no_qualifying_point_and_mismatched_shapes():
    lum, tracks, visible, dynamic = _scene(np.ones(T))
    r = static_relighting(lum, tracks, visible, np.ones_like(dynamic))
    assert r == {"median_ratio": None, "relit_fraction": None, "points": 0}
    with pytest.raises(ValueError, match="do not match"):
        static_relighting(lum[:-1], tracks, visible, dynamic)


def _write_clip(root: Path, gain):
    lum, tracks, visible, dynamic = _scene(gain)
    (root / "gt" / "hdr").mkdir(parents=True)
    for t in range(T):
        write_exr(
            root / "gt" / "hdr" / f"{t:05d}.exr",
            np.repeat(lum[t][..., None], 3, -1).astype(np.float32),
        )
    np.savez(
        root / "gt" / "tracks.npz",
        tracks=tracks,
        visible=visible,
        dynamic=dynamic,
        frames=np.arange(T),
    )


def test_clip_relighting_reads_the_ground_truth(tmp_path):
    assert clip_relighting(tmp_path) is None  # no gt/tracks.npz
    gain = np.where(np.arange(T) < T // 2, 1.0, 4.0)  # a light switched up half way
    _write_clip(tmp_path / "c", gain)
    r = clip_relighting(tmp_path / "c")
    assert math.isclose(r["median_ratio"], 4.0, rel_tol=1e-5) and r["relit_fraction"] == 1.0
    (tmp_path / "c" / "gt" / "hdr" / "00007.exr").unlink()
    with pytest.raises(FileNotFoundError, match="00007.exr"):
        clip_relighting(tmp_path / "c")
    np.savez(tmp_path / "c" / "gt" / "tracks.npz", tracks=np.zeros((1, T, 2)))
    with pytest.raises(ValueError, match="tracks.npz: no field 'visible'"):
        clip_relighting(tmp_path / "c")


def test_show_prints_the_relighting_of_a_generated_clip(tiny_clip_oracle):
    from benchgen.cli import main

    r = CliRunner().invoke(main, ["show", "--no-sheet", str(tiny_clip_oracle)])
    assert r.exit_code == 0, r.output
    printed = json.loads(r.output[r.output.index("{") : r.output.rindex("}") + 1])
    relit = printed["relighting"]
    assert (
        relit["points"] > 0
        and relit["median_ratio"] >= 1.0
        and 0.0 <= relit["relit_fraction"] <= 1.0
    )
    assert relit == clip_relighting(Path(tiny_clip_oracle))


def test_show_says_why_when_the_ground_truth_tracks_are_incomplete(tiny_clip_oracle, tmp_path):
    import shutil

    from benchgen.show import summary
    from m4dgs.clip import Clip

    root = tmp_path / "clip"
    shutil.copytree(tiny_clip_oracle, root)
    with np.load(root / "gt" / "tracks.npz") as d:
        kept = {k: d[k] for k in d.files if k != "dynamic"}
    np.savez(root / "gt" / "tracks.npz", **kept)
    s = summary(Clip.open(root))
    assert "no field 'dynamic'" in s["relighting"]["unavailable"] and s["frames"] > 0
