"""benchgen make as a whole: a finished clip validates, is deterministic for a seed, and resumes."""

from __future__ import annotations

import hashlib

import mitsuba as mi
import numpy as np
import pytest
import torch

from benchgen.make import make_clip as _make_clip
from benchgen.suite import builtin_scenes_dir
from m4dgs.clip import Clip, frame_name


def make_clip(*a, **kw):
    """tiny-flag-arm is a smoke-test scene: placement targets are tested in test_placement.py, not
    here."""
    return _make_clip(*a, allow_misplaced=True, **kw)


def _digest(root, rels):
    h = hashlib.sha256()
    for rel in rels:
        h.update((root / rel).read_bytes())
    return h.hexdigest()


def _inputs_and_priors(clip):
    rels = [f"input/ldr/{frame_name(g, 'png')}" for g in clip.train_frames]
    rels += [f"priors/depth/{frame_name(g, 'exr')}" for g in clip.train_frames]
    return rels + ["priors/tracks.npz", "priors/flow.npz"]


def test_clip_contract_and_ground_truth_notes(tiny_clip_realistic):
    clip = Clip.open(tiny_clip_realistic, validate="full")
    m = clip.meta
    assert m.exposures.schedule == "alternating"
    assert m.exposures.train_dt[:3] == [0.125, 2.0, 32.0]
    assert m.hdr_scale and m.hdr_scale > 0
    assert m.priors["profile"] == "realistic"
    for key in (
        "render_noise",
        "hdr_tae_floor",
        "hdr_tae_floor_interior",
        "dynamic_fraction",
        "dynamic_range_stops",
    ):
        assert key in m.gt, key
    # generator version 6: textures band-limited for the preset's grid, adaptive samples spent,
    # the exposure-ladder denoiser, and its error against a 1024-spp render recorded per band;
    # 7: held-out views of the test frames and the camera-motion statistics
    assert m.generator["version"] == 7
    assert set(m.gt["views"]) == {"small", "medium", "large"} and "camera_motion" in m.gt
    assert m.gt["render"]["denoise_ladder"] is True
    bias = m.gt["render_bias"]
    assert bias["reference_spp"] == 1024 and len(bias["median_rel_error"]) == 4
    assert all(0 <= e < 0.5 for e in bias["median_rel_error"]), bias
    assert m.gt["textures"]["band_limit_grid"] == [m.width, m.height]
    lo, hi = m.gt["textures"]["cutoff_cycles_per_side"]["flag"]
    assert 0 < lo <= hi
    assert m.gt["render"]["adaptive_spp"] > 0 and m.gt["render"]["adaptive_extra_spp_mean"] > 0
    # the scene needs merging: the longest observed exposure saturates somewhere
    long_g = [
        g
        for g, dt in zip(clip.train_frames, m.exposures.train_dt)
        if dt == max(m.exposures.observed)
    ][0]
    assert (clip.load_ldr(long_g) == 255).any()
    # flow prior only between frames of the same exposure level (t, t +- N_e)
    fs = clip.load_flow_prior()
    dt = dict(zip(clip.train_frames, m.exposures.train_dt))
    assert all(dt[int(a)] == dt[int(b)] for a, b in fs.pairs)


def test_same_seed_is_byte_identical_and_resume_skips(tiny_clip_realistic, tmp_path):
    first = Clip.open(tiny_clip_realistic)
    again = make_clip(
        builtin_scenes_dir() / "tiny-flag-arm.yaml",
        tmp_path / "again",
        preset="tiny",
        priors="realistic",
        seed=0,
        progress=False,
    )
    clip2 = Clip.open(again)
    rels = _inputs_and_priors(first)
    assert _digest(first.root, rels) == _digest(clip2.root, rels)
    # clip.json says where it was made: the Mitsuba variant that rendered it and the host
    host = clip2.meta.generator["host"]
    assert host["variant"] in ("llvm_ad_rgb", "scalar_rgb") and host["mitsuba"] == mi.__version__
    assert host["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    # a finished clip with the same settings is returned untouched
    before = (again / "clip.json").stat().st_mtime_ns
    make_clip(
        builtin_scenes_dir() / "tiny-flag-arm.yaml",
        again,
        preset="tiny",
        priors="realistic",
        seed=0,
        progress=False,
    )
    assert (again / "clip.json").stat().st_mtime_ns == before
    # an unfinished clip (no clip.json) resumes: rendered HDR frames are kept, the rest is rebuilt
    # identically
    (again / "clip.json").unlink()
    (again / "input/ldr" / frame_name(0, "png")).unlink()
    hdr_mtime = (again / "gt/hdr" / frame_name(3, "exr")).stat().st_mtime_ns
    make_clip(
        builtin_scenes_dir() / "tiny-flag-arm.yaml",
        again,
        preset="tiny",
        priors="realistic",
        seed=0,
        progress=False,
    )
    assert (again / "gt/hdr" / frame_name(3, "exr")).stat().st_mtime_ns == hdr_mtime
    assert _digest(first.root, rels) == _digest(again, rels)


def test_other_seed_changes_priors(tiny_clip_realistic, tmp_path):
    other = make_clip(
        builtin_scenes_dir() / "tiny-flag-arm.yaml",
        tmp_path / "seed1",
        preset="tiny",
        priors="realistic",
        seed=1,
        progress=False,
    )
    a = np.load(tiny_clip_realistic / "priors/tracks.npz")["tracks"]
    b = np.load(other / "priors/tracks.npz")["tracks"]
    assert a.shape != b.shape or not np.array_equal(a, b)


def test_spp_override_is_recorded_and_guards_resume(tmp_path):
    scene = builtin_scenes_dir() / "tiny-lamp-box.yaml"
    out = make_clip(
        scene,
        tmp_path / "c",
        preset="tiny",
        priors="oracle",
        seed=0,
        progress=False,
        max_frames=5,
        spp=16,
    )
    m = Clip.open(out).meta
    assert m.generator["spp"] == 16 and m.gt["render"]["spp"] == 16
    # the light selection chosen by the probe is the one the frames were rendered with, and it was
    # the least noisy
    probe = m.gt["emitter_sampling_probe"]
    assert probe["chosen"] == m.gt["render"]["emitter_sampling"]
    assert probe["noise_tae_two_seeds"][probe["chosen"]] == min(
        probe["noise_tae_two_seeds"].values()
    )
    # a finished clip made with other render settings is never silently mixed or overwritten
    with pytest.raises(FileExistsError, match="other settings"):
        make_clip(
            scene, out, preset="tiny", priors="oracle", seed=0, progress=False, max_frames=5, spp=64
        )
    with pytest.raises(ValueError, match="spp"):
        make_clip(
            scene, tmp_path / "bad", preset="tiny", priors="oracle", seed=0, progress=False, spp=0
        )


def test_track_density_follows_the_preset(tmp_path, monkeypatch):
    """The ground-truth query grid is the preset's: the grid step is sqrt(pixels / cells), the
    number of tracks grows with the lattice, and the oracle prior keeps every one of them."""
    import dataclasses

    import benchgen.make as bm

    scene = builtin_scenes_dir() / "tiny-lamp-box.yaml"
    counts, steps = {}, {}
    for grid in (64, 256):
        monkeypatch.setitem(
            bm.PRESETS,
            "tiny",
            dataclasses.replace(bm.PRESETS["tiny"], track_grid=grid, track_dynamic=0),
        )
        out = make_clip(
            scene,
            tmp_path / f"g{grid}",
            preset="tiny",
            priors="oracle",
            seed=0,
            progress=False,
            max_frames=3,
            spp=4,
        )
        clip = Clip.open(out)
        notes = clip.meta.gt["tracks"]
        assert notes["num_grid"] == grid and notes["num_dynamic"] == 0
        gt = np.load(out / "gt/tracks.npz")
        counts[grid] = notes["num"]
        assert gt["tracks"].shape[0] == counts[grid]
        # the queries of the first reference frame (frame 0) sit on pixel centres, on a grid of the
        # expected step
        first = gt["tracks"][:, 0][gt["visible"][:, 0]].astype(np.float64)
        on_centre = (np.abs((first - 0.5) - np.round(first - 0.5)) < 1e-3).all(axis=1)
        xs = np.unique(np.round(first[on_centre, 0], 3))
        steps[grid] = float(np.median(np.diff(xs)))
        # oracle keeps all
        assert np.load(out / "priors/tracks.npz")["tracks"].shape[0] == counts[grid]
    W, H = bm.PRESETS["tiny"].width, bm.PRESETS["tiny"].height
    lattice = {}
    for grid in (64, 256):
        step = round(np.sqrt(W * H / grid))
        assert steps[grid] == step
        lattice[grid] = len(range(step // 2, W, step)) * len(range(step // 2, H, step))
    # more tracks in proportion to the lattice points (not every grid pixel sees a surface)
    assert counts[256] / counts[64] == pytest.approx(lattice[256] / lattice[64], rel=0.2)
