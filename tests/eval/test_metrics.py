"""Metric tests, each against an independent answer (scikit-image, numpy, scipy, analytic
values)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from scipy import ndimage
from skimage.metrics import structural_similarity

from eval.metrics import geometry, hdr, image, lpips, perf, temporal

RNG = np.random.default_rng


def _smooth_texture(h, w, seed=0, sigma=2.0, c=3):
    rng = RNG(seed)
    x = ndimage.gaussian_filter(rng.random((h, w, c)), sigma=(sigma, sigma, 0))
    x = (x - x.min()) / (x.max() - x.min())
    return x


def _pair(seed=0, h=48, w=64):
    gt = _smooth_texture(h, w, seed)
    pred = np.clip(gt + 0.05 * RNG(seed + 1).standard_normal(gt.shape), 0, 1)
    return pred, gt


# -----------------------------------------------------------------------------------------------
# LDR


def test_ssim_matches_skimage_crop5_and_full_map_is_higher():
    for seed in (0, 1):
        pred, gt = _pair(seed)
        ref = structural_similarity(
            pred,
            gt,
            gaussian_weights=True,
            sigma=1.5,
            use_sample_covariance=False,
            data_range=1,
            channel_axis=-1,
        )
        assert image.ssim(pred, gt, crop=5) == pytest.approx(ref, abs=1e-5)
        full = image.ssim(pred, gt)
        assert full > ref  # zero-padded borders read higher (small image: a large border share)


def test_psnr_matches_numpy_per_image_mean():
    pred = np.stack([_pair(s)[0] for s in range(3)])
    gt = np.stack([_pair(s)[1] for s in range(3)])
    ref = np.mean([10 * np.log10(1.0 / np.mean((p - g) ** 2)) for p, g in zip(pred, gt)])
    assert image.psnr(pred, gt) == pytest.approx(ref, abs=1e-9)
    assert image.psnr(
        torch.from_numpy(pred).float(), torch.from_numpy(gt).float()
    ) == pytest.approx(ref, abs=1e-4)
    assert image.psnr(gt[0], gt[0]) == math.inf
    # uint8 inputs are 8-bit images
    u8p = np.round(pred[0] * 255).astype(np.uint8)
    u8g = np.round(gt[0] * 255).astype(np.uint8)
    ref8 = 10 * np.log10(255.0**2 / np.mean((u8p.astype(float) - u8g.astype(float)) ** 2))
    assert image.psnr(u8p, u8g) == pytest.approx(ref8, abs=1e-9)


def test_png_roundtrip_is_8bit_quantisation_and_jpeg_costs_db():
    pred, gt = _pair(3)
    q = np.round(pred * 255) / 255
    assert np.abs(image.roundtrip(pred, "png").numpy() - q).max() < 1e-12
    ref = 10 * np.log10(1.0 / np.mean((q - gt) ** 2))
    assert image.psnr(pred, gt, roundtrip="png") == pytest.approx(ref, abs=1e-9)
    j75 = image.roundtrip(gt, "jpeg").numpy()
    j95 = image.roundtrip(gt, "jpeg", jpeg_quality=95).numpy()
    assert np.allclose(j75 * 255, np.round(j75 * 255), atol=1e-9)  # 8-bit values
    err75, err95 = np.mean((j75 - gt) ** 2), np.mean((j95 - gt) ** 2)
    assert 0 < err95 < err75
    assert 10 * np.log10(1 / err75) > 28  # a smooth image survives JPEG-75 reasonably
    with pytest.raises(ValueError):
        image.roundtrip(gt, "webp")


def test_masked_psnr_and_ssim_against_numpy_and_skimage():
    pred, gt = _pair(4, 40, 56)
    mask = np.zeros(gt.shape[:2], bool)
    # interior: >= 5 px from the border, where zero padding and skimage agree
    mask[12:30, 15:41] = True
    ref_psnr = 10 * np.log10(1.0 / np.mean(((pred - gt) ** 2)[mask]))
    assert image.masked_psnr(pred, gt, mask) == pytest.approx(ref_psnr, abs=1e-9)
    _, smap = structural_similarity(
        pred,
        gt,
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        data_range=1,
        channel_axis=-1,
        full=True,
    )
    assert image.masked_ssim(pred, gt, mask) == pytest.approx(smap[mask].mean(), abs=1e-5)
    assert image.masked_psnr(pred, gt, np.zeros_like(mask)) is None
    assert image.masked_ssim(pred, gt, np.zeros_like(mask)) is None


# -----------------------------------------------------------------------------------------------
# HDR


def test_mu_law_known_values():
    v = hdr.mu_law(np.array([0.0, 1.0, 0.001])).numpy()
    assert v[0] == 0.0
    assert v[1] == pytest.approx(1.0, abs=1e-12)
    assert v[2] == pytest.approx(math.log(6) / math.log(5001), abs=1e-12)


def test_hdr_psnr_gt_max_vs_own_max_for_scale_error():
    rng = RNG(5)
    gt = 10.0 * rng.uniform(0.05, 0.75, size=(32, 40, 3))
    gt[0, 0, :] = 10.0  # the maximum
    pred = 1.3 * gt * (1 + 1e-3 * rng.standard_normal(gt.shape))
    # independent numpy answer
    s = gt.max()

    def t(x):
        return np.log(1 + 5000 * np.clip(x / s, 0, 1)) / np.log(5001)

    ref = 10 * np.log10(1 / np.mean((t(pred) - t(gt)) ** 2))
    got = hdr.hdr_psnr(pred, gt)
    assert got == pytest.approx(ref, abs=1e-9)
    assert got == pytest.approx(30.2, abs=0.3)  # ~ -20 log10(log(1.3) / log(5001))
    own = hdr.hdr_psnr(pred, gt, norm="own")
    assert own > got + 10
    # SSIM in the mu-law domain equals skimage on the tone-mapped pair
    ref_ssim = structural_similarity(
        t(pred),
        t(gt),
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        data_range=1,
        channel_axis=-1,
    )
    assert hdr.hdr_ssim(pred, gt, crop=5) == pytest.approx(ref_ssim, abs=1e-5)


def test_pu21_monotonic_and_known_value():
    y = np.logspace(np.log10(0.005), 4, 200)
    v = hdr.pu21_encode(y).numpy()
    assert np.all(np.diff(v) > 0)
    p1, p2, p3, p4, p5, p6, p7 = (
        0.353487901,
        0.3734658629,
        8.277049286e-05,
        0.9062562627,
        0.09150303166,
        0.9099517204,
        596.3148142,
    )
    yy = 100.0
    hand = p7 * (((p1 + p2 * yy**p4) / (1 + p3 * yy**p4)) ** p5 - p6)
    assert float(hdr.pu21_encode(np.array(100.0))) == pytest.approx(hand, rel=1e-12)
    # clamping to [0.005, 10000]
    assert float(hdr.pu21_encode(np.array(1e-5))) == float(hdr.pu21_encode(np.array(0.005)))
    assert float(hdr.pu21_encode(np.array(5e4))) == float(hdr.pu21_encode(np.array(1e4)))


def test_pu21_psnr_against_numpy():
    rng = RNG(6)
    gt = rng.uniform(0.001, 2.0, size=(16, 20, 3))
    pred = gt * rng.uniform(0.8, 1.2, size=gt.shape)
    p1, p2, p3, p4, p5, p6, p7 = hdr.PU21_BANDING_GLARE

    def enc(x):
        y = np.clip(x, 0.005, 10000)
        return np.maximum(p7 * (((p1 + p2 * y**p4) / (1 + p3 * y**p4)) ** p5 - p6), 0)

    k = 4000.0 / gt.max()
    ref = 10 * np.log10(256.0**2 / np.mean((enc(pred * k) - enc(gt * k)) ** 2))
    assert hdr.pu21_psnr(pred, gt) == pytest.approx(ref, abs=1e-9)
    assert hdr.pu21_psnr(gt, gt) == math.inf


def test_hdr_flip_zero_for_identical_positive_for_perturbed():
    rng = RNG(7)
    gt = 3.0 * _smooth_texture(32, 40, 7).astype(np.float32) + 0.01
    assert hdr.hdr_flip(gt, gt) == pytest.approx(0.0, abs=1e-7)
    pert = gt * (1 + 0.3 * rng.standard_normal(gt.shape)).clip(0.1, None)
    assert hdr.hdr_flip(pert, gt) > 0.01


# ------------------------------------------------------------------------------------------
# temporal


def _exact_translation_clip(t_len=3, h=24, w=32, d=(2, 1), seed=8):
    """Frames of a translating texture: H_{t+1}(x + d) = H_t(x); exact flows and visibility."""
    big = 0.05 + 4.0 * _smooth_texture(
        h + 2 * t_len * abs(d[1]) + 4, w + 2 * t_len * abs(d[0]) + 4, seed
    )
    frames = []
    for t in range(t_len):
        y0, x0 = 2 + t_len * abs(d[1]) - t * d[1], 2 + t_len * abs(d[0]) - t * d[0]
        frames.append(big[y0 : y0 + h, x0 : x0 + w])
    frames = np.stack(frames)
    fwd = np.broadcast_to(np.array(d, float), (t_len - 1, h, w, 2)).copy()
    bwd = -fwd
    ys, xs = np.mgrid[0:h, 0:w]
    vis_f = (xs + d[0] >= 0) & (xs + d[0] <= w - 1) & (ys + d[1] >= 0) & (ys + d[1] <= h - 1)
    vis_b = (xs - d[0] >= 0) & (xs - d[0] <= w - 1) & (ys - d[1] >= 0) & (ys - d[1] <= h - 1)
    return frames, fwd, bwd, np.stack([vis_f] * (t_len - 1)), np.stack([vis_b] * (t_len - 1))


def test_tae_zero_for_exact_translation():
    frames, fwd, bwd, vf, vb = _exact_translation_clip()
    assert temporal.hdr_tae(frames, fwd, bwd, vf, vb) == pytest.approx(0.0, abs=1e-12)
    # global HDR scale does not change TAE (also with a brightness flicker)
    fl = frames * np.array([1.0, 1.7, 0.6])[:, None, None, None]
    a = temporal.hdr_tae(fl, fwd, bwd, vf, vb)
    assert a > 0.1
    assert temporal.hdr_tae(37.0 * fl, fwd, bwd, vf, vb) == pytest.approx(a, rel=1e-9)


def test_tae_global_flicker_ratio():
    rng = RNG(9)
    base = rng.uniform(0.1, 5.0, size=(16, 20, 3))
    zero = np.zeros((1, 16, 20, 2))
    for r in (1.5, 0.25, 3.0):
        frames = np.stack([base, r * base])
        expect = 3 * abs(r - 1) / (r + 1)
        # default visibility (forward-backward consistency: all visible for zero flow)
        assert temporal.hdr_tae(frames, zero, zero) == pytest.approx(expect, rel=1e-9)
    # three frames alternating flicker: every pair has the same value
    frames = np.stack([base, 2 * base, base])
    z2 = np.zeros((2, 16, 20, 2))
    assert temporal.hdr_tae_pairs(frames, z2, z2) == pytest.approx([1.0, 1.0], rel=1e-9)


def _scipy_warp(img, flow):
    """Bilinear backward warp of img [H, W, 3] by flow [H, W, 2] with border padding (coordinates
    clamped), by scipy.ndimage.map_coordinates: the temporal metrics' reference."""
    h, w = img.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w].astype(float)
    cy = np.clip(ys + flow[..., 1], 0, h - 1)
    cx = np.clip(xs + flow[..., 0], 0, w - 1)
    return np.stack([ndimage.map_coordinates(img[..., c], [cy, cx], order=1) for c in range(3)], -1)


def test_tae_subpixel_against_scipy_reference():
    rng = RNG(10)
    h, w = 20, 24
    frames = 0.1 + _smooth_texture(h, w, 11)[None].repeat(2, 0) * rng.uniform(
        0.8, 1.2, size=(2, 1, 1, 3)
    )
    frames[1] = np.roll(frames[1], 1, axis=1)
    fwd = rng.uniform(-1.5, 1.5, size=(1, h, w, 2))
    bwd = rng.uniform(-1.5, 1.5, size=(1, h, w, 2))
    vf = rng.random((1, h, w)) > 0.3
    vb = rng.random((1, h, w)) > 0.3

    def direction(a, b, f, v):
        hw = _scipy_warp(b, f)
        rel = (np.abs(a - hw) / (a + hw + 1e-10)).sum(-1)
        return (rel * v).sum() / v.sum()

    ref = 0.5 * (
        direction(frames[0], frames[1], fwd[0], vf[0])
        + direction(frames[1], frames[0], bwd[0], vb[0])
    )
    assert temporal.hdr_tae(frames, fwd, bwd, vf, vb) == pytest.approx(ref, rel=1e-9)


def test_tce_zero_for_the_truth_floor_for_a_frozen_video_and_scale_free():
    frames, fwd, bwd, vf, vb = _exact_translation_clip()
    # the truth changes between frames (a light that brightens), so its own HDR-TAE is not zero
    gt = frames * np.array([1.0, 1.3, 1.1])[:, None, None, None]
    tae_gt = temporal.hdr_tae(gt, fwd, bwd, vf, vb)
    assert tae_gt > 0.05
    assert temporal.hdr_tce(gt, gt, fwd, bwd, vf, vb) == pytest.approx(0.0, abs=1e-12)
    # a constant scale on the prediction cancels
    assert temporal.hdr_tce(42.0 * gt, gt, fwd, bwd, vf, vb) == pytest.approx(0.0, abs=1e-9)
    # a prediction that follows the motion but not the brightening: HDR-TAE below the truth's,
    # HDR-TCE exactly the truth's HDR-TAE (the clip's floor)
    frozen = frames
    assert temporal.hdr_tae(frozen, fwd, bwd, vf, vb) == pytest.approx(0.0, abs=1e-12)
    assert temporal.hdr_tce(frozen, gt, fwd, bwd, vf, vb) == pytest.approx(tae_gt, rel=1e-9)
    # flicker on top of the truth is an error too
    fl = gt * np.array([1.0, 0.8, 1.2])[:, None, None, None]
    assert temporal.hdr_tce(fl, gt, fwd, bwd, vf, vb) > 0.1
    with pytest.raises(ValueError, match="differ"):
        temporal.hdr_tce(gt[:2], gt, fwd, bwd, vf, vb)


def test_tce_subpixel_against_scipy_reference():
    rng = RNG(14)
    h, w = 18, 22
    tex = 0.1 + _smooth_texture(h, w, 15)
    gt = tex[None].repeat(2, 0) * rng.uniform(0.8, 1.2, size=(2, 1, 1, 3))
    gt[1] = np.roll(gt[1], 1, axis=1)
    pred = gt * rng.uniform(0.9, 1.1, size=(2, h, w, 3))
    fwd = rng.uniform(-1.5, 1.5, size=(1, h, w, 2))
    bwd = rng.uniform(-1.5, 1.5, size=(1, h, w, 2))
    vf = rng.random((1, h, w)) > 0.3
    vb = rng.random((1, h, w)) > 0.3

    def change(a, b, f):
        bw = _scipy_warp(b, f)
        return (a - bw) / (a + bw + 1e-10)

    def direction(i, j, f, v):
        err = np.abs(change(pred[i], pred[j], f) - change(gt[i], gt[j], f)).sum(-1)
        return (err * v).sum() / v.sum()

    ref = 0.5 * (direction(0, 1, fwd[0], vf[0]) + direction(1, 0, bwd[0], vb[0]))
    assert temporal.hdr_tce(pred, gt, fwd, bwd, vf, vb) == pytest.approx(ref, rel=1e-9)


def test_hdr_t_std_against_numpy():
    rng = RNG(12)
    frames = rng.uniform(0, 3, size=(5, 8, 10, 3)) * rng.uniform(0.5, 1.5, size=(5, 1, 1, 1))
    means = frames.reshape(5, -1).mean(1)
    assert temporal.hdr_t_std(frames) == pytest.approx(np.std(means) / frames.mean(), rel=1e-12)
    assert temporal.hdr_t_std(np.stack([frames[0]] * 4)) == pytest.approx(0.0, abs=1e-12)


def test_dis_flow_recovers_translation():
    h, w, dx, dy = 96, 128, 3, -2
    big = 0.01 + 8.0 * _smooth_texture(h + 20, w + 20, 13, sigma=1.5) ** 2
    a = big[10 : 10 + h, 10 : 10 + w]
    b = big[10 - dy : 10 - dy + h, 10 - dx : 10 - dx + w]  # b(x + d) = a(x)
    flow = temporal.dis_flow(a.astype(np.float32), b.astype(np.float32))
    assert flow.shape == (h, w, 2) and flow.dtype == np.float32
    inner = flow[12:-12, 12:-12]
    epe = np.linalg.norm(inner - np.array([dx, dy]), axis=-1).mean()
    assert epe < 0.2
    # uint8 path (LDR) also works
    t8 = temporal.tonemap_8bit(a)
    assert t8.dtype == np.uint8 and t8.max() == 255


# ------------------------------------------------------------------------------------------
# geometry


def _rotz(th):
    c, s = math.cos(th), math.sin(th)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _rot(axis, th):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(th) * k + (1 - math.cos(th)) * k @ k


def test_ate_zero_for_sim3_transformed_and_known_value():
    pytest.importorskip("m4dgs.core.camera")
    cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    s0, r0, t0 = 2.5, _rot([1, 2, 3], 0.7), np.array([0.3, -1.0, 4.0])
    assert geometry.ate(s0 * cube @ r0.T + t0, cube) == pytest.approx(0.0, abs=1e-9)
    # perturbation with zero mean and zero cross-covariance: optimal alignment is R = I, t = 0, s =
    # 3 / (3 + d^2)
    d = 0.2
    sign = cube[:, 0] * cube[:, 1] * cube[:, 2]
    est = cube + d * sign[:, None] * np.array([0.0, 0.6, 0.8])
    s = 3 / (3 + d**2)
    expect = math.sqrt(3 * (s - 1) ** 2 + s**2 * d**2)
    moved = s0 * est @ r0.T + t0  # any Sim(3) of the estimate gives the same ATE
    assert geometry.ate(moved, cube) == pytest.approx(expect, abs=1e-9)
    assert geometry.ate(est, cube, with_scale=False) == pytest.approx(d, abs=1e-9)


def _traj(n=6, seed=14):
    rng = RNG(seed)
    poses = []
    for i in range(n):
        p = np.eye(4)
        p[:3, :3] = _rot(rng.standard_normal(3), 0.3 * rng.random())
        p[:3, 3] = [i * 0.5, np.sin(i), 0.2 * i**2 - 1 + 0.3 * rng.standard_normal()]
        poses.append(p)
    return np.stack(poses)


def test_rpe_zero_after_sim3_and_known_rotation_perturbation():
    pytest.importorskip("m4dgs.core.camera")
    gt = _traj()
    n = gt.shape[0]
    s0, r0, t0 = 0.7, _rot([0, 1, 1], 1.1), np.array([1.0, 2.0, -0.5])
    est = gt.copy()
    est[:, :3, :3] = r0 @ gt[:, :3, :3]
    est[:, :3, 3] = s0 * gt[:, :3, 3] @ r0.T + t0
    # the metric aligns est to gt, so express est in a transformed frame
    r = geometry.rpe(est, gt)
    assert r["rpe_trans"] == pytest.approx(0.0, abs=1e-8) and r["rpe_rot"] == pytest.approx(
        0.0, abs=1e-5
    )
    # rotate camera k about its own z axis: centres (and thus the alignment) are unchanged
    k, th = 2, 0.05
    est = gt.copy()
    est[k, :3, :3] = gt[k, :3, :3] @ _rotz(th)
    m = np.linalg.inv(gt[k]) @ gt[k + 1]
    trans_err = np.linalg.norm((_rotz(th).T - np.eye(3)) @ m[:3, 3])
    r = geometry.rpe(est, gt)
    assert r["rpe_rot"] == pytest.approx(math.degrees(th) * math.sqrt(2 / (n - 1)), rel=1e-6)
    assert r["rpe_trans"] == pytest.approx(trans_err / math.sqrt(n - 1), rel=1e-6)


def test_depth_absrel_hand_case_and_scale_invariance():
    gt = np.array([[1.0, 2.0, 3.0], [4.0, 0.0, -1.0]])
    pred = np.array([[2.0, 4.0, 6.0], [10.0, 5.0, 5.0]])
    # valid: gt > 0 -> [1,2,3,4] vs [2,4,6,10]; s = 2.5 / 5 = 0.5; errors [0,0,0,1/4]
    assert geometry.depth_absrel(pred, gt) == pytest.approx(0.0625, abs=1e-12)
    assert geometry.depth_absrel(123.0 * pred, gt) == pytest.approx(0.0625, abs=1e-12)
    rng = RNG(15)
    g = rng.uniform(1, 10, (12, 14))
    d = g * rng.uniform(0.9, 1.1, g.shape)
    assert geometry.depth_absrel(d, g) == pytest.approx(
        geometry.depth_absrel(0.01 * d, g), rel=1e-12
    )
    assert geometry.depth_absrel(d, -g) is None


def test_track_error_hand_case():
    gt = np.zeros((2, 3, 2))
    pred = gt.copy()
    pred[0, :, 0] = [0.5, 3.0, 100.0]  # errors 0.5, 3, (invisible)
    pred[1, :, 1] = [1.0, 9.0, 20.0]  # errors 1 (not < 1), 9, 20
    vis = np.array([[True, True, False], [True, True, True]])
    r = geometry.track_error(pred, gt, vis)
    errs = np.array([0.5, 3.0, 1.0, 9.0, 20.0])
    assert r["epe"] == pytest.approx(errs.mean())
    fr = [np.mean(errs < d) for d in (1, 2, 4, 8, 16)]  # [0.2, 0.4, 0.6, 0.6, 0.8]
    assert [r[f"within_{d}"] for d in (1, 2, 4, 8, 16)] == pytest.approx(fr)
    assert r["delta_avg"] == pytest.approx(np.mean(fr))
    r256 = geometry.track_error(pred, gt, vis, image_size=(512, 256))  # x halves, y unchanged
    assert r256["epe"] == pytest.approx(np.mean([0.25, 1.5, 1.0, 9.0, 20.0]))
    assert geometry.track_error(pred, gt, np.zeros_like(vis))["epe"] is None


# ------------------------------------------------------------------------------------------ LPIPS


def _random_weights(seed=16):
    g = torch.Generator().manual_seed(seed)
    conv_w, conv_b = [], []
    for _, cin, cout, k, _, _ in lpips.ALEX_CONVS:
        conv_w.append(torch.randn(cout, cin, k, k, generator=g) * math.sqrt(2.0 / (cin * k * k)))
        conv_b.append(0.1 * torch.randn(cout, generator=g))
    lin = [torch.rand(1, c, 1, 1, generator=g) for c in lpips.TAP_CHANNELS]
    return lpips.LpipsWeights(conv_w, conv_b, lin)


def _manual_lpips(a, b, w, normalize):
    """Layer-by-layer recomputation with plain conv2d calls (independent wiring)."""
    shift = torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1)
    scale = torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1)

    def feats(x):
        x = x.permute(0, 3, 1, 2)
        x = (2 * x - 1) if normalize else x
        x = (x - shift) / scale
        r1 = torch.relu(F.conv2d(x, w.conv_w[0], w.conv_b[0], stride=4, padding=2))
        r2 = torch.relu(F.conv2d(F.max_pool2d(r1, 3, 2), w.conv_w[1], w.conv_b[1], padding=2))
        r3 = torch.relu(F.conv2d(F.max_pool2d(r2, 3, 2), w.conv_w[2], w.conv_b[2], padding=1))
        r4 = torch.relu(F.conv2d(r3, w.conv_w[3], w.conv_b[3], padding=1))
        r5 = torch.relu(F.conv2d(r4, w.conv_w[4], w.conv_b[4], padding=1))
        return [r1, r2, r3, r4, r5]

    total = 0.0
    for fa, fb, lw in zip(feats(a), feats(b), w.lin):
        na = fa / (fa.norm(dim=1, keepdim=True) + 1e-10)
        nb = fb / (fb.norm(dim=1, keepdim=True) + 1e-10)
        total = total + ((na - nb) ** 2 * lw.view(1, -1, 1, 1)).sum(1).mean()
    return float(total)


def test_lpips_wiring_with_generated_weights(tmp_path):
    w = _random_weights()
    rng = RNG(17)
    a = rng.random((64, 72, 3)).astype(np.float32)
    b = np.clip(a + 0.2 * rng.standard_normal(a.shape), 0, 1).astype(np.float32)
    assert lpips.lpips(a, a, w) == pytest.approx(0.0, abs=1e-7)
    at, bt = torch.from_numpy(a)[None], torch.from_numpy(b)[None]
    v = lpips.lpips(a, b, w)
    assert v > 0
    assert v == pytest.approx(_manual_lpips(at, bt, w, True), rel=1e-5)
    v_raw = lpips.lpips(a, b, w, normalize_input=False)
    assert v_raw == pytest.approx(_manual_lpips(at, bt, w, False), rel=1e-5)
    # [0,1] fed unnormalised == normalised input of (x + 1) / 2
    assert v_raw == pytest.approx(lpips.lpips((a + 1) / 2, (b + 1) / 2, w), rel=1e-5)
    # identity-like heads (all ones): each layer term is mean |n(fa) - n(fb)|^2 in [0, 4]
    ones = lpips.LpipsWeights(
        w.conv_w, w.conv_b, [torch.ones(1, c, 1, 1) for c in lpips.TAP_CHANNELS]
    )
    assert 0 < lpips.lpips(a, b, ones) <= 20
    # save / load round trip, and the lpips full-model key layout
    path = tmp_path / "alex_lpips.pth"
    lpips.save_lpips_weights(w, path)
    assert lpips.lpips(a, b, str(path)) == pytest.approx(v, rel=1e-7)
    sd = {}
    for (idx, *_), cw, cb in zip(lpips.ALEX_CONVS, w.conv_w, w.conv_b):
        sd[f"net.slice{lpips._SLICE_OF[idx]}.{idx}.weight"] = cw
        sd[f"net.slice{lpips._SLICE_OF[idx]}.{idx}.bias"] = cb
    for i, l in enumerate(w.lin):
        sd[f"lin{i}.model.0.weight"] = l
    assert lpips.lpips(a, b, lpips.weights_from_state_dict({"state_dict": sd})) == pytest.approx(
        v, rel=1e-7
    )


def test_lpips_rejects_bad_files_and_is_none_without_weights(tmp_path):
    a = np.zeros((64, 64, 3), np.float32)
    assert lpips.lpips(a, a, None) is None
    sd = _random_weights().state_dict()
    del sd["lin3.model.1.weight"]
    with pytest.raises(KeyError, match="lin3.model.1.weight"):
        lpips.weights_from_state_dict(sd)
    sd = _random_weights().state_dict()
    sd["features.6.weight"] = torch.zeros(384, 192, 5, 5)
    with pytest.raises(ValueError, match="features.6"):
        lpips.weights_from_state_dict(sd)
    sd = _random_weights().state_dict()
    sd["lin0.model.1.weight"] = -sd["lin0.model.1.weight"]
    with pytest.raises(ValueError, match="negative"):
        lpips.weights_from_state_dict(sd)


# ------------------------------------------------------------------------------------------ perf


def test_measure_fps_with_injected_clock():
    now = [0.0]
    calls = [0]

    def render():
        calls[0] += 1
        now[0] += 0.02

    r = perf.measure_fps(render, warmup=2, iters=10, clock=lambda: now[0])
    assert calls[0] == 12
    assert r["fps"] == pytest.approx(50.0) and r["ms_per_frame"] == pytest.approx(20.0)
    mem = perf.measure_peak_memory_mib(lambda: torch.zeros(10))
    assert mem is None or mem > 0


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_metrics_follow_cuda_inputs():
    pred, gt = _pair(18, 64, 72)
    pc, gc = torch.from_numpy(pred).cuda(), torch.from_numpy(gt).cuda()
    assert image.psnr(pc, gc) == pytest.approx(image.psnr(pred, gt), abs=1e-9)
    assert image.ssim(pc, gc) == pytest.approx(image.ssim(pred, gt), abs=1e-5)
    assert hdr.hdr_psnr(4 * pc, 4 * gc) == pytest.approx(hdr.hdr_psnr(4 * pred, 4 * gt), abs=1e-9)
    frames, fwd, bwd, vf, vb = _exact_translation_clip()
    fl = frames * np.array([1.0, 1.7, 0.6])[:, None, None, None]
    cpu = temporal.hdr_tae(fl, fwd, bwd, vf, vb)
    assert temporal.hdr_tae(
        torch.from_numpy(fl).cuda(),
        torch.from_numpy(fwd).cuda(),
        torch.from_numpy(bwd).cuda(),
        torch.from_numpy(vf).cuda(),
        torch.from_numpy(vb).cuda(),
    ) == pytest.approx(cpu, rel=1e-9)
    w = _random_weights()
    assert lpips.lpips(pc, gc, w) == pytest.approx(lpips.lpips(pred, gt, w), rel=1e-3)


def test_depth_edges_and_interior_visibility_on_a_hand_made_step():
    from eval.metrics.temporal import depth_edges, interior_visibility

    d = np.ones((6, 10))
    d[:, 5:] = 2.0  # a 100 % depth jump between columns 4 and 5
    d[0, 0] = 0.0  # one pixel without a surface
    e = depth_edges(d, radius=0)
    expect = np.zeros((6, 10), bool)
    expect[:, 4:6] = True
    expect[0, 0] = expect[0, 1] = expect[1, 0] = True
    assert (e == expect).all()
    e1 = depth_edges(d, radius=1)
    assert e1[:, 3:7].all() and not e1[3:, :3].any() and not e1[:, 7:].any()
    d2 = np.ones((6, 10))
    d2[:, 5:] = 1.03  # below the 5 % tolerance: no edge
    assert not depth_edges(d2).any()
    # interior visibility: pixels on an edge of a, or landing on an edge of b, are dropped
    vis = np.ones((6, 10), bool)
    flow = np.zeros((6, 10, 2))
    flow[:, 0, 0] = 4.0  # column 0 lands on column 4 (an edge of b)
    eb = np.zeros((6, 10), bool)
    eb[:, 4] = True
    ea = np.zeros((6, 10), bool)
    ea[2, 8] = True
    iv = interior_visibility(vis, flow, ea, eb)
    assert not iv[:, 0].any() and not iv[:, 4].any() and not iv[2, 8]
    assert iv.sum() == 60 - 6 - 6 - 1
