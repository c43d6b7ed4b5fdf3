"""Tests of the loss functions (m4dgs.losses) on hand-computed cases and independent references."""

import math

import numpy as np
import pytest
import torch

from m4dgs.core.knn import knn
from m4dgs.core.ssim import ssim
from m4dgs.core.warp import sample_map
from m4dgs.losses.geometry import (
    depth_loss,
    destination_pixels,
    flow_from_destination_map,
    flow_loss,
    track_loss,
)
from m4dgs.losses.motion import (
    acceleration_loss,
    arap_loss,
    quat_relative_angle,
    relative_to_neighbours,
    smoothness_terms,
    velocity_loss,
    window_times,
)
from m4dgs.losses.photometric import rgb_loss, unit_exposure_loss
from m4dgs.losses.temporal import (
    hdr_reprojection_loss,
    ldr_reprojection_loss,
    reprojection_coords,
    tlr_den_floor,
    tlr_loss,
    tlr_loss_neighbours,
    tlr_valid_mask,
)


# --------------------------------------------------------------------------------------------------
# Photometric
# --------------------------------------------------------------------------------------------------
def test_rgb_loss_equals_hand_formula():
    g = torch.Generator().manual_seed(0)
    a = torch.rand(24, 20, 3, generator=g)
    b = (a + 0.1 * torch.randn(24, 20, 3, generator=g)).clamp(0, 1)
    l1 = np.abs(a.numpy() - b.numpy()).mean()
    s = float(ssim(a, b))
    expect = 0.8 * l1 + 0.2 * (1 - s) / 2
    assert float(rgb_loss(a, b)) == pytest.approx(expect, rel=1e-5)
    # an all-true mask changes nothing; a partial mask restricts the L1 term to the masked pixels
    assert float(rgb_loss(a, b, torch.ones(24, 20, dtype=torch.bool))) == pytest.approx(
        expect, rel=1e-5
    )
    m = torch.zeros(24, 20, dtype=torch.bool)
    m[:, :10] = True
    l1_m = np.abs(a.numpy()[:, :10] - b.numpy()[:, :10]).mean()
    assert float(rgb_loss(a, b, m, lambda_d=0.0)) == pytest.approx(l1_m, rel=1e-5)


def test_unit_exposure_loss_hand_case():
    phi0 = torch.tensor([0.70, 0.80, 0.73])
    assert float(unit_exposure_loss(phi0, 0.73)) == pytest.approx(0.03**2 + 0.07**2, rel=1e-4)
    assert float(unit_exposure_loss(phi0, 0.73, "mean")) == pytest.approx(
        (0.03**2 + 0.07**2) / 3, rel=1e-4
    )


# --------------------------------------------------------------------------------------------------
# Depth, flow, tracks
# --------------------------------------------------------------------------------------------------
def test_depth_loss_masked_hand_case():
    pred = torch.tensor([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], requires_grad=True)
    prior = torch.tensor([[1.5, 0.0, float("nan")], [3.0, 5.5, 9.0]])
    valid = torch.tensor([[True, True, True], [True, True, False]])
    # usable pixels: (0,0) 0.5, (1,0) 1.0, (1,1) 0.5 -> mean 2/3 (prior 0 / nan and the masked pixel
    # excluded)
    loss = depth_loss(pred, prior, valid)
    assert loss.item() == pytest.approx(2.0 / 3.0)
    loss.backward()
    assert torch.isfinite(pred.grad).all()
    assert pred.grad[0, 1] == 0 and pred.grad[0, 2] == 0 and pred.grad[1, 2] == 0
    # scale-shift invariant mode ignores an affine change of the prior
    p2 = torch.rand(5, 6) + 1
    assert float(depth_loss(p2, 3.0 * p2 + 2.0, scale_shift_invariant=True)) == pytest.approx(
        0.0, abs=1e-5
    )


def test_flow_from_video_destination_map_hand_case():
    H, W = 2, 4
    dest = torch.zeros(H, W, 3)
    dest[..., 2] = 1.0
    dest[0, 0] = torch.tensor([0.0, 0.0, 1.0])  # image centre: u = (0 + 1) * 4 / 2 = 2, v = 1
    dest[1, 3] = torch.tensor([-1.0, 1.0, 0.0])  # u = 0, v = 2; z = 0 -> invalid
    flow, valid = flow_from_destination_map(dest)
    torch.testing.assert_close(flow[0, 0], torch.tensor([2 - 0.5, 1 - 0.5]))
    torch.testing.assert_close(flow[1, 3], torch.tensor([0 - 3.5, 2 - 1.5]))
    torch.testing.assert_close(flow[1, 1], torch.tensor([2 - 1.5, 1 - 1.5]))
    assert valid.sum() == 7 and not valid[1, 3]
    # authors' index-space formula u = (x + 1) W / 2 - 0.5 minus the pixel index gives the same flow
    xs = torch.arange(W).float()
    authors_dx = (dest[..., 0] + 1) * W / 2 - 0.5 - xs
    torch.testing.assert_close(flow[..., 0], authors_dx)
    # un-normalised blends with their alpha give the same flow
    alpha = torch.full((H, W), 0.5)
    flow_a, valid_a = flow_from_destination_map(dest * 0.5, alpha=alpha)
    torch.testing.assert_close(flow_a, flow)


def test_flow_from_world_destination_map_pinhole():
    g = torch.Generator().manual_seed(1)
    H, W = 3, 5
    K = torch.tensor([[10.0, 0, 2.5], [0, 12.0, 1.5], [0, 0, 1]])
    pts = torch.randn(H, W, 3, generator=g) * 0.3 + torch.tensor([0.0, 0.0, 4.0])
    c, s = math.cos(0.2), math.sin(0.2)
    w2c = torch.tensor([[c, 0, s, 0.1], [0, 1, 0, -0.2], [-s, 0, c, 0.3], [0, 0, 0, 1]])
    flow, valid = flow_from_destination_map(pts, K=K, w2c_dst=w2c)
    pc = pts.numpy() @ w2c[:3, :3].numpy().T + w2c[:3, 3].numpy()
    u = 10.0 * pc[..., 0] / pc[..., 2] + 2.5
    v = 12.0 * pc[..., 1] / pc[..., 2] + 1.5
    jj, ii = np.meshgrid(np.arange(W), np.arange(H))
    np.testing.assert_allclose(flow[..., 0].numpy(), u - (jj + 0.5), rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(flow[..., 1].numpy(), v - (ii + 0.5), rtol=1e-5, atol=1e-4)
    assert valid.all()
    # same positions given already in the destination camera frame
    flow2, _ = flow_from_destination_map(torch.tensor(pc, dtype=torch.float32), K=K)
    torch.testing.assert_close(flow2, flow, atol=1e-4, rtol=1e-5)
    # a point behind the destination camera is invalid
    _, ok = destination_pixels(torch.tensor([[0.0, 0.0, -1.0]]), K=K)
    assert not ok[0]


def test_flow_loss_hand_case():
    pred = torch.tensor([[[1.0, 2.0], [0.0, 0.0]], [[3.0, -1.0], [5.0, 5.0]]], requires_grad=True)
    prior = torch.tensor([[[0.0, 0.0], [0.0, 0.0]], [[0.0, 3.0], [float("nan"), 0.0]]])
    valid = torch.tensor([[True, True], [True, True]])
    # L1 distances: 3, 0, 7, (nan prior excluded) -> 10 / 3
    loss = flow_loss(pred, prior, valid)
    assert loss.item() == pytest.approx(10.0 / 3.0)
    loss.backward()
    assert torch.isfinite(pred.grad).all() and (pred.grad[1, 1] == 0).all()
    # L2 distances sqrt(5), 0, 5; clamp at 4
    assert flow_loss(pred, prior, valid, norm="l2", clamp=4.0).item() == pytest.approx(
        (math.sqrt(5) + 4.0) / 3
    )
    valid[1, 0] = False
    assert flow_loss(pred, prior, valid).item() == pytest.approx(3.0 / 2.0)


def test_sample_map_bilinear_hand_case():
    H, W = 4, 5
    ys, xs = torch.meshgrid(torch.arange(H).float(), torch.arange(W).float(), indexing="ij")
    # linear in pixel index -> bilinear sampling is exact
    img = torch.stack([2 * xs + 1, 3 * ys - 2], -1)
    uv = torch.tensor([[1.3 + 0.5, 1.7 + 0.5], [0.5, 0.5], [4.5, 3.5]])  # centre convention
    out = sample_map(img, uv)
    expect = torch.tensor([[2 * 1.3 + 1, 3 * 1.7 - 2], [1.0, -2.0], [9.0, 7.0]])
    torch.testing.assert_close(out, expect)


def test_track_loss_video_space_hand_case():
    H, W = 6, 8
    # destination map of a uniform translation by (2, -1) px at depth 1: x = 2 (u + 2) / W - 1 with
    # u the centre
    ys, xs = torch.meshgrid(
        torch.arange(H).float() + 0.5, torch.arange(W).float() + 0.5, indexing="ij"
    )
    dest = torch.stack([2 * (xs + 2) / W - 1, 2 * (ys - 1) / H - 1, torch.ones(H, W)], -1)
    dest[5, 7, 2] = 0.0  # a pixel whose destination depth is invalid
    src = torch.tensor([[2.8, 3.2], [1.0, 1.5], [4.4, 2.6], [7.5, 5.5]])
    true_dst = src + torch.tensor([2.0, -1.0])
    dst = true_dst + torch.tensor([[3.0, 4.0], [0.0, 0.0], [-6.0, 8.0], [0.0, 0.0]])
    valid = torch.tensor([True, True, False, True])
    # track 2 masked by visibility; track 3 samples the z = 0 pixel -> excluded. Errors: (3, 4), (0,
    # 0)
    assert float(track_loss(dest, src, dst, valid)) == pytest.approx((7.0 + 0.0) / 2, rel=1e-5)
    assert float(track_loss(dest, src, dst, valid, norm="l2")) == pytest.approx(5.0 / 2, rel=1e-5)
    assert float(track_loss(dest, src, dst, valid, norm="l2", clamp=4.0)) == pytest.approx(
        4.0 / 2, rel=1e-5
    )
    assert float(track_loss(dest, src, true_dst)) == pytest.approx(0.0, abs=1e-5)
    d = dest.clone().requires_grad_(True)
    track_loss(d, src, dst, valid).backward()
    assert torch.isfinite(d.grad).all() and d.grad.abs().sum() > 0


def test_track_loss_pinhole_world():
    K = torch.tensor([[20.0, 0, 8.0], [0, 20.0, 6.0], [0, 0, 1]])
    H, W = 12, 16
    P = torch.tensor([0.5, -0.2, 5.0])
    dest = P.expand(
        H, W, 3
    ).clone()  # every pixel's point ends at P (world); destination camera = identity
    src = torch.tensor([[3.3, 4.1]])
    u = 20.0 * 0.5 / 5.0 + 8.0
    v = 20.0 * -0.2 / 5.0 + 6.0
    dst = torch.tensor([[u + 1.0, v - 2.0]])
    assert float(track_loss(dest, src, dst, K=K, w2c_dst=torch.eye(4))) == pytest.approx(
        3.0, rel=1e-5
    )


# --------------------------------------------------------------------------------------------------
# Motion regularisation
# --------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("backend", ["torch", "scipy"])
def test_knn_matches_brute_force(backend):
    g = torch.Generator().manual_seed(0)
    pts = torch.randn(300, 3, generator=g)
    idx, dist = knn(pts, 5, chunk_elems=300 * 7, backend=backend)  # torch: 7 rows per chunk
    d = np.linalg.norm(pts.numpy()[:, None] - pts.numpy()[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    ref = np.argsort(d, axis=1)[:, :5]
    np.testing.assert_array_equal(idx.numpy(), ref)
    np.testing.assert_allclose(dist.numpy(), np.take_along_axis(d, ref, 1), rtol=1e-4, atol=1e-5)


def test_knn_excludes_self_with_duplicates():
    pts = torch.tensor([[0.0, 0, 0], [0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0]])
    for backend in ("torch", "scipy"):
        idx, dist = knn(pts, 2, backend=backend)
        assert (idx != torch.arange(4)[:, None]).all()
        torch.testing.assert_close(dist[:, 0], torch.tensor([0.0, 0.0, 1.0, 2.0]))


def _random_rotation(seed):
    q = torch.randn(4, generator=torch.Generator().manual_seed(seed))
    q = q / q.norm()
    w, x, y, z = q
    return torch.tensor(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_arap_rigid_zero_nonrigid_positive():
    pts = torch.randn(200, 3, generator=torch.Generator().manual_seed(3))
    R = _random_rotation(4)
    moved = pts @ R.T + torch.tensor([1.0, -2.0, 0.5])
    assert float(arap_loss(pts, moved)) == pytest.approx(0.0, abs=1e-9)
    stretched = pts * torch.tensor([1.2, 1.0, 1.0])
    assert float(arap_loss(pts, stretched)) > 1e-3


def test_arap_three_point_hand_case():
    p_t = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    p_tp = torch.tensor([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]], requires_grad=True)
    # k = 2: all pairs in both directions. Pair distance changes: 01: 1 -> 2, 02: 2 -> 2, 12: sqrt5
    # -> sqrt8
    d = (math.sqrt(8) - math.sqrt(5)) ** 2
    expect = (1.0 + 0.0 + 1.0 + d + 0.0 + d) / 6.0
    loss = arap_loss(p_t, p_tp, k=2)
    assert loss.item() == pytest.approx(expect, rel=1e-6)
    loss.backward()
    assert torch.isfinite(p_tp.grad).all()


def _axis_quats(angles, axis):
    axis = axis / axis.norm()
    half = angles / 2
    return torch.cat([torch.cos(half)[..., None], torch.sin(half)[..., None] * axis], -1)


def test_velocity_acceleration_linear_and_quadratic():
    T, N = 6, 4
    t = torch.arange(T, dtype=torch.float64)[:, None, None]
    a = torch.randn(1, N, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(5))
    b = torch.tensor([0.3, -0.4, 1.2], dtype=torch.float64)  # |b| = 1.3
    lin = a + b * t
    assert float(velocity_loss(lin)) == pytest.approx((T - 1) * 1.3)
    assert float(acceleration_loss(lin)) == pytest.approx(0.0, abs=1e-9)
    assert float(velocity_loss(lin, stride=2)) == pytest.approx((T - 2) * 2 * 1.3)
    assert float(velocity_loss(lin, time_reduction="mean")) == pytest.approx(1.3)
    c = torch.tensor([0.0, 0.6, 0.8], dtype=torch.float64)  # |c| = 1
    quad = a + c * t**2
    # |mu_{t+1} - mu_t| = (2t + 1) |c| summed over t = 0..T-2 = (T - 1)^2; second difference = 2c
    assert float(velocity_loss(quad)) == pytest.approx((T - 1) ** 2)
    assert float(acceleration_loss(quad)) == pytest.approx((T - 2) * 2.0)


def test_rotation_smoothness_constant_and_accelerating():
    T, N = 7, 3
    axis = torch.tensor([1.0, 2.0, -0.5], dtype=torch.float64)
    omega = 0.25
    pos = torch.zeros(T, N, 3, dtype=torch.float64)
    steps = torch.arange(T, dtype=torch.float64)
    q = _axis_quats(omega * steps, axis)[:, None].expand(T, N, 4) * 3.0  # unnormalised on purpose
    terms = smoothness_terms(pos, q)
    assert float(terms["rot_vel"]) == pytest.approx((T - 1) * omega, rel=1e-9)
    assert float(terms["rot_acc"]) == pytest.approx(0.0, abs=1e-9)
    alpha = 0.05
    q2 = _axis_quats(alpha * steps**2, axis)[:, None].expand(T, N, 4)
    # per-step angles alpha (2t + 1); their differences 2 alpha
    assert float(acceleration_loss(pos, q2)) == pytest.approx((T - 2) * 2 * alpha, rel=1e-7)
    assert float(quat_relative_angle(q2[3, 0], q2[3, 0])) == pytest.approx(0.0, abs=1e-7)


def test_smoothness_gradient_finite_at_rest():
    pos = torch.zeros(5, 2, 3, requires_grad=True)
    q = torch.tensor([1.0, 0, 0, 0]).expand(5, 2, 4).clone().requires_grad_(True)
    (velocity_loss(pos, q) + acceleration_loss(pos, q)).backward()
    assert torch.isfinite(pos.grad).all() and torch.isfinite(q.grad).all()


def test_window_times():
    assert window_times(5, 20) == [3, 4, 5, 6, 7]
    assert window_times(0, 20) == [0, 1, 2, 3, 4]
    assert window_times(19, 20) == [15, 16, 17, 18, 19]
    assert window_times(1, 3) == [0, 1, 2]


# --------------------------------------------------------------------------------------------------
# Temporal luminance regularisation
# --------------------------------------------------------------------------------------------------
def test_tlr_static_scene_zero_and_flicker_ratio():
    g = torch.Generator().manual_seed(7)
    h = torch.rand(10, 12, 3, generator=g) * 5 + 0.1
    zero = torch.zeros(10, 12, 2)
    assert float(tlr_loss(h, h.clone(), zero)) == pytest.approx(0.0, abs=1e-6)
    r = 1.7
    assert float(tlr_loss(h, r * h, zero)) == pytest.approx(abs(r - 1) / (r + 1), rel=1e-5)
    # exact integer motion with its exact flow: zero on the pixels that stay in the image
    nb = torch.zeros_like(h)
    nb[1:, 2:] = h[:-1, :-2]  # content moved by (+2, +1) px
    flow = torch.zeros(10, 12, 2)
    flow[..., 0], flow[..., 1] = 2.0, 1.0
    assert float(tlr_loss(h, nb, flow)) == pytest.approx(0.0, abs=1e-6)


def test_tlr_gradient_only_into_current_frame():
    h = torch.tensor([[[1.0, 2.0, 3.0]]]).repeat(2, 2, 1).requires_grad_(True)
    nb = torch.tensor([[[3.0, 2.0, 1.0]]]).repeat(2, 2, 1).requires_grad_(True)
    flow = torch.zeros(2, 2, 2, requires_grad=True)
    loss = tlr_loss(h, nb, flow)
    # per pixel: |3-1|/4, 0, |1-3|/4 -> mean 1/3
    assert loss.item() == pytest.approx(1.0 / 3.0)
    loss.backward()
    assert nb.grad is None and flow.grad is None
    # detached denominator: d/dH |Hw - H| / (Hw + H) = -sign(Hw - H) / (Hw + H), divided by 12
    # elements
    expect = torch.tensor([-1 / 4, 0.0, 1 / 4]) / 12
    torch.testing.assert_close(h.grad[0, 0], expect)
    # with the denominator attached: d/dH (Hw - H)/(Hw + H) = -2 Hw / (Hw + H)^2 for Hw > H
    h2 = h.detach().clone().requires_grad_(True)
    tlr_loss(h2, nb.detach(), flow.detach(), detach_denominator=False).backward()
    assert float(h2.grad[0, 0, 0]) == pytest.approx(-2 * 3 / 16 / 12)


def test_tlr_denominator_floor():
    """loss.tlr_den_floor: the floor is fraction x the render's median; the loss and its gradient
    are the hand formula |Hw - H| / (Hw + H + floor) with the floor and the denominator held
    constant; fraction 0 is the paper's loss, bit for bit."""
    g = torch.Generator().manual_seed(3)
    h = (torch.rand(6, 7, 3, generator=g) * 4).requires_grad_(True)
    nb = torch.rand(6, 7, 3, generator=g) * 4
    flow = torch.zeros(6, 7, 2)
    assert tlr_den_floor(h, 0.0) == 0.0
    floor = tlr_den_floor(h, 0.25)
    assert not floor.requires_grad
    flat = np.sort(h.detach().numpy().ravel())
    lower_median = flat[(flat.size - 1) // 2]  # torch's median: the lower of the middle two
    assert float(floor) == pytest.approx(0.25 * float(lower_median), rel=1e-6)
    loss = tlr_loss(h, nb, flow, den_floor=floor)
    hand = ((nb - h.detach()).abs() / (nb + h.detach() + float(floor))).mean()
    assert float(loss.detach()) == pytest.approx(float(hand), rel=1e-6)
    (grad,) = torch.autograd.grad(loss, h)
    expect = -torch.sign(nb - h.detach()) / (nb + h.detach() + float(floor)) / h.numel()
    torch.testing.assert_close(grad, expect)
    # the floor weighs the dark pixels down: their share of the gradient falls
    dark = h.detach().mean(-1) < float(np.median(h.detach().numpy()))
    (g0,) = torch.autograd.grad(tlr_loss(h, nb, flow), h)
    share = lambda gr: float(gr.abs().sum(-1)[dark].sum() / gr.abs().sum())  # noqa: E731
    assert share(grad) < share(g0)
    # fraction 0: the same bits as the loss without the option
    assert torch.equal(
        tlr_loss(h, nb, flow, den_floor=tlr_den_floor(h, 0.0)), tlr_loss(h, nb, flow)
    )


def test_tlr_valid_mask_hand_case():
    depth_nb = torch.full((1, 4), 2.0)
    ref = torch.tensor([[2.0, 2.1, 2.3, 1.0]])
    flow = torch.zeros(1, 4, 2)
    occ = tlr_valid_mask(flow, depth_nb, ref)
    assert occ.tolist() == [[True, True, False, True]]
    sym = tlr_valid_mask(flow, depth_nb, ref, mode="symmetric")
    assert sym.tolist() == [[True, True, False, False]]
    flow[0, 0, 0] = -1.0  # leaves the image
    assert not tlr_valid_mask(flow, depth_nb, ref)[0, 0]


def test_tlr_neighbours_average_and_occlusion_mask():
    h = torch.ones(1, 4, 3)
    zero = torch.zeros(1, 4, 2)
    nb_prev = {"hdr": 3.0 * h, "flow": zero}  # ratio 3 -> 0.5 everywhere
    nb_next = {"hdr": h.clone(), "flow": zero}  # identical -> 0
    assert tlr_loss_neighbours(h, [nb_prev, nb_next]).item() == pytest.approx(0.25, abs=1e-6)
    # occluded pixels of the previous frame (point behind the neighbour's surface by > 10 %) are
    # dropped
    hdr_prev = torch.ones(1, 4, 3)
    hdr_prev[0, 2] = 5.0  # differs only where the point is occluded
    nb = {
        "hdr": hdr_prev,
        "flow": zero,
        "depth": torch.full((1, 4), 2.0),
        "depth_ref": torch.tensor([[2.0, 2.0, 3.0, 2.0]]),
    }
    assert tlr_loss_neighbours(h, [nb]).item() == pytest.approx(0.0, abs=1e-6)
    nb.pop("depth")
    assert tlr_loss_neighbours(h, [nb]).item() == pytest.approx((4.0 / 6.0) / 4, abs=1e-6)


# --------------------------------------------------------------------------------------------------
# Photometric reprojection (textured plane seen by two cameras, built analytically)
# --------------------------------------------------------------------------------------------------
H_IMG, W_IMG = 36, 48
K_NP = np.array([[40.0, 0, 24.0], [0, 40.0, 18.0], [0, 0, 1]])
PLANE_Z = 4.0


def _texture(P):
    X, Y = P[..., 0], P[..., 1]
    return np.stack(
        [
            1.5 + np.sin(1.3 * X + 0.4) * np.cos(0.9 * Y),
            2.0 + 0.8 * np.cos(0.7 * X - 1.1 * Y),
            1.2 + 0.6 * np.sin(0.5 * X + 1.4 * Y + 0.3),
        ],
        -1,
    )


def _pose(angle_y, t):
    c, s = math.cos(angle_y), math.sin(angle_y)
    M = np.eye(4)
    M[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    M[:3, 3] = t
    return M


def _render_plane(c2w):
    """HDR image and z-depth of the plane Z_w = PLANE_Z seen by a pinhole camera (c2w, K_NP)."""
    jj, ii = np.meshgrid(np.arange(W_IMG) + 0.5, np.arange(H_IMG) + 0.5)
    d_cam = np.stack(
        [(jj - K_NP[0, 2]) / K_NP[0, 0], (ii - K_NP[1, 2]) / K_NP[1, 1], np.ones_like(jj)], -1
    )
    d_w = d_cam @ c2w[:3, :3].T
    o = c2w[:3, 3]
    s = (PLANE_Z - o[2]) / d_w[..., 2]  # camera-space z of d_cam is 1, so s is the z-depth
    P = o + s[..., None] * d_w
    return _texture(P), s


C2W_T = _pose(0.0, [0.0, 0.0, 0.0])
C2W_TP = _pose(math.radians(3.0), [0.25, 0.08, 0.1])


def _t(x):
    return torch.tensor(x, dtype=torch.float64)


def test_reprojection_coords_match_paper_w2c_formula():
    depth = _t(_render_plane(C2W_T)[1])
    uv, ok = reprojection_coords(depth, _t(K_NP), _t(C2W_T), _t(C2W_TP))
    # the paper's form with world-to-camera [R|T]: x' = R_t' R_t^-1 (x - T_t) + T_t'
    w2c_t, w2c_tp = np.linalg.inv(C2W_T), np.linalg.inv(C2W_TP)
    jj, ii = np.meshgrid(np.arange(W_IMG) + 0.5, np.arange(H_IMG) + 0.5)
    d = depth.numpy()
    x = np.stack([(jj - 24.0) / 40.0 * d, (ii - 18.0) / 40.0 * d, d], -1)
    R_t, T_t, R_tp, T_tp = w2c_t[:3, :3], w2c_t[:3, 3], w2c_tp[:3, :3], w2c_tp[:3, 3]
    xp = (x - T_t) @ np.linalg.inv(R_t).T @ R_tp.T + T_tp
    u = 40.0 * xp[..., 0] / xp[..., 2] + 24.0
    v = 40.0 * xp[..., 1] / xp[..., 2] + 18.0
    np.testing.assert_allclose(uv[..., 0].numpy(), u, atol=1e-9)
    np.testing.assert_allclose(uv[..., 1].numpy(), v, atol=1e-9)
    assert ok.all()


def test_hdr_reprojection_exact_small_perturbed_larger_and_gradient():
    hdr_t, depth_t = _render_plane(C2W_T)
    hdr_tp, _ = _render_plane(C2W_TP)
    K = _t(K_NP)
    exact = float(
        hdr_reprojection_loss(_t(hdr_t), _t(hdr_tp), _t(depth_t), K, _t(C2W_T), _t(C2W_TP))
    )
    wrong = C2W_TP.copy()
    wrong[:3, 3] += [0.08, -0.05, 0.0]
    perturbed = float(
        hdr_reprojection_loss(_t(hdr_t), _t(hdr_tp), _t(depth_t), K, _t(C2W_T), _t(wrong))
    )
    assert exact < 2e-3
    assert perturbed > 10 * exact

    # gradient wrt the camera translation is finite and a small step along it reduces the loss
    trans = _t(wrong[:3, 3]).requires_grad_(True)
    depth = _t(depth_t).requires_grad_(True)
    hdr_ref = _t(hdr_tp).requires_grad_(True)

    def loss_of(tr, dep, ref):
        top = torch.cat([_t(wrong[:3, :3]), tr[:, None]], 1)
        c2w = torch.cat([top, _t([[0, 0, 0, 1.0]])], 0)
        return hdr_reprojection_loss(_t(hdr_t), ref, dep, K, _t(C2W_T), c2w)

    loss = loss_of(trans, depth, hdr_ref)
    loss.backward()
    assert torch.isfinite(trans.grad).all() and trans.grad.norm() > 0
    assert torch.isfinite(depth.grad).all() and depth.grad.abs().sum() > 0
    assert hdr_ref.grad is None  # the stage-1 reference frame is detached
    with torch.no_grad():
        stepped = float(loss_of(trans - 0.02 * trans.grad / trans.grad.norm(), depth, hdr_ref))
    assert stepped < loss.item()


def test_hdr_reprojection_excludes_dynamic_pixels():
    hdr_t, depth_t = _render_plane(C2W_T)
    hdr_tp, _ = _render_plane(C2W_TP)
    args = (_t(depth_t), _t(K_NP), _t(C2W_T), _t(C2W_TP))
    corrupted = hdr_t.copy()
    corrupted[5:15, 10:30] *= 3.0
    dyn = torch.zeros(H_IMG, W_IMG, dtype=torch.bool)
    dyn[5:15, 10:30] = True
    clean = float(hdr_reprojection_loss(_t(hdr_t), _t(hdr_tp), *args, dynamic_mask=dyn))
    masked = float(hdr_reprojection_loss(_t(corrupted), _t(hdr_tp), *args, dynamic_mask=dyn))
    unmasked = float(hdr_reprojection_loss(_t(corrupted), _t(hdr_tp), *args))
    assert masked == pytest.approx(clean, rel=1e-9)
    assert unmasked > 10 * masked


def test_ldr_reprojection_same_exposure():
    hdr_t, depth_t = _render_plane(C2W_T)
    hdr_tp, _ = _render_plane(C2W_TP)
    ldr_t, ldr_tp = (hdr_t / (hdr_t + 1)) ** (1 / 2.2), (hdr_tp / (hdr_tp + 1)) ** (1 / 2.2)
    args = (_t(depth_t), _t(K_NP), _t(C2W_T))
    exact = float(ldr_reprojection_loss(_t(ldr_t), _t(ldr_tp), *args, _t(C2W_TP)))
    wrong = C2W_TP.copy()
    wrong[:3, 3] += [0.08, -0.05, 0.0]
    perturbed = float(ldr_reprojection_loss(_t(ldr_t), _t(ldr_tp), *args, _t(wrong)))
    assert exact < 1e-3 and perturbed > 10 * exact


def test_relative_smoothness_frees_a_group_that_moves_as_one():
    """Velocity and acceleration of positions relative to the neighbours' mean
    (loss.smooth_relative): zero for six points that share a fast curved path, and, with one point
    jittering, that point's jitter less its neighbours' mean, recomputed here with loops."""
    T, N = 7, 6
    t = torch.arange(T, dtype=torch.float64)
    path = torch.stack([3.0 * torch.sin(t), 0.5 * t**2, -2.0 * t], -1)  # [T, 3]: fast, curved
    offsets = torch.randn(N, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    pos = path[:, None] + offsets[None]  # [T, N, 3]
    nbr = torch.tensor([[j for j in range(N) if j != i][:5] for i in range(N)])  # [N, 5]
    rel = relative_to_neighbours(pos, pos[:, nbr])
    own = smoothness_terms(pos)
    assert own["pos_vel"] > 1.0 and own["pos_acc"] > 0.5  # the paper's terms charge the path
    free = smoothness_terms(rel)
    assert float(free["pos_vel"]) < 1e-12 and float(free["pos_acc"]) < 1e-12
    jit = torch.zeros(T, N, 3, dtype=torch.float64)
    jit[:, 2, 0] = torch.tensor([0.0, 0.3, -0.1, 0.2, 0.0, -0.4, 0.1], dtype=torch.float64)
    moved = pos + jit
    got = smoothness_terms(relative_to_neighbours(moved, moved[:, nbr]))
    vel, acc = 0.0, 0.0
    for i in range(N):
        r = [moved[k, i] - sum(moved[k, j] for j in nbr[i].tolist()) / 5 for k in range(T)]
        vel += sum(float((r[k + 1] - r[k]).norm()) for k in range(T - 1))
        acc += sum(float((r[k] - 2 * r[k + 1] + r[k + 2]).norm()) for k in range(T - 2))
    assert math.isclose(float(got["pos_vel"]), vel / N, rel_tol=1e-9)
    assert math.isclose(float(got["pos_acc"]), acc / N, rel_tol=1e-9)
