"""What a newcomer meets first on the benchgen side: the tiny demo's placement note on a shipped
scene, the summary `benchgen from-hdr` prints, the priors `benchgen show` lists, the contact
sheet's tracks and the depth-count error of `benchgen from-hdr`."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from benchgen.cli import main
from benchgen.from_hdr import HdrVideoOptions, clip_from_hdr_video
from benchgen.make import PlacementError, check_clip_placement, make_clip
from benchgen.suite import builtin_scenes_dir
from m4dgs.clip import Clip, TrackSet, frame_name
from m4dgs.core.errors import InputError

MISSED = {
    "targets": {
        "short_dark": {"value": 0.0, "wanted": ">= 0.005 of pixels <= 5", "met": False},
        "mid_median": {"value": 0.5, "wanted": "in [0.35, 0.65]", "met": True},
    }
}


@pytest.fixture(scope="module")
def video(tiny_clip_oracle, tmp_path_factory):
    """The tiny clip's gt HDR frames as an HDR video and its gt depth of every frame as one .npy
    per frame (as in test_from_hdr.py)."""
    src = Clip.open(tiny_clip_oracle)
    root = tmp_path_factory.mktemp("hdr-video-newcomer")
    (root / "hdr").mkdir()
    (root / "depth").mkdir()
    for g in src.meta.frames:
        shutil.copyfile(src.path("gt/hdr", frame_name(g, "exr")), root / "hdr" / f"f{g}.exr")
        np.save(root / "depth" / f"d{g:03d}.npy", src.load_gt_depth(g))
    return src, root


@pytest.fixture(scope="module")
def hdr_clip(video, tmp_path_factory):
    """A from-hdr clip made through the command line: (clip folder, the CliRunner result)."""
    src, root = video
    out = tmp_path_factory.mktemp("from-hdr-newcomer") / "mine"
    r = CliRunner().invoke(
        main,
        ["from-hdr", "--hdr", str(root / "hdr"), "--out", str(out)]
        + ["--depth", str(root / "depth"), "--allow-misplaced"],
    )
    assert r.exit_code == 0, r.output
    return out, r


# 1. the placement miss of a shipped smoke-test scene ----------------------------------------------
def test_a_shipped_smoke_test_scene_s_miss_does_not_ask_to_edit_its_spec(tiny_clip_oracle, capsys):
    """The tiny demo makes tiny-flag-arm, which misses a target at the tiny preset (its suite sets
    `placement: warn`): the note says the miss is expected, not that the user should change the
    spec. Asked for again, the finished clip is checked again (no render)."""
    meta = Clip.open(tiny_clip_oracle).meta
    assert not meta.gt["placement"]["all_met"]  # the case of the demo
    spec = builtin_scenes_dir() / "tiny-flag-arm.yaml"
    capsys.readouterr()
    out = make_clip(
        spec,
        tiny_clip_oracle,
        preset="tiny",
        priors="oracle",
        seed=0,
        progress=False,
        allow_misplaced=True,
    )
    assert out == tiny_clip_oracle
    err = capsys.readouterr().err
    assert "short_dark" in err and "gt.placement" in err and "expected" in err
    assert "scene spec" not in err and err.startswith("note: ")
    # not allowed (a suite of the user's listing it with `placement: require`): still an error,
    # naming the way to keep the clip, not the spec
    with pytest.raises(PlacementError) as e:
        check_clip_placement(tiny_clip_oracle, MISSED, False, spec, "tiny")
    assert "--allow-misplaced" in str(e.value) and "scene spec" not in str(e.value)


def test_placement_messages_by_whose_scene_it_is(tmp_path, capsys):
    # the user's own spec (a copy of a shipped one elsewhere): change the spec
    own = tmp_path / "my-scene.yaml"
    shutil.copyfile(builtin_scenes_dir() / "tiny-flag-arm.yaml", own)
    with pytest.raises(PlacementError, match="Change the scene spec"):
        check_clip_placement(tmp_path / "c", MISSED, False, own, "tiny")
    # a shipped benchmark scene (syn-exp-3 requires the targets): to report, not to edit
    bench = builtin_scenes_dir() / "lamp-room-orbit.yaml"
    with pytest.raises(PlacementError) as e:
        check_clip_placement(tmp_path / "c", MISSED, False, bench, "small")
    msg = str(e.value)
    assert "lamp-room-orbit" in msg and "report" in msg and "scene spec" not in msg
    check_clip_placement(tmp_path / "c", MISSED, True, bench, "small")
    assert capsys.readouterr().err.startswith("warning: ")


# 2. the summary of `benchgen from-hdr` ------------------------------------------------------------
def test_from_hdr_prints_a_summary_and_the_next_steps(hdr_clip):
    out, r = hdr_clip
    clip = Clip.open(out)
    assert r.stdout.strip().splitlines() == [str(out)]  # the path alone on stdout, for scripts
    err = r.stderr
    T, G = len(clip.train_frames), clip.meta.num_frames
    assert f"{G} frames" in err and f"{T} training" in err and f"{G - T} test" in err
    assert f"{clip.width}x{clip.height}" in err
    assert "0.125, 2, 32" in err and "novel 0.5, 8" in err
    assert f"depth {T} maps" in err and "tracks" in err
    assert f"m4dgs train --clip {out} --preset small" in err
    assert "m4dgs-eval score runs/mine/full" in err


# 3. the priors `benchgen show` lists --------------------------------------------------------------
def test_show_lists_the_priors_of_a_from_hdr_clip(hdr_clip, tiny_clip_oracle):
    out, _ = hdr_clip
    r = CliRunner().invoke(main, ["show", "--no-sheet", str(out)])
    assert r.exit_code == 0, r.output
    pv = json.loads(r.stdout)["priors"]
    clip = Clip.open(out)
    assert pv is not None and "profile" not in pv
    assert pv["depth"] == len(clip.train_frames)
    assert pv["tracks"] == clip.load_tracks_prior().tracks.shape[0] > 0
    assert pv["flow"] is None  # no --flow given
    assert pv["sources"]["depth"].endswith("depth") and "DIS" in pv["sources"]["tracks"]
    # a benchgen clip: its profile, and every prior file
    r = CliRunner().invoke(main, ["show", "--no-sheet", str(tiny_clip_oracle)])
    pv = json.loads(r.stdout)["priors"]
    b = Clip.open(tiny_clip_oracle)
    assert pv["profile"] == "oracle" and pv["depth"] == len(b.train_frames)
    assert pv["flow"] == len(b.load_flow_prior().pairs) > 0


# 4. the contact sheet's tracks --------------------------------------------------------------------
def test_tracks_not_visible_are_not_drawn_at_the_corner():
    """One track visible now at pixel (50, 20) whose earlier frames are occluded with placeholder
    (0, 0) coordinates or NaN, one never visible: only the dot at (50, 20) is drawn, nothing near
    the image's corner."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from benchgen.show import draw_tracks

    H, W, T = 40, 72, 5
    tr = np.zeros((3, T, 2), np.float32)
    vis = np.zeros((3, T), bool)
    tr[0, -1] = (50.5, 20.5)  # the centre of pixel (50, 20)
    vis[0, -1] = True
    tr[0, 1] = np.nan
    tr[1, :] = (10.5, 10.5)  # never visible
    tr[2, -1] = np.nan
    vis[2, -1] = True  # visible, but no coordinates
    ts = TrackSet(tr, vis, np.arange(T))

    def render(tracks):
        fig, ax = plt.subplots(figsize=(W / 10, H / 10), dpi=100)
        ax.imshow(np.zeros((H, W, 3), np.float32))
        ax.axis("off")
        if tracks is not None:
            draw_tracks(ax, tracks)
        ax.set_xlim(-0.5, W - 0.5)
        ax.set_ylim(H - 0.5, -0.5)
        fig.subplots_adjust(0, 0, 1, 1)
        fig.canvas.draw()
        img = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(int)
        to_px = ax.transData.transform
        plt.close(fig)
        return img, to_px

    img, to_px = render(ts)
    blank, _ = render(None)
    drawn = np.abs(img - blank).sum(-1) > 30
    h = img.shape[0]
    (x, y) = to_px((50, 20))
    r, c = int(round(h - y)), int(round(x))
    assert drawn[r - 2 : r + 3, c - 2 : c + 3].any()  # the visible point
    (x0, y0) = to_px((-0.5, -0.5))
    r0, c0 = int(round(h - y0)), int(round(x0))
    assert not drawn[max(r0 - 8, 0) : r0 + 8, max(c0 - 8, 0) : c0 + 8].any()  # nothing at (0, 0)
    far = drawn.copy()
    far[r - 6 : r + 7, c - 6 : c + 7] = False
    assert not far.any()  # nor anywhere else (a line from the corner, the never visible track)


# 5. the depth-count error of `benchgen from-hdr` --------------------------------------------------
def test_a_wrong_depth_count_names_every_accepted_count(video, tmp_path):
    src, root = video
    G = src.meta.num_frames
    T = len(range(0, G, 2))
    n = T + 2  # neither one per training frame nor one per HDR frame, here nor with 6 frames kept
    assert n not in (T, G, 3, 6)
    wrong = tmp_path / "depth-wrong"
    wrong.mkdir()
    for i in range(n):
        np.save(wrong / f"{i}.npy", src.load_gt_depth(0))
    with pytest.raises(InputError) as e:
        clip_from_hdr_video(tmp_path / "x", HdrVideoOptions(hdr=root / "hdr", depth=wrong))
    msg = str(e.value)
    assert str(wrong) in msg and f"{n} found" in msg
    assert f"{T} (one per training frame" in msg and f"{G} (one per HDR frame" in msg
    assert "\n" not in msg and not (tmp_path / "x").exists()
    # with --max-frames 6: 3 training frames, 6 HDR frames kept, or one per HDR file of the folder
    # (G), of which the kept training frames' are taken
    with pytest.raises(InputError) as e:
        clip_from_hdr_video(
            tmp_path / "y", HdrVideoOptions(hdr=root / "hdr", depth=wrong, max_frames=6)
        )
    msg = str(e.value)
    assert "3 (one per training frame" in msg and "6 (one per HDR frame kept" in msg
    assert f"{G} (one per HDR file in {root / 'hdr'}" in msg
    opt = HdrVideoOptions(
        hdr=root / "hdr", depth=root / "depth", max_frames=6, scale=1.0, allow_misplaced=True
    )
    clip = Clip.open(clip_from_hdr_video(tmp_path / "z", opt))
    assert clip.train_frames == [0, 2, 4]
    for g in clip.train_frames:
        assert np.allclose(clip.load_depth_prior(g), src.load_gt_depth(g), rtol=1e-6)
