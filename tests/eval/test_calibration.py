"""The calibration rows' pieces on hand-made cases with known answers: the Debevec-Malik response
against the true curve, the radiance merge and re-exposure, copy-nearest on a still scene, and
flow-merge on a translating texture (better than a copy, where the copy is off by the motion)."""

from __future__ import annotations

import numpy as np
import pytest

from eval.calibration.predict import ClipFrames, copy_nearest, flow_merge, neighbours, response_of
from eval.calibration.response import expose, merge_radiance, radiance, solve_response
from m4dgs.core.crf import clip_crf, tonemap_ldr

CRF = clip_crf("hdrnerf")
LEVELS = (0.125, 2.0, 32.0)


def _scene(h=48, w=96, seed=0, shift=0.0):
    """A smooth radiance field spanning ~12 stops, optionally translated by `shift` pixels in x
    (periodic, so a translation is exact)."""
    rng = np.random.default_rng(seed)
    H, W = h, w
    k = np.fft.fftfreq(W)[None, :] ** 2 + np.fft.fftfreq(H)[:, None] ** 2
    out = []
    for c in range(3):
        spec = np.fft.fft2(rng.normal(size=(H, W))) * np.exp(-k * 300)
        spec *= np.exp(-2j * np.pi * np.fft.fftfreq(W)[None, :] * shift)
        f = np.real(np.fft.ifft2(spec))
        f = (f - f.min()) / (f.max() - f.min())
        out.append(np.exp2(f * 12.0 - 8.0 + 0.3 * c))
    return np.stack(out, -1).astype(np.float32)


def _true_g(codes):
    y = (np.asarray(codes, np.float64)) / 255.0
    return np.log(np.maximum(CRF.inverse(y), 1e-30))


def test_debevec_malik_recovers_the_response_up_to_its_anchor():
    hdr = _scene()
    frames = [tonemap_ldr(hdr, dt, CRF) for dt in LEVELS]
    rng = np.random.default_rng(1)
    idx = rng.choice(hdr.shape[0] * hdr.shape[1], 400, replace=False)
    codes = np.stack([f.reshape(-1, 3)[idx, 1] for f in frames], 1)
    anchor = int(round(255 * float(CRF(np.float64(1.0)))))
    g = solve_response(codes, np.log(LEVELS), anchor=anchor)
    z = np.arange(20, 236)  # the ends are barely measured: a code of 2 is ~2 x a code of 1
    err = np.abs(g[z] - _true_g(z))
    assert g[anchor] == 0 and np.all(np.diff(g) >= 0)
    assert np.median(err) < 0.05 and err.max() < 0.25, (np.median(err), err.max())
    # a wrong anchor moves the whole curve: the anchor is what sets the scale
    g2 = solve_response(codes, np.log(LEVELS), anchor=anchor + 40)
    assert np.median(np.abs(g2[z] - _true_g(z))) > 0.3


def test_merge_and_expose_round_trip():
    hdr = _scene(seed=2)
    frames = [tonemap_ldr(hdr, dt, CRF) for dt in LEVELS]
    codes = np.arange(256)
    gt = _true_g(codes)
    gt[0], gt[255] = gt[1] - 1.0, gt[254] + 1.0  # the clipped ends: bounds, not measurements
    g = np.stack([gt] * 3)
    merged = merge_radiance(frames, LEVELS, g)
    ok = np.any([(f > 10) & (f < 245) for f in frames], axis=0)
    rel = np.abs(merged - hdr) / hdr
    assert np.median(rel[ok]) < 0.02
    for f, dt in zip(frames, LEVELS):
        back = expose(merged, dt, g).astype(int)
        mid = (f > 10) & (f < 245)
        assert np.abs(back - f)[mid].max() <= 2
        # one frame alone: its own codes back exactly where they are not clipped
        again = expose(radiance(f, dt, g), dt, g).astype(int)
        assert np.abs(again - f)[(f > 0) & (f < 255)].max() <= 1


def _clip(shift_per_frame=0.0, n=9):
    frames = list(range(0, n, 2))  # training frames: even g, test frames odd
    dts = [LEVELS[i % 3] for i in range(len(frames))]
    hdrs = {g: _scene(seed=3, shift=shift_per_frame * g) for g in range(n)}
    ldr = [tonemap_ldr(hdrs[g], dt, CRF) for g, dt in zip(frames, dts)]
    return ClipFrames(frames, ldr, dts, float(CRF(np.float64(1.0)))), hdrs


def test_the_response_of_a_moving_clip_needs_no_alignment():
    """Quantile samples of brackets whose frames moved (3 px between frames) give the true
    response; pixel samples of the same unaligned frames do not."""
    from eval.calibration.response import estimate_response

    cf, _ = _clip(shift_per_frame=1.5)
    groups = [np.stack(cf.ldr[i : i + 3]) for i in (0, 1, 2)]
    dts = [cf.dt[i : i + 3] for i in (0, 1, 2)]
    z = np.arange(20, 236)
    errs = {}
    for sampling in ("quantiles", "pixels"):
        g = estimate_response(groups, dts, anchor=cf.anchor, sampling=sampling)
        errs[sampling] = float(np.abs(g[1][z] - _true_g(z)).max())
    assert errs["quantiles"] < 0.1 < errs["pixels"], errs


def test_copy_nearest_on_a_still_scene_is_the_frame_itself():
    cf, hdrs = _clip()
    g_est = response_of(cf)
    pred = copy_nearest(cf, 3.0, g_est)  # nearest: frame 2 (the earlier on a tie), dt 2
    assert cf.frames[1] == 2
    back = expose(pred, cf.dt[1], g_est).astype(int)
    f = cf.ldr[1].astype(int)
    assert np.abs(back - f)[(f > 0) & (f < 255)].max() <= 1
    # and the estimated radiance is the truth's where that frame is well exposed
    ok = (cf.ldr[1] > 20) & (cf.ldr[1] < 235)
    assert np.median(np.abs(pred - hdrs[3])[ok] / hdrs[3][ok]) < 0.1


def test_flow_merge_follows_motion_that_a_copy_misses():
    cf, hdrs = _clip(shift_per_frame=1.5)
    g_est = response_of(cf)
    # levels 0.125, 2, 32, 0.125, 2 at frames 0, 2, 4, 6, 8: the nearest of each level to time 3
    # (0.125: frames 0 and 6 tie, the earlier wins)
    assert [cf.frames[i] for i in neighbours(cf, 3.0)] == [0, 2, 4]

    def err(pred):
        ok = slice(8, -8)  # away from the borders the warp fills by replication
        a, b = np.log(pred[:, ok]), np.log(hdrs[3][:, ok])
        return float(np.median(np.abs(a - b)))

    e_copy, e_merge = err(copy_nearest(cf, 3.0, g_est)), err(flow_merge(cf, 3.0, g_est))
    assert e_merge < 0.6 * e_copy, (e_merge, e_copy)
    cf0, hdrs0 = _clip(shift_per_frame=0.0)
    still = flow_merge(cf0, 3.0, response_of(cf0))
    assert float(np.median(np.abs(np.log(still) - np.log(hdrs0[3])))) < 0.05


def test_calibration_rows_read_no_ground_truth(tiny_clip_oracle, monkeypatch):
    """ClipFrames.of reads input/ldr and clip.json only: every ground-truth and prior reader of the
    clip fails the test if called."""
    from m4dgs.clip import Clip

    clip = Clip.open(tiny_clip_oracle)
    for name in dir(clip):
        if name.startswith(("load_gt", "load_view", "load_depth", "load_tracks", "load_flow")):
            monkeypatch.setattr(clip, name, lambda *a, _n=name, **k: pytest.fail(_n))
    cf = ClipFrames.of(clip)
    g = response_of(cf)
    out = flow_merge(cf, float(clip.test_frames[0]), g)
    assert out.shape == (clip.height, clip.width, 3) and np.isfinite(out).all()


def test_dibr_moves_a_plane_exactly_and_keeps_the_nearest_surface():
    """A fronto-parallel plane at depth 4 seen by a camera, forward-warped into one moved 0.4 m to
    the right: every pixel shifts left by f 0.4 / 4 = 4 px (f = 40), exactly; a nearer patch in
    front of it hides what lies behind it in the new view."""
    from eval.calibration.predict import dibr

    H, W, f = 24, 40, 40.0
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    src, dst = np.eye(4), np.eye(4)
    dst[0, 3] = 0.4
    img = np.tile(np.arange(W, dtype=np.float64)[None, :, None], (H, 1, 1))  # colour = column
    depth = np.full((H, W), 4.0)
    out, hit = dibr(img, depth, K, src, K, dst, W, H)
    assert hit[:, : W - 4].all() and not hit[:, W - 4 :].any()  # the right edge had no source
    np.testing.assert_array_equal(out[:, : W - 4, 0], img[:, 4:, 0])
    np.testing.assert_array_equal(out[:, W - 4 :, 0], np.broadcast_to(img[:, W - 1 :, 0], (H, 4)))
    # a patch at depth 2 (columns 10-13) shifts by 8 px and wins over the plane where they meet
    depth2 = depth.copy()
    depth2[:, 10:14] = 2.0
    img2 = img.copy()
    img2[:, 10:14] = -1.0
    out2, _ = dibr(img2, depth2, K, src, K, dst, W, H)
    assert (out2[:, 2:6, 0] == -1.0).all()


def test_a_calibration_row_is_scored_like_another_method(tiny_clip_oracle, tmp_path):
    """The row's folder passes score-frames' checks and is scored with every frame metric; its
    LDR frames are its own response of its HDR."""
    from click.testing import CliRunner

    from eval.calibration.frames import write_prediction
    from eval.cli import main as eval_main
    from m4dgs.clip import Clip

    clip = Clip.open(tiny_clip_oracle)
    pred = write_prediction(clip, tmp_path / "pred", "flow-merge")
    out = tmp_path / "runs" / "flow-merge"
    r = CliRunner().invoke(
        eval_main,
        [
            "score-frames",
            "--clip",
            str(tiny_clip_oracle),
            "--pred",
            str(pred),
            "--name",
            "flow-merge",
            "--out",
            str(out),
        ],
    )
    assert r.exit_code == 0, r.output
    from m4dgs.core.io import read_json

    m = read_json(out / "metrics.json")
    for k in ("ldr_oe_psnr", "ldr_ne_psnr", "hdr_psnr"):
        assert np.isfinite(m[k]) and m[k] > 10, (k, m[k])


def test_dibr_row_at_the_views_scores_like_a_method(tiny_clip_oracle, tmp_path):
    """The dibr row writes every view frame from the camera initialisation of the clip (a short
    one here), and eval.experiments.view_scores scores it as it scores a run's renders."""
    from eval.experiments.dibr_views import write_dibr_views
    from eval.experiments.view_scores import score_views
    from m4dgs.clip import Clip

    out = write_dibr_views(
        tiny_clip_oracle, tmp_path / "views", preset="tiny", overrides={"camera_init.ba_steps": 20}
    )
    s = score_views(Clip.open(tiny_clip_oracle), out)
    for v in ("small", "medium", "large"):
        assert 10 < s[f"nv_{v}_ldr_oe_psnr"] < 60, (v, s[f"nv_{v}_ldr_oe_psnr"])
