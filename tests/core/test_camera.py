"""Camera conventions: round trips to 1e-6 and known answers (independent of the code under
test)."""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from m4dgs.core import camera as C

RNG = np.random.default_rng(0)


def random_c2w(n):
    R = Rotation.random(n, random_state=1).as_matrix()
    T = RNG.normal(size=(n, 3))
    return C.make_c2w(R, T)


def test_quat_matches_scipy():
    q = RNG.normal(size=(50, 4))
    R = C.quat_to_rotmat(q)
    qn = q / np.linalg.norm(q, axis=-1, keepdims=True)
    R_ref = Rotation.from_quat(qn[:, [1, 2, 3, 0]]).as_matrix()  # scipy is (x, y, z, w)
    np.testing.assert_allclose(R, R_ref, atol=1e-12)


def test_quat_rotmat_round_trip_including_edge_cases():
    R = Rotation.random(200, random_state=2).as_matrix()
    # rotations by pi about axes exercise the non-w branches
    R = np.concatenate([R, Rotation.from_rotvec(np.pi * np.eye(3)).as_matrix(), np.eye(3)[None]])
    q = C.rotmat_to_quat(R)
    assert (q[:, 0] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1, atol=1e-12)
    np.testing.assert_allclose(C.quat_to_rotmat(q), R, atol=1e-9)


def test_quat_multiply_composes_rotations():
    a, b = RNG.normal(size=(10, 4)), RNG.normal(size=(10, 4))
    np.testing.assert_allclose(
        C.quat_to_rotmat(C.quat_multiply(a, b)),
        C.quat_to_rotmat(a) @ C.quat_to_rotmat(b),
        atol=1e-12,
    )


def test_c2w_w2c_round_trip():
    c2w = random_c2w(20)
    w2c = C.c2w_to_w2c(c2w)
    np.testing.assert_allclose(w2c @ c2w, np.tile(np.eye(4), (20, 1, 1)), atol=1e-12)
    np.testing.assert_allclose(w2c, np.linalg.inv(c2w), atol=1e-12)
    p = RNG.normal(size=(20, 3))
    np.testing.assert_allclose(C.transform_points(c2w, C.transform_points(w2c, p)), p, atol=1e-12)


def test_transform_points_broadcasts_like_homogeneous_coordinates():
    """[..., 4, 4] transforms against [..., 3] points with broadcasting (one transform and an image
    of points; a batch of transforms against shared points), checked against M @ [p, 1] per
    element."""
    c2w = random_c2w(3)
    img = RNG.normal(size=(4, 5, 3))
    out = C.transform_points(c2w[0], img)
    hom = np.concatenate([img, np.ones((4, 5, 1))], -1)
    np.testing.assert_allclose(out, np.einsum("ij,hwj->hwi", c2w[0], hom)[..., :3], atol=1e-12)
    pts = RNG.normal(size=(7, 3))
    out = C.transform_points(c2w[:, None], pts)  # [3, 1, 4, 4] x [7, 3] -> [3, 7, 3]
    assert out.shape == (3, 7, 3)
    for b in range(3):
        for k in range(7):
            np.testing.assert_allclose(out[b, k], (c2w[b] @ np.append(pts[k], 1.0))[:3], atol=1e-12)


def test_camera_centre_is_translation():
    c2w = random_c2w(1)[0]
    np.testing.assert_allclose(C.transform_points(c2w, np.zeros(3)), c2w[:3, 3], atol=1e-12)


def test_projection_known_answer_and_round_trip():
    K = C.K_from_fov(200, 100, 90.0)  # fx = 100 / tan(45 deg) = 100
    np.testing.assert_allclose(K, [[100, 0, 100], [0, 100, 50], [0, 0, 1]], atol=1e-12)
    # a point 1 right, 0.5 down, 2 forward lands at u = 100 + 100 * 0.5 = 150, v = 50 + 100 * 0.25 =
    # 75
    np.testing.assert_allclose(
        C.project_pinhole(np.array([1.0, 0.5, 2.0]), K), [150, 75], atol=1e-12
    )
    # the centre of pixel (0, 0) is (0.5, 0.5): the ray through it points up-left
    ray = C.unproject_pinhole(np.array([0.5, 0.5]), 1.0, K)
    np.testing.assert_allclose(ray, [(0.5 - 100) / 100, (0.5 - 50) / 100, 1.0], atol=1e-12)
    uv = RNG.uniform(0, 100, size=(100, 2))
    d = RNG.uniform(0.5, 10, size=100)
    np.testing.assert_allclose(C.project_pinhole(C.unproject_pinhole(uv, d, K), K), uv, atol=1e-9)


def test_ortho_mapping():
    W, H = 216, 120
    # pixel centre of the first column maps to x = 2 * 0.5 / W - 1; image edges map to -1 and +1
    np.testing.assert_allclose(
        C.pixel_to_ortho(np.array([0.5, 0.5]), W, H), [1 / W - 1, 1 / H - 1], atol=1e-15
    )
    np.testing.assert_allclose(C.pixel_to_ortho(np.array([W, H]), W, H), [1, 1], atol=1e-15)
    uv = RNG.uniform(0, W, size=(50, 2))
    np.testing.assert_allclose(C.ortho_to_pixel(C.pixel_to_ortho(uv, W, H), W, H), uv, atol=1e-9)
    # the orthographic K reproduces the same mapping as u = fx x + cx
    K = C.K_ortho(W, H)
    xy = RNG.uniform(-1, 1, size=(5, 2))
    np.testing.assert_allclose(
        C.ortho_to_pixel(xy, W, H), xy * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]], atol=1e-12
    )


def test_video_camera_round_trip():
    W, H = 64, 48
    K = C.K_from_fov(W, H, 60.0)
    p = np.column_stack([RNG.uniform(-1, 1, 30), RNG.uniform(-1, 1, 30), RNG.uniform(1, 5, 30)])
    np.testing.assert_allclose(
        C.camera_to_video(C.video_to_camera(p, K, W, H), K, W, H), p, atol=1e-9
    )


def test_slerp_known_answer():
    q0 = np.array([1.0, 0, 0, 0])
    q1 = Rotation.from_rotvec([0, 0, np.pi / 2]).as_quat()[[3, 0, 1, 2]]
    q = C.slerp(q0, q1, 0.5)
    ref = Rotation.from_rotvec([0, 0, np.pi / 4]).as_quat()[[3, 0, 1, 2]]
    np.testing.assert_allclose(q, ref, atol=1e-12)
    # short arc despite the sign flip
    np.testing.assert_allclose(C.slerp(q0, -q1, 0.5), ref, atol=1e-12)
    np.testing.assert_allclose(C.slerp(q0, q0, 0.3), q0, atol=1e-12)


def test_pose_interpolation():
    c2w = random_c2w(2)
    mid = C.interpolate_pose(c2w[0], c2w[1], 0.5)
    np.testing.assert_allclose(mid[:3, 3], (c2w[0, :3, 3] + c2w[1, :3, 3]) / 2, atol=1e-12)
    rel = Rotation.from_matrix(c2w[0, :3, :3].T @ c2w[1, :3, :3]).as_rotvec()
    ref = c2w[0, :3, :3] @ Rotation.from_rotvec(rel / 2).as_matrix()
    np.testing.assert_allclose(mid[:3, :3], ref, atol=1e-9)
    np.testing.assert_allclose(C.interpolate_pose(c2w[0], c2w[1], 0.0), c2w[0], atol=1e-9)
    np.testing.assert_allclose(C.interpolate_pose(c2w[0], c2w[1], 1.0), c2w[1], atol=1e-9)


def test_trajectory_interpolation_test_frames():
    c2w = random_c2w(3)
    q = C.interpolate_trajectory(
        np.array([0.0, 2.0, 4.0]), c2w, np.array([0.0, 1.0, 3.0, 4.0, 5.0])
    )
    np.testing.assert_allclose(q[0], c2w[0], atol=1e-9)
    np.testing.assert_allclose(q[1], C.interpolate_pose(c2w[0], c2w[1], 0.5), atol=1e-9)
    np.testing.assert_allclose(q[2], C.interpolate_pose(c2w[1], c2w[2], 0.5), atol=1e-9)
    np.testing.assert_allclose(q[4], c2w[2], atol=1e-9)  # clamped past the last training frame


def test_umeyama_recovers_similarity():
    src = RNG.normal(size=(40, 3))
    R = Rotation.random(random_state=3).as_matrix()
    dst = 2.5 * src @ R.T + np.array([1.0, -2.0, 0.5])
    s, R_est, t = C.umeyama_sim3(src, dst)
    assert abs(s - 2.5) < 1e-9
    np.testing.assert_allclose(R_est, R, atol=1e-9)
    np.testing.assert_allclose(t, [1.0, -2.0, 0.5], atol=1e-9)
    s1, _, _ = C.umeyama_sim3(src, dst, with_scale=False)
    assert s1 == 1.0


def test_torch_inputs_are_differentiable():
    q = torch.randn(4, 4, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: C.quat_to_rotmat(x), (q,))
    p = torch.tensor([[0.3, -0.2, 2.0]], dtype=torch.float64, requires_grad=True)
    K = torch.tensor(C.K_from_fov(32, 24, 60.0))
    assert torch.autograd.gradcheck(lambda x: C.project_pinhole(x, K), (p,))
