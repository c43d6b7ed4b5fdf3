"""Epipolar geometry, RANSAC, error maps, dynamic masks and the classical flow/track fallback
(m4dgs.priors.epipolar).

Independent answers: the analytic F = K^-T [t]x R K^-1 of a known two-view geometry; exact
correspondences by projection; a flow field built from a known rigid motion plus a known moving
square; OpenCV-free reference shifts."""

import numpy as np
import pytest
import torch

from m4dgs.clip import FlowSet
from m4dgs.core.camera import K_from_fov, quat_to_rotmat
from m4dgs.priors.epipolar import (
    EpipolarConfig,
    analytic_fundamental,
    dynamic_masks,
    eight_point,
    epipolar_error_maps,
    normalise_brightness,
    opencv_flow_prior,
    pair_error_map,
    ransac_fundamental,
    sampson_error,
    symmetric_epipolar_error,
    tracks_from_flow,
)

W, H = 96, 72


def _two_view(n=200, seed=0):
    rng = np.random.default_rng(seed)
    K = torch.as_tensor(K_from_fov(W, H, 60.0))
    R = quat_to_rotmat(torch.tensor([0.99, 0.02, -0.08, 0.03], dtype=torch.float64))
    t = torch.tensor([0.4, -0.1, 0.15], dtype=torch.float64)
    X = torch.as_tensor(
        np.stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(3, 8, n)], -1)
    )
    X2 = X @ R.T + t
    x1 = (X @ K.T)[:, :2] / X[:, 2:]
    x2 = (X2 @ K.T)[:, :2] / X2[:, 2:]
    return K, R, t, x1, x2


def _same_up_to_scale(A, B):
    a = A / A.norm()
    b = B / B.norm()
    return min(float((a - b).abs().max()), float((a + b).abs().max()))


def test_eight_point_matches_analytic_F():
    K, R, t, x1, x2 = _two_view()
    F = eight_point(x1, x2)
    h1 = torch.cat([x1, torch.ones(len(x1), 1, dtype=torch.float64)], 1)
    h2 = torch.cat([x2, torch.ones(len(x2), 1, dtype=torch.float64)], 1)
    alg = (h2 * (h1 @ F.T)).sum(-1)
    # algebraic residual relative to the scale of the terms |x2| |F| |x1|
    assert float(alg.abs().max()) / float(h1.norm(dim=1).max() * h2.norm(dim=1).max()) < 1e-10
    Fa = analytic_fundamental(K, K, R, t)
    assert _same_up_to_scale(F, Fa) < 1e-6
    assert float(torch.linalg.svdvals(F)[2]) < 1e-10  # rank 2
    # Sampson and point-to-line errors vanish on exact data
    assert float(sampson_error(F, x1, x2).max()) < 1e-12
    assert float(symmetric_epipolar_error(F, x1, x2).max()) < 1e-12


def test_sampson_and_symmetric_error_values():
    # F of a pure horizontal translation with K = I: epipolar lines are rows (y' = y); a vertical
    # offset dy gives
    # point-to-line distances |dy| in both images -> symmetric error dy^2, Sampson (dy^2)/2 (two
    # unit gradients)
    F = analytic_fundamental(
        torch.eye(3), torch.eye(3), torch.eye(3), torch.tensor([1.0, 0.0, 0.0])
    )
    x1 = torch.tensor([[10.0, 5.0], [3.0, -2.0]], dtype=torch.float64)
    x2 = x1 + torch.tensor([[4.0, 1.5], [-2.0, -0.5]], dtype=torch.float64)
    dy2 = torch.tensor([1.5**2, 0.5**2], dtype=torch.float64)
    assert torch.allclose(symmetric_epipolar_error(F, x1, x2), dy2)
    assert torch.allclose(sampson_error(F, x1, x2), dy2 / 2)


@pytest.mark.parametrize("method", ["lmeds", "msac"])
def test_ransac_rejects_moving_points(method):
    K, R, t, x1, x2 = _two_view(n=300, seed=1)
    rng = np.random.default_rng(2)
    x2 = x2 + torch.as_tensor(rng.normal(0, 0.2, x2.shape))
    out = np.arange(0, 300, 4)  # 25 % moving points: extra 2D motion of 5-15 px
    ang = rng.uniform(0, 2 * np.pi, out.size)
    mag = rng.uniform(5, 15, out.size)
    x2[out] += torch.as_tensor(np.stack([np.cos(ang) * mag, np.sin(ang) * mag], -1))
    F, inl = ransac_fundamental(x1, x2, method=method, threshold=1.0, seed=0)
    e = sampson_error(F, x1, x2)
    static = np.setdiff1d(np.arange(300), out)
    moving = out[np.abs((x2[out] - x1[out]).numpy()).sum(1) > 0]
    assert float(e[static].median()) < 0.1
    assert float(torch.quantile(e[static], 0.95)) < 0.5
    # most moving points far from their epipolar line (a motion along the line is invisible to F)
    assert float((e[moving] > 1.0).float().mean()) > 0.85
    assert float(inl[static].float().mean()) > 0.95
    assert _same_up_to_scale(F, analytic_fundamental(K, K, R, t)) < 0.05
    # the plain 8-point fit on everything is corrupted by the outliers
    F_ls = eight_point(x1, x2)
    assert float(sampson_error(F_ls, x1[static], x2[static]).median()) > 5 * float(
        e[static].median()
    )


def _rigid_flow_with_square(seed=0, square=(30, 20, 22, 18), motion=(0.0, 4.0)):
    """Exact flow of a smooth depth field under a known camera motion + a moving square (gt
    mask)."""
    K = K_from_fov(W, H, 55.0)
    ys, xs = np.meshgrid(np.arange(H) + 0.5, np.arange(W) + 0.5, indexing="ij")
    depth = 4.0 + 1.5 * np.sin(xs / 9.0) * np.cos(ys / 11.0) + 0.02 * xs
    X = np.stack([(xs - K[0, 2]) / K[0, 0] * depth, (ys - K[1, 2]) / K[1, 1] * depth, depth], -1)
    R = quat_to_rotmat(np.array([1.0, 0.01, 0.03, -0.01]))
    t = np.array([0.35, 0.02, 0.1])
    X2 = X @ R.T + t
    u2 = K[0, 0] * X2[..., 0] / X2[..., 2] + K[0, 2]
    v2 = K[1, 1] * X2[..., 1] / X2[..., 2] + K[1, 2]
    flow = np.stack([u2 - xs, v2 - ys], -1)
    x0, y0, w, h = square
    mask = np.zeros((H, W), bool)
    mask[y0 : y0 + h, x0 : x0 + w] = True
    flow[mask] += np.asarray(motion)
    return flow.astype(np.float32), mask


def _iou(a, b):
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    return (a & b).sum() / max((a | b).sum(), 1)


@pytest.mark.parametrize("units,threshold", [("px", 1.0), ("ndc", 1.0 / ((W / 2) * (H / 2)))])
def test_dynamic_mask_iou_moving_square(units, threshold):
    flow, gt = _rigid_flow_with_square()
    rng = np.random.default_rng(0)
    flow_noisy = flow + rng.normal(0, 0.15, flow.shape).astype(np.float32)
    cfg = EpipolarConfig(units=units, threshold=threshold)
    e, F, frac = pair_error_map(flow_noisy, np.ones((H, W), bool), cfg)
    m = dynamic_masks(e[None], cfg.threshold)[0].numpy()
    assert _iou(m, gt) > 0.9
    assert 0.8 < frac < 0.97  # the square (6 % of the pixels) is the outlier set
    # error units: ndc errors are the px errors rescaled by ~ (2/W)(2/H) (exactly so for the
    # symmetric error on a square image; here a rough check)
    if units == "ndc":
        e_px, _, _ = pair_error_map(flow_noisy, np.ones((H, W), bool), EpipolarConfig())
        ratio = float(e[gt].median() / e_px[gt].median())
        assert 0.3 * (4 / (W * H)) < ratio < 3 * (4 / (W * H))


def test_epipolar_error_maps_combine_and_fill():
    flow, gt = _rigid_flow_with_square()
    flow_b, gt_b = _rigid_flow_with_square(square=(50, 40, 20, 20), motion=(-3.0, 3.0))
    ones = np.ones((H, W), bool)
    fs = FlowSet(
        pairs=np.array([[0, 3], [0, 6], [6, 3]]),
        flow=np.stack([flow, flow_b, flow]),
        valid=np.stack([ones, ones, ones]),
    )
    frames = [0, 3, 6]
    emax = epipolar_error_maps(fs, frames, EpipolarConfig(combine="max"))
    emean, info = epipolar_error_maps(fs, frames, EpipolarConfig(combine="mean"), return_info=True)
    assert emax.shape == (3, H, W)
    m = dynamic_masks(emax, 1.0)
    assert _iou(m[0], gt | gt_b) > 0.85  # max: union of both pairs' moving squares
    assert _iou(m[2], gt) > 0.9
    # frame 3 has no pair: the nearest frame's map (tie -> the earlier one)
    assert torch.equal(emean[1], emean[0]) and info["filled_from"] == {3: 0}
    # mean of two maps equals their average where both are valid
    e0, _, _ = pair_error_map(flow, ones, EpipolarConfig(), seed_offset=0)
    e1, _, _ = pair_error_map(flow_b, ones, EpipolarConfig(), seed_offset=1)
    assert torch.allclose(emean[0], (e0 + e1) / 2, rtol=1e-4, atol=1e-6)
    assert torch.equal(
        epipolar_error_maps(
            FlowSet(
                np.zeros((0, 2), np.int64),
                np.zeros((0, H, W, 2), np.float32),
                np.zeros((0, H, W), bool),
            ),
            frames,
        ),
        torch.zeros(3, H, W),
    )


def _textured(seed=0):
    rng = np.random.default_rng(seed)
    import cv2

    base = rng.uniform(0, 1, (H // 4, W // 4))
    img = cv2.resize(base, (W, H), interpolation=cv2.INTER_CUBIC)
    return np.clip(img, 0.05, 0.95)


def test_normalise_brightness_removes_exposure():
    lin = _textured() ** 2.2 * 0.2
    a = np.round(np.clip((lin * 1.0) ** (1 / 2.2), 0, 1) * 255).astype(np.uint8)
    b = np.round(np.clip((lin * 4.0) ** (1 / 2.2), 0, 1) * 255).astype(np.uint8)
    na = normalise_brightness(np.repeat(a[..., None], 3, -1), 1.0, 2.0).astype(float)
    nb = normalise_brightness(np.repeat(b[..., None], 3, -1), 4.0, 2.0).astype(float)
    assert np.abs(na - nb).mean() < 2.0  # both at the reference exposure 2.0
    ref = np.round(np.clip((lin * 2.0) ** (1 / 2.2), 0, 1) * 255)
    assert np.abs(na - ref).mean() < 2.0


def test_opencv_flow_prior_and_tracks_on_shifted_texture():
    # frames: a texture translated by 1 px per frame; exposures alternate 1, 4 (same-exposure pairs
    # 2 apart)
    big = _textured(3)
    import cv2

    big = cv2.resize(big, (W * 2, H * 2), interpolation=cv2.INTER_CUBIC)
    frames, dts = [], []
    for i in range(6):
        # content moves left by 1 px per frame -> flow (-1, 0)
        crop = big[20 : 20 + H, 20 + i : 20 + i + W]
        dt = 1.0 if i % 2 == 0 else 4.0
        ldr = np.round(
            np.clip((np.clip(crop, 0, 1) ** 2.2 * 0.2 * dt) ** (1 / 2.2), 0, 1) * 255
        ).astype(np.uint8)
        frames.append(np.repeat(ldr[..., None], 3, -1))
        dts.append(dt)
    g = [0, 2, 4, 6, 8, 10]
    fs = opencv_flow_prior(np.stack(frames), dts, g)
    want = [(0, 4), (4, 0), (4, 8), (8, 4), (2, 6), (6, 2), (6, 10), (10, 6)]
    assert sorted(map(tuple, fs.pairs.tolist())) == sorted(want)
    f, v = fs.get(0, 4)
    inner = (slice(8, H - 8), slice(8, W - 8))
    assert (
        np.median(np.abs(f[inner][..., 0] + 2.0)) < 0.2
        and np.median(np.abs(f[inner][..., 1])) < 0.2
    )
    assert v[inner].mean() > 0.9
    ts = tracks_from_flow(fs, g, grid_step=8)
    assert ts.tracks.shape[1] == 6
    # a track seeded in frame 0 moves -2 px per same-exposure link (frames 0 -> 4 -> 8 = indices 0,
    # 2, 4)
    sel = ts.visible[:, 0] & ts.visible[:, 2] & ts.visible[:, 4]
    sel &= (ts.tracks[:, 0, 0] > 16) & (ts.tracks[:, 0, 0] < W - 16)
    assert sel.sum() > 20
    d = ts.tracks[sel][:, [2, 4]] - ts.tracks[sel][:, [0, 0]]
    assert np.median(np.abs(d[:, 0, 0] + 2)) < 0.3 and np.median(np.abs(d[:, 1, 0] + 4)) < 0.5
    assert not ts.visible[sel][:, 1].any()  # other exposure level: not on this chain
    # consecutive mode links adjacent frames across exposures
    fc = opencv_flow_prior(np.stack(frames), dts, g, mode="consecutive")
    f01, v01 = fc.get(0, 2)
    assert np.median(np.abs(f01[inner][..., 0] + 1.0)) < 0.3
