"""Clips that differ only after the render (camera response, exposures, priors) take a finished
clip's render: the result equals a fresh clip's (ground truth byte for byte, HDR to float32
rounding), and a clip with another render is never taken."""

from __future__ import annotations

from functools import partial
from types import SimpleNamespace

import numpy as np
import pytest

import benchgen.clip_pass as bpass
import benchgen.render as brender
from benchgen.make import RENDER_OUTPUTS, make_clip, sibling_clips
from benchgen.suite import builtin_scenes_dir
from m4dgs.clip import Clip, frame_name
from m4dgs.core import io as mio

# a smoke-test scene (placement targets: test_placement.py); 3 frames at 4 spp: seconds
SCENE = builtin_scenes_dir() / "tiny-lamp-box.yaml"
make = partial(
    make_clip,
    SCENE,
    preset="tiny",
    priors="oracle",
    seed=0,
    progress=False,
    max_frames=3,
    allow_misplaced=True,
)


def _files(root, rel):
    p = root.joinpath(*rel)
    return (
        sorted(q.relative_to(root) for q in p.rglob("*") if q.is_file())
        if p.is_dir()
        else [p.relative_to(root)]
    )


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """base: hdrnerf; fresh: srgb-shoulder rendered anew; reused: srgb-shoulder from base's render
    (the renderer is not called)."""
    root = tmp_path_factory.mktemp("reuse")
    base = make(root / "syn-exp-3" / "tiny-lamp-box", spp=4, crf="hdrnerf")
    fresh = make(root / "fresh" / "tiny-lamp-box", spp=4, crf="srgb-shoulder")
    mp = pytest.MonkeyPatch()

    def no_render(*a, **kw):
        raise AssertionError("the render was not reused")

    mp.setattr(bpass, "render_clip_gt", no_render)
    mp.setattr(brender, "choose_emitter_sampling", no_render)
    try:
        reused = make(
            root / "syn-exp-3-crf-srgb-shoulder" / "tiny-lamp-box",
            spp=4,
            crf="srgb-shoulder",
            # an unfinished clip and this clip's own folder are passed over
            render_from=[
                root / "unfinished",
                root / "syn-exp-3-crf-srgb-shoulder" / "tiny-lamp-box",
                base,
            ],
        )
    finally:
        mp.undo()
    return SimpleNamespace(root=root, base=base, fresh=fresh, reused=reused)


def test_reused_render_equals_a_fresh_one(clips):
    fresh, reused = (
        Clip.open(clips.fresh, validate="full"),
        Clip.open(clips.reused, validate="full"),
    )
    mf, mr = fresh.meta, reused.meta
    assert mr.gt["render_key"] == mf.gt["render_key"] == Clip.open(clips.base).meta.gt["render_key"]
    assert mr.gt["render_source"] == "../../syn-exp-3/tiny-lamp-box"
    assert "render_source" not in mf.gt
    # every ground-truth file of the render, byte for byte
    for rel in RENDER_OUTPUTS:
        names = _files(clips.fresh, rel)
        assert names == _files(clips.reused, rel) and names, rel
        for n in names:
            assert (clips.fresh / n).read_bytes() == (clips.reused / n).read_bytes(), n
    # the render's notes (noise, floors, bias) are the base clip's, which are the fresh clip's
    for k in ("render_noise", "hdr_tae_floor", "render_bias", "tracks"):
        assert mr.gt[k] == mf.gt[k], k
    # HDR: the base clip's gt/hdr / its scale * this clip's scale, to float32 rounding
    assert mr.hdr_scale == pytest.approx(mf.hdr_scale, rel=1e-5)
    for g in mf.frames:
        a = mio.read_exr(clips.fresh / "gt/hdr" / frame_name(g, "exr"))
        b = mio.read_exr(clips.reused / "gt/hdr" / frame_name(g, "exr"))
        np.testing.assert_allclose(b, a, rtol=3e-6, atol=0)
    # the 8-bit inputs: the same codes (a code may flip only where the HDR sits on a rounding edge)
    for g in fresh.train_frames:
        a, b = (c.load_ldr(g).astype(np.int16) for c in (fresh, reused))  # uint8 codes
        assert np.abs(a - b).max() <= 1
        assert (a != b).mean() <= 1e-3
    # the held-out views come with the render: geometry byte for byte, HDR to float32 rounding
    assert reused.view_names() == fresh.view_names() == ["small", "medium", "large"]
    assert mr.gt["views"] == mf.gt["views"] and mr.gt["camera_motion"] == mf.gt["camera_motion"]
    for v in fresh.view_names():
        for part in ("depth", "masks/dynamic", "covis", "cameras.json"):
            rel = ("gt", "views", v, *part.split("/"))
            names = _files(clips.fresh, rel)
            assert names and names == _files(clips.reused, rel), (v, part)
            for n in names:
                assert (clips.fresh / n).read_bytes() == (clips.reused / n).read_bytes(), n
        for g in fresh.test_frames:
            np.testing.assert_allclose(
                reused.load_view_hdr(v, g), fresh.load_view_hdr(v, g), rtol=3e-6, atol=0
            )
    # the unit-scale frames are gone once the clip is finished, as for a rendered clip
    assert not (clips.reused / ".benchgen" / "hdr_unit").exists()


def test_another_render_is_not_taken(clips, tmp_path):
    calls = []
    real = bpass.render_clip_gt

    def counting(*a, **kw):
        calls.append(1)
        return real(*a, **kw)

    mp = pytest.MonkeyPatch()
    mp.setattr(bpass, "render_clip_gt", counting)
    try:
        # another sample count is another render: the base clip is offered but not taken
        out = make(
            tmp_path / "x" / "tiny-lamp-box", spp=16, crf="aces-filmic", render_from=[clips.base]
        )
    finally:
        mp.undo()
    assert calls == [1]
    m = Clip.open(out).meta
    assert "render_source" not in m.gt
    assert m.gt["render_key"] != Clip.open(clips.base).meta.gt["render_key"]


def test_sibling_clips_and_clip_waves(clips, tmp_path):
    from eval.experiments.runner import clip_waves

    assert sibling_clips(clips.root, "tiny-lamp-box") == sorted(
        [clips.base, clips.fresh, clips.reused]
    )
    # an unfinished clip (no clip.json) is no candidate
    (tmp_path / "s" / "tiny-lamp-box").mkdir(parents=True)
    assert sibling_clips(tmp_path, "tiny-lamp-box") == []
    J = SimpleNamespace
    todo = [J(scene="a", k=0), J(scene="a", k=1), J(scene="b", k=2), J(scene="a", k=3)]
    waves = clip_waves(todo)
    assert [[j.k for j in w] for w in waves] == [[0, 2], [1, 3]]
    assert clip_waves([]) == []


def test_cli_passes_the_reuse_root(tmp_path, monkeypatch):
    from click.testing import CliRunner

    import benchgen.make as bm
    from benchgen.cli import main as benchgen_main

    seen = []
    monkeypatch.setattr(bm, "make_suite", lambda *a, **kw: seen.append(kw["reuse_root"]) or [])
    r = CliRunner().invoke(
        benchgen_main, ["make", "--suite", "tiny", "--reuse-renders", str(tmp_path)]
    )
    assert r.exit_code == 0, r.output
    assert seen == [str(tmp_path)]
    r = CliRunner().invoke(
        benchgen_main, ["make", "--suite", "tiny", "--reuse-renders", str(tmp_path / "nope")]
    )
    assert r.exit_code != 0 and "does not exist" in r.output


def test_priors_only_sibling_has_the_same_inputs(clips):
    """A clip that differs from its render's source in the priors alone takes the source's HDR
    scale and HDR frames: its inputs are the same bytes (the comparison between the two isolates
    the priors), while the crf sibling above chose its own scale from the rebuilt unit frames."""
    import benchgen.make as bm

    mp = pytest.MonkeyPatch()
    chosen = []
    real_choose = bm.choose_hdr_scale

    def counting(*a, **kw):
        chosen.append(1)
        return real_choose(*a, **kw)

    mp.setattr(bpass, "render_clip_gt", lambda *a, **kw: pytest.fail("render not reused"))
    mp.setattr(bm, "choose_hdr_scale", counting)
    try:
        out = make(
            clips.root / "syn-exp-3-priors-realistic" / "tiny-lamp-box",
            spp=4,
            crf="hdrnerf",
            priors="realistic",
            render_from=[clips.base],
        )
    finally:
        mp.undo()
    assert chosen == []  # the scale was taken, not chosen again
    base, sib = Clip.open(clips.base), Clip.open(out, validate="full")
    assert sib.meta.hdr_scale == base.meta.hdr_scale
    assert sib.meta.gt["hdr_scale_report"] == base.meta.gt["hdr_scale_report"]
    for rel in (("input",), ("gt", "hdr"), ("gt", "ldr")):
        names = _files(clips.base, rel)
        assert names == _files(out, rel) and names, rel
        for n in names:
            assert (clips.base / n).read_bytes() == (out / n).read_bytes(), n
    # the priors are the sibling's own
    assert sib.meta.priors["profile"] == "realistic" != base.meta.priors["profile"]
    # the crf sibling's scale was chosen for its own response
    state = mio.read_json(clips.reused / ".benchgen" / "state.json")
    assert state["scale_key"] != mio.read_json(clips.base / ".benchgen" / "state.json")["scale_key"]


def test_scale_key_follows_what_step_3_reads(clips):
    """scale_key changes with the response, the exposure times and the targets, not with the
    priors or the trainer seed."""
    from benchgen.make import scale_key
    from benchgen.placement import PlacementTargets
    from m4dgs.core.crf import clip_crf

    job = SimpleNamespace(
        state={"render_key": "r"},
        crf=clip_crf("hdrnerf"),
        settings=__import__("benchgen.exposure", fromlist=["ExposureSettings"]).ExposureSettings(),
        train=[0, 2],
        test=[1],
        priors="oracle",
        seed=0,
    )
    t = PlacementTargets()
    k = scale_key(job, [0.125, 2.0], t)
    assert k == scale_key(
        SimpleNamespace(**{**vars(job), "priors": "harsh", "seed": 3}), [0.125, 2.0], t
    )
    assert k != scale_key(
        SimpleNamespace(**{**vars(job), "crf": clip_crf("aces-filmic")}), [0.125, 2.0], t
    )
    assert k != scale_key(job, [0.125, 32.0], t)
    assert k != scale_key(job, [0.125, 2.0], PlacementTargets(mid_median=(0.3, 0.7)))
    assert k != scale_key(
        SimpleNamespace(**{**vars(job), "state": {"render_key": "s"}}), [0.125, 2.0], t
    )


def test_profile_file_changes_only_its_family(clips, tmp_path):
    """A profile file (realistic with harsh's disparity shift) makes a clip of the same render
    whose depth prior differs from the realistic sibling's while its tracks, flow and inputs are
    the same bytes; a file that repeats harsh's parameters gives harsh's priors bytes."""
    import dataclasses

    import yaml

    from benchgen.priors import HARSH

    shift = tmp_path / "shift.yaml"
    shift.write_text("base: realistic\ndepth_disp_shift: 0.08\n")
    like_harsh = tmp_path / "like-harsh.yaml"
    params = {k: v for k, v in dataclasses.asdict(HARSH).items() if k != "name"}
    like_harsh.write_text(yaml.safe_dump({"base": "oracle", **params}))
    made = {}
    for name, prof in (
        ("realistic", "realistic"),
        ("shift", str(shift)),
        ("harsh", "harsh"),
        ("like-harsh", str(like_harsh)),
    ):
        made[name] = make(
            clips.root / f"syn-exp-3-priors-{name}" / "tiny-lamp-box",
            spp=4,
            crf="hdrnerf",
            priors=prof,
            render_from=[clips.base],
        )
    real, sh = made["realistic"], made["shift"]
    meta = Clip.open(sh).meta
    assert meta.priors["profile"] == "shift" and meta.priors["params"]["depth_disp_shift"] == 0.08
    assert meta.generator["priors"].startswith("shift@")
    # (3 frames: no flow pairs, so no flow prior)
    assert not (real / "priors" / "flow.npz").exists() and not (sh / "priors" / "flow.npz").exists()
    for rel in (("input",), ("priors", "tracks.npz")):
        for n in _files(real, rel):
            assert (real / n).read_bytes() == (sh / n).read_bytes(), n
    depth = _files(real, ("priors", "depth"))
    assert depth and any((real / n).read_bytes() != (sh / n).read_bytes() for n in depth)
    for n in _files(made["harsh"], ("priors",)):
        assert (made["harsh"] / n).read_bytes() == (made["like-harsh"] / n).read_bytes(), n


def test_profile_file_errors_name_the_file_and_key(tmp_path):
    from benchgen.priors import REALISTIC, load_profile
    from m4dgs.core.errors import InputError

    ok = tmp_path / "ok.yaml"
    ok.write_text("base: realistic\ntrack_jitter_px: 1.5\ndepth_scale_stops: [1, 3]\n")
    p = load_profile(ok)
    assert p.name == "ok" and p.track_jitter_px == 1.5 and p.depth_scale_stops == (1.0, 3.0)
    assert p.depth_noise_rel == REALISTIC.depth_noise_rel
    for text, what in [
        ("base: nope\n", "base"),
        ("track_jiter_px: 1\n", "track_jiter_px"),
        ("track_jitter_px: -1\n", "track_jitter_px"),
        ("track_jitter_px: yes\n", "track_jitter_px"),
        ("track_vis_window: 2.5\n", "track_vis_window"),
        ("depth_scale_stops: [3, 1]\n", "depth_scale_stops"),
        ("depth_scale_stops: [a, 1]\n", "depth_scale_stops"),
        ("track_vis_flip_prob: 1.5\n", "track_vis_flip_prob"),
        ("depth_emitter_pull: 2\n", "depth_emitter_pull"),
        ("name: harsh\n", "name"),
        ("- 1\n", "mapping"),
    ]:
        bad = tmp_path / "bad.yaml"
        bad.write_text(text)
        with pytest.raises(InputError) as e:
            load_profile(bad)
        assert str(bad) in str(e.value) and what in str(e.value), (text, str(e.value))


def test_cli_takes_a_profile_file_and_refuses_a_bad_one(tmp_path, monkeypatch):
    from click.testing import CliRunner

    import benchgen.make as bm
    from benchgen.cli import main as benchgen_main

    seen = []
    monkeypatch.setattr(bm, "make_suite", lambda *a, **kw: seen.append(kw["priors"]) or [])
    prof = tmp_path / "p.yaml"
    prof.write_text("base: harsh\nflow_noise_px: 0.5\n")
    r = CliRunner().invoke(benchgen_main, ["make", "--suite", "tiny", "--priors", str(prof)])
    assert r.exit_code == 0, r.output
    assert seen == [str(prof)]
    prof.write_text("flow_noize_px: 0.5\n")
    r = CliRunner().invoke(benchgen_main, ["make", "--suite", "tiny", "--priors", str(prof)])
    assert r.exit_code != 0 and "flow_noize_px" in r.output and seen == [str(prof)]
    r = CliRunner().invoke(benchgen_main, ["make", "--suite", "tiny", "--priors", "medium"])
    assert r.exit_code != 0 and "neither a built-in profile" in r.output


def test_a_changed_spec_is_not_finished_with_the_old_renders(tmp_path):
    """A clip folder holds the renders of a spec (resume state and clip.json carry its render key,
    which covers the spec's bytes). Made again after the spec changed: refused without force, and
    with force rendered anew (the new wall colour shows in gt/hdr), never finished with the old
    frames."""
    from benchgen.make import make_clip
    from benchgen.suite import builtin_scenes_dir

    spec = tmp_path / "tiny-lamp-box.yaml"
    text = (builtin_scenes_dir() / "tiny-lamp-box.yaml").read_text()
    spec.write_text(text)
    out = tmp_path / "clip"
    kw = dict(preset="tiny", priors="oracle", max_frames=5, allow_misplaced=True)
    make_clip(spec, out, **kw)
    before = mio.read_exr(out / "gt/hdr/00000.exr")
    # the back wall's stripes from grey-brown to saturated green
    spec.write_text(
        text.replace("[[0.6, 0.5, 0.4], [0.2, 0.2, 0.25]]", "[[0.1, 0.8, 0.1], [0.05, 0.4, 0.05]]")
    )
    with pytest.raises(FileExistsError, match="render key"):
        make_clip(spec, out, **kw)
    # an unfinished clip of the old spec (clip.json gone, the resume state kept) is refused too
    (out / "clip.json").unlink()
    with pytest.raises(FileExistsError, match="render key"):
        make_clip(spec, out, **kw)
    make_clip(spec, out, force=True, **kw)
    after = mio.read_exr(out / "gt/hdr/00000.exr")
    g_over_r = lambda a: float(a[..., 1].mean() / max(a[..., 0].mean(), 1e-9))  # noqa: E731
    assert g_over_r(after) > 1.2 * g_over_r(before), (g_over_r(before), g_over_r(after))
