"""`m4dgs-eval error-maps`: one test frame's renders, error maps and error changes as a figure.

Predictions with errors put where the test chooses (a few 8-bit codes on one frame, an HDR scale
on another) are scored by `score-frames`; the maps must hold the planted errors, the titles' PSNRs
must be scikit-image's for the frame and average to the scorer's per-level PSNR, the automatic
frame must be the one where the error was planted, and bad input must say what is wrong."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner
from skimage.metrics import peak_signal_noise_ratio

from eval.cli import main
from eval.experiments.frames import score_frames
from eval.inspect.errormaps import (
    GAP,
    colourise,
    domain_frames,
    error_maps,
    error_video,
    frame_psnrs,
    parse_domain,
    pick_frame,
    pixel_sq_error,
    video_frame,
)
from eval.metrics.hdr import hdr_psnr
from m4dgs.clip import Clip, frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.core.errors import InputError


def _write_pred(clip: Clip, root, codes: dict, hdr_scale: dict):
    """Test renders: the ground truth with +codes[g] 8-bit codes (clipped at 255) on every LDR
    level and x hdr_scale[g] on the HDR frame (frames not named: exact)."""
    ex = clip.meta.exposures
    for g in clip.test_frames:
        h = clip.load_gt_hdr(g)
        mio.write_exr(root / "test/hdr" / frame_name(g, "exr"), hdr_scale.get(g, 1.0) * h)
        for lv in list(ex.observed) + list(ex.novel):
            gt = clip.load_gt_ldr(lv, g).astype(int)
            p = np.clip(gt + codes.get(g, 0), 0, 255).astype(np.uint8)
            mio.write_png(root / "test/ldr" / level_name(lv) / frame_name(g, "png"), p)
    return root


@pytest.fixture(scope="module")
def runs(tiny_clip_realistic, tmp_path_factory):
    """A reference with 2 codes of error on every test frame, a run with 9 codes on the second
    test frame (2 elsewhere) and its HDR x1.3 on the last test frame."""
    tmp = tmp_path_factory.mktemp("errormaps")
    clip = Clip.open(tiny_clip_realistic)
    test = clip.test_frames
    assert len(test) >= 3
    ref_codes = {g: 2 for g in test}
    run_codes = {**ref_codes, test[1]: 9}
    ref, _ = score_frames(
        tiny_clip_realistic,
        _write_pred(clip, tmp / "pr", ref_codes, {}),
        "ref",
        tmp / "runs" / "ref",
    )
    run, m = score_frames(
        tiny_clip_realistic,
        _write_pred(clip, tmp / "pa", run_codes, {test[-1]: 1.3}),
        "run",
        tmp / "runs" / "run",
    )
    return clip, ref, run, m, tmp


def test_domains_parse_to_the_clips_levels_and_name_them_when_wrong(tiny_clip_realistic):
    clip = Clip.open(tiny_clip_realistic)
    ex = clip.meta.exposures
    assert parse_domain(clip, None) == ex.observed[0]
    assert parse_domain(clip, "hdr") is None
    assert parse_domain(clip, f"ldr {level_name(ex.novel[0])}") == ex.novel[0]
    assert parse_domain(clip, "ldr .125") == 0.125  # as a number, not only as spelt
    for bad in ("ldr 3", "LDR-OE", "0.125"):
        with pytest.raises(InputError) as e:
            parse_domain(clip, bad)
        assert "'ldr 0.125'" in str(e.value) and "clip.json" in str(e.value)
    assert domain_frames(clip, None) == list(clip.test_frames)


def test_pick_frame_takes_the_largest_drop_or_the_lowest_psnr():
    run = {1: 30.0, 3: 25.0, 5: 28.0}
    assert pick_frame(run) == 3
    assert pick_frame(run, {1: 35.0, 3: 26.0, 5: 29.0}) == 1  # -5 beats -1
    assert pick_frame({1: 20.0, 3: 20.0}) == 1  # ties: the earliest
    with pytest.raises(InputError):
        pick_frame(run, {7: 1.0})


def test_maps_hold_the_planted_error_and_titles_are_the_frames_psnr(runs, tmp_path):
    clip, ref, run, m, _ = runs
    test, lv = clip.test_frames, clip.meta.exposures.observed[0]
    res = error_maps([run], tmp_path / "f.png", ref=ref)
    assert res["domain"] == f"ldr {level_name(lv)}"
    assert res["frame"] == test[1]  # where the 9 codes were put
    assert (tmp_path / "f.png").stat().st_size > 10_000
    g = res["frame"]
    gt = clip.load_gt_ldr(lv, g).astype(float) / 255
    pa = np.clip(clip.load_gt_ldr(lv, g).astype(int) + 9, 0, 255) / 255
    pr = np.clip(clip.load_gt_ldr(lv, g).astype(int) + 2, 0, 255) / 255
    p = res["runs"][0]
    assert np.allclose(res["gt"], gt) and np.allclose(p["pred"], pa)
    # the maps: per pixel the channel mean of the squared error, and its change
    assert np.allclose(p["sq_err"], ((pa - gt) ** 2).mean(-1))
    assert np.allclose(p["d_sq_err"], ((pa - gt) ** 2).mean(-1) - ((pr - gt) ** 2).mean(-1))
    assert (p["d_sq_err"] >= -1e-12).all() and p["d_sq_err"].max() > 0
    # titles: scikit-image's PSNR of the frame, and the difference from the reference's
    assert p["psnr"] == pytest.approx(peak_signal_noise_ratio(gt, pa, data_range=1.0), abs=1e-9)
    ref_psnr = peak_signal_noise_ratio(gt, pr, data_range=1.0)
    assert p["d_psnr"] == pytest.approx(p["psnr"] - ref_psnr, abs=1e-9)
    # over the level's frames the PSNRs average to the scorer's per-level PSNR
    per = frame_psnrs(run, clip, lv, domain_frames(clip, lv))
    assert np.mean(list(per.values())) == pytest.approx(
        m["per_level"][level_name(lv)]["psnr"], abs=1e-9
    )
    # the picked frame's drop is the largest of the candidates
    assert res["picked_from"][g] == min(res["picked_from"].values())


def test_hdr_domain_and_a_given_frame(runs, tmp_path):
    clip, ref, run, _, _ = runs
    g = clip.test_frames[-1]  # HDR x1.3 there
    res = error_maps([run, ref], tmp_path / "h.png", domain="hdr", frame=g, labels=["a", "b"])
    assert res["picked_from"] is None and res["frame"] == g and res["ref"] is None
    a, b = res["runs"]
    assert (a["label"], b["label"]) == ("a", "b")
    assert a["psnr"] == pytest.approx(hdr_psnr(1.3 * clip.load_gt_hdr(g), clip.load_gt_hdr(g)))
    assert b["psnr"] == 100.0  # the reference's HDR is exact: the cap
    # without a reference the automatic frame is the first run's worst
    assert error_maps([run], tmp_path / "w.png", domain="hdr")["frame"] == g
    with pytest.raises(InputError, match="not a test frame"):
        error_maps([run], tmp_path / "x.png", frame=clip.meta.split.train[0])


def test_cli_draws_and_reports_bad_input(runs, tmp_path):
    clip, ref, run, _, tmp = runs
    out = tmp_path / "cli.png"
    res = CliRunner().invoke(main, ["error-maps", str(run), "--ref", str(ref), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert f"frame {clip.test_frames[1]}" in res.output and "against the reference" in res.output
    assert out.exists()
    bad = CliRunner().invoke(main, ["error-maps", str(run), "--out", str(out), "--domain", "ldr 3"])
    assert bad.exit_code != 0 and "'ldr 0.125'" in bad.output
    bad = CliRunner().invoke(main, ["error-maps", str(run), "--out", str(out), "--labels", "a,b"])
    assert bad.exit_code != 0 and "2 label(s) for 1 run(s)" in bad.output
    # a run without renders: the missing file is named
    empty = tmp / "runs" / "empty"
    (empty / "renders/test").mkdir(parents=True)
    mio.write_json(empty / "run.json", mio.read_json(run / "run.json"))
    bad = CliRunner().invoke(main, ["error-maps", str(empty), "--out", str(out)])
    assert bad.exit_code != 0 and "missing render" in bad.output


def test_pixel_error_is_the_channel_mean():
    a = np.zeros((2, 3, 3))
    b = np.zeros((2, 3, 3))
    b[0, 0] = [0.3, 0.0, 0.0]
    e = pixel_sq_error(a, b)
    assert e.shape == (2, 3) and e[0, 0] == pytest.approx(0.03) and e.sum() == pytest.approx(0.03)


def test_colourise_maps_the_ends_of_the_range_to_the_ends_of_the_colour_map():
    from matplotlib import colormaps

    a = np.array([[-1.0, 0.0, 0.5, 2.0]])
    c = colourise(a, "magma", 0.0, 0.5)
    assert c.shape == (1, 4, 3) and c.dtype == np.uint8
    lo = np.round(np.array(colormaps["magma"](0.0)[:3]) * 255)
    hi = np.round(np.array(colormaps["magma"](1.0)[:3]) * 255)
    assert np.array_equal(c[0, 0], lo) and np.array_equal(c[0, 1], lo)  # below: clipped
    assert np.array_equal(c[0, 2], hi) and np.array_equal(c[0, 3], hi)


def test_video_holds_every_test_frame_and_its_psnrs_average_to_the_score(runs, tmp_path):
    import imageio.v2 as imageio

    clip, ref, run, m, _ = runs
    lv = clip.meta.exposures.observed[0]
    res = error_video([run], tmp_path / "v.mp4", ref=ref, labels=["a"], fps=5)
    frames = domain_frames(clip, lv)
    assert res["frames"] == frames and res["domain"] == f"ldr {level_name(lv)}"
    # each tile's PSNR is the frame's; over the level's frames they average to the scorer's
    assert np.mean(res["psnr"]["a"]) == pytest.approx(
        m["per_level"][level_name(lv)]["psnr"], abs=1e-9
    )
    assert set(res["psnr"]) == {"a", "ref ref"}
    # the grid: 3 rows (image, error, change) x 3 columns (truth, reference, run), scaled x2
    h, w, s = clip.height, clip.width, 2
    shape = (3 * h * s + 2 * GAP * s, 3 * w * s + 2 * GAP * s, 3)
    rd = imageio.get_reader(tmp_path / "v.mp4")
    got = [f for f in rd]
    assert len(got) == len(frames)
    assert got[0].shape[:2] == (shape[0] + shape[0] % 2, shape[1] + shape[1] % 2)
    # the first frame's grid as drawn: the run's error tile is its error map through the scale
    pn = error_maps([run], tmp_path / "f.png", ref=ref, frame=frames[0], labels=["a"])
    img = video_frame(pn, res["err_top"], res["d_top"], scale=s)
    assert img.shape == shape
    y0, x0 = h * s + GAP * s, 2 * (w * s + GAP * s)
    tile = img[y0 + h * s // 2 :, x0 : x0 + w * s][: h * s // 2]  # below the caption
    want = colourise(np.sqrt(pn["runs"][0]["sq_err"]), "magma", 0.0, res["err_top"])
    want = np.repeat(np.repeat(want, s, 0), s, 1)[h * s // 2 :]
    assert np.array_equal(tile, want)


def test_cli_writes_a_video_and_needs_an_output(runs, tmp_path):
    clip, ref, run, _, _ = runs
    res = CliRunner().invoke(
        main, ["error-maps", str(run), "--ref", str(ref), "--video", str(tmp_path / "v.mp4")]
    )
    assert res.exit_code == 0, res.output
    assert "frames" in res.output and (tmp_path / "v.mp4").stat().st_size > 0
    assert not (tmp_path / "f.png").exists()
    bad = CliRunner().invoke(main, ["error-maps", str(run)])
    assert bad.exit_code != 0 and "--out PNG, --video MP4" in bad.output
