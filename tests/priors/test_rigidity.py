"""Rigidity-test dynamic masks (m4dgs.priors.rigidity).

Independent answers: the analytic flow of a fronto-parallel plane under a sideways camera
translation (u' - u = -f t_x / z) and of a pure rotation (a homography K R K^-1, independent of
depth); per-pixel projection written out by hand; a known moving square whose motion lies along the
epipolar lines, which the epipolar test cannot see."""

import math

import numpy as np
import pytest
import torch

from m4dgs.core.camera import K_from_fov, quat_to_rotmat
from m4dgs.priors.epipolar import EpipolarConfig, dynamic_masks, pair_error_map
from m4dgs.priors.rigidity import (
    DynamicMaskConfig,
    relative_threshold_masks,
    reprojection_error_maps,
    rigidity_masks,
    segment_distance,
    static_flow,
)
from m4dgs.training.config import preset

W, H = 80, 60


def _pose(R=None, t=(0.0, 0.0, 0.0)):
    c2w = torch.eye(4, dtype=torch.float64)
    if R is not None:
        c2w[:3, :3] = torch.as_tensor(R, dtype=torch.float64)
    c2w[:3, 3] = torch.as_tensor(t, dtype=torch.float64)
    return c2w


def test_static_flow_sideways_translation_of_a_plane():
    K = torch.as_tensor(K_from_fov(W, H, 60.0))
    z = 5.0
    depth = torch.full((H, W), z, dtype=torch.float64)
    tx = 0.3  # camera j sits 0.3 to the right: points move left by f tx / z
    flow, ok = static_flow(depth, K, _pose(), _pose(t=(tx, 0, 0)))
    assert ok.all()
    np.testing.assert_allclose(flow[..., 0].numpy(), -float(K[0, 0]) * tx / z, atol=1e-4)
    np.testing.assert_allclose(flow[..., 1].numpy(), 0.0, atol=1e-5)


def test_static_flow_pure_rotation_is_the_homography():
    K = torch.as_tensor(K_from_fov(W, H, 55.0))
    R = quat_to_rotmat(torch.tensor([0.995, 0.03, -0.06, 0.02], dtype=torch.float64))
    R = R / torch.linalg.det(R) ** (1 / 3)
    rng = np.random.default_rng(0)
    depth = torch.as_tensor(rng.uniform(1, 10, (H, W)))  # rotation-only flow ignores depth
    flow, ok = static_flow(depth, K, _pose(), _pose(R=R))
    # camera j = rotation R (c2w); a world point X maps to R^T X in camera j: homography K R^T K^-1
    Hm = (K @ R.T @ torch.linalg.inv(K)).numpy()
    for y, x in [(0, 0), (10, 70), (59, 3), (31, 40)]:
        p = Hm @ np.array([x + 0.5, y + 0.5, 1.0])
        np.testing.assert_allclose(flow[y, x].numpy(), p[:2] / p[2] - [x + 0.5, y + 0.5], atol=1e-4)
    assert ok.all()


def test_static_flow_general_motion_matches_hand_projection():
    K = torch.as_tensor(K_from_fov(W, H, 70.0))
    R1 = quat_to_rotmat(torch.tensor([0.99, 0.05, 0.02, -0.04], dtype=torch.float64))
    R2 = quat_to_rotmat(torch.tensor([0.98, -0.03, 0.1, 0.01], dtype=torch.float64))
    c1, c2 = _pose(R1, (0.2, -0.1, 0.3)), _pose(R2, (-0.4, 0.05, 0.1))
    rng = np.random.default_rng(1)
    depth = torch.as_tensor(rng.uniform(2, 6, (H, W)))
    depth[5, 7] = -1.0  # invalid
    flow, ok = static_flow(depth, K, c1, c2)
    assert not ok[5, 7] and ok.sum() == H * W - 1
    Kn = K.numpy()
    for y, x in [(0, 0), (20, 33), (59, 79)]:
        ray = np.linalg.inv(Kn) @ np.array([x + 0.5, y + 0.5, 1.0])
        Xw = c1.numpy()[:3, :3] @ (ray * float(depth[y, x])) + c1.numpy()[:3, 3]
        Xc = c2.numpy()[:3, :3].T @ (Xw - c2.numpy()[:3, 3])
        p = Kn @ Xc
        np.testing.assert_allclose(flow[y, x].numpy(), p[:2] / p[2] - [x + 0.5, y + 0.5], atol=1e-4)


def _sliding_square_scene(motion=4.0, noise=0.1, seed=0):
    """Three frames of a camera translating sideways over a smooth depth field; a square in frame 0
    slides by `motion` px horizontally, i.e. along the (horizontal) epipolar lines. Returns the
    inputs of reprojection_error_maps (with prior depth = world depth / 2 and BA scale 2) and the gt
    mask of frame 0."""
    rng = np.random.default_rng(seed)
    K = torch.as_tensor(K_from_fov(W, H, 60.0))
    ys, xs = np.meshgrid(np.arange(H) + 0.5, np.arange(W) + 0.5, indexing="ij")
    depth = torch.as_tensor(4.0 + np.sin(xs / 7.0) * np.cos(ys / 9.0))
    c2w = torch.stack([_pose(t=(0.15 * k, 0, 0)) for k in range(3)])
    pairs = [(0, 1), (1, 0), (1, 2), (2, 1)]
    flows, valids = [], []
    for i, j in pairs:
        f, ok = static_flow(depth, K, c2w[i], c2w[j])
        flows.append(f + torch.as_tensor(rng.normal(0, noise, f.shape), dtype=torch.float32))
        valids.append(ok)
    gt = torch.zeros(H, W, dtype=torch.bool)
    gt[20:36, 30:50] = True
    flows[0][gt, 0] += motion  # moving in frame 0 -> 1, horizontally
    prior = (depth / 2).expand(3, H, W).clone()
    scale = torch.full((3,), 2.0, dtype=torch.float64)
    return prior, scale, K, c2w, torch.stack(flows), torch.stack(valids), pairs, gt


def test_reprojection_error_is_the_added_motion():
    prior, scale, K, c2w, flow, valid, pairs, gt = _sliding_square_scene(motion=4.0, noise=0.0)
    err, ok = reprojection_error_maps(prior, scale, K, c2w, flow, valid, pairs, combine="max")
    assert ok.all()
    np.testing.assert_allclose(err[0][gt].numpy(), 4.0, atol=1e-3)
    assert float(err[0][~gt].abs().max()) < 1e-3 and float(err[1:].abs().max()) < 1e-3
    mean, _ = reprojection_error_maps(prior, scale, K, c2w, flow, valid, pairs, combine="mean")
    # frame 0 is the source of one pair
    np.testing.assert_allclose(mean[0][gt].numpy(), 4.0, atol=1e-3)
    # the wrong depth scale is an error of every static pixel (the test needs the BA scale)
    bad, _ = reprojection_error_maps(prior, scale / 2, K, c2w, flow, valid, pairs, combine="max")
    assert float(bad[0][~gt].median()) > 1.0


def test_rigidity_masks_see_motion_along_epipolar_lines_the_epipolar_test_misses():
    prior, scale, K, c2w, flow, valid, pairs, gt = _sliding_square_scene(motion=4.0, noise=0.1)
    masks = rigidity_masks(
        prior, scale, K, c2w, flow, valid, pairs, DynamicMaskConfig(method="reprojection")
    )
    iou = float((masks[0] & gt).sum() / (masks[0] | gt).sum())
    assert iou > 0.95
    assert masks[1:].float().mean() < 0.01  # static frames: only noise
    e, _, _ = pair_error_map(flow[0].numpy(), valid[0].numpy(), EpipolarConfig())
    epi = dynamic_masks(e[None], 1.0)[0]
    assert float((epi & gt).sum() / gt.sum()) < 0.1  # the square's flow stays on its epipolar line


def test_segment_distance_by_hand():
    a = torch.tensor([[-1.0, 0.0]] * 4)
    b = torch.tensor([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0], [-1.0, 0.0]])  # the last one a point
    p = torch.tensor([[0.0, 1.0], [3.0, 0.0], [-4.0, -4.0], [2.0, 4.0]])
    np.testing.assert_allclose(segment_distance(p, a, b).numpy(), [1.0, 2.0, 5.0, 5.0], atol=1e-6)


def test_depth_tolerance_forgives_a_wrong_depth_prior_and_not_motion_beyond_it():
    """Sideways translation t_x: a static point at depth z flows by -f t_x / z, so the depths z /
    1.1 .. 1.1 z cover the flows -1.1 f t_x / z .. -f t_x / (1.1 z). A depth prior 5 % too far
    (z' = 1.05 z) still covers the true flow (no error); the square's +4 px along the epipolar line
    leaves the range about z' by 4 - f t_x / z + f t_x / (1.1 z') px."""
    prior, scale, K, c2w, flow, valid, pairs, gt = _sliding_square_scene(motion=4.0, noise=0.0)
    wrong = prior * 1.05
    e0, _ = reprojection_error_maps(wrong, scale, K, c2w, flow, valid, pairs, combine="max")
    e1, ok = reprojection_error_maps(
        wrong, scale, K, c2w, flow, valid, pairs, combine="max", depth_tolerance=0.1
    )
    assert ok.all()
    assert float(e0[0][~gt].median()) > 0.1  # without the tolerance the depth error is an error
    assert float(e1[0][~gt].abs().max()) < 1e-3 and float(e1[1:].abs().max()) < 1e-3
    z = (prior[0] * 2.0)[gt].numpy()  # the true depth of frame 0 (the prior is depth / 2)
    f_tx = float(K[0, 0]) * 0.15  # pair (0, 1): camera 1 sits 0.15 to the right
    expected = 4.0 - f_tx / z + f_tx / (1.1 * 1.05 * z)
    np.testing.assert_allclose(e1[0][gt].numpy(), expected, atol=2e-3)
    # the segment holds the tolerance-free prediction: the error can only fall
    assert bool((e1 <= e0 + 1e-5).all())
    with pytest.raises(ValueError, match="depth_tolerance"):
        reprojection_error_maps(prior, scale, K, c2w, flow, valid, pairs, depth_tolerance=-0.1)


def test_relative_threshold_floor_and_frames_without_pairs():
    err = torch.zeros(3, 10, 20)
    err[0, 2, 3] = 0.5
    valid = torch.ones(3, 10, 20, dtype=torch.bool)
    valid[0, 2, 4] = False
    err[0, 2, 4] = 9.0  # invalid pixels are never dynamic
    floor = 1e-2  # x diagonal 22.4 px = 0.224 px: with a zero median, only the floor decides
    m = relative_threshold_masks(err, valid, 3.0, floor)
    assert m.sum() == 1 and m[0, 2, 3]
    assert math.isclose(floor * math.hypot(10, 20), 0.2236, rel_tol=1e-3)
    # frame 2 is the source of no pair: it copies frame 1's maps
    prior, scale, K, c2w, flow, valid3, pairs, gt = _sliding_square_scene(noise=0.0)
    keep = [p for p, (i, _) in enumerate(pairs) if i != 2]
    err3, ok3 = reprojection_error_maps(
        prior, scale, K, c2w, flow[keep], valid3[keep], [pairs[p] for p in keep]
    )
    assert torch.equal(err3[2], err3[1]) and torch.equal(ok3[2], ok3[1])
    with pytest.raises(ValueError, match="pairs"):
        reprojection_error_maps(prior, scale, K, c2w, flow, valid3, pairs[:2])


def test_mask_config_presets_and_validation():
    assert preset("paper").masks.method == "epipolar"  # sec. 3.3.2 as written
    assert preset("small").masks.method == "union"
    with pytest.raises(ValueError, match="masks.method"):
        DynamicMaskConfig(method="flow").validate()
    with pytest.raises(ValueError, match="masks.combine"):
        DynamicMaskConfig(combine="median").validate()
