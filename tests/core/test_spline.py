"""Cubic Hermite spline (paper appendix) against hand computations, finite differences and exact
fits."""

import numpy as np
import pytest
import torch

from m4dgs.core import spline


def _hand_hermite(p, tk, t):
    """Independent numpy evaluation of the appendix formula for one scalar trajectory."""
    p = np.asarray(p, dtype=np.float64)
    tk = np.asarray(tk, dtype=np.float64)
    k = len(p)
    m = np.zeros(k)
    for i in range(k):
        if i == 0:
            m[i] = (p[1] - p[0]) / (tk[1] - tk[0])
        elif i == k - 1:
            m[i] = (p[-1] - p[-2]) / (tk[-1] - tk[-2])
        else:
            m[i] = 0.5 * (
                (p[i + 1] - p[i]) / (tk[i + 1] - tk[i]) + (p[i] - p[i - 1]) / (tk[i] - tk[i - 1])
            )
    i = min(int(np.searchsorted(tk, t, side="right") - 1), k - 2)
    h = tk[i + 1] - tk[i]
    s = (t - tk[i]) / h
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    return h00 * p[i] + h10 * h * m[i] + h01 * p[i + 1] + h11 * h * m[i + 1]


def test_make_knots_grid_and_last_frame():
    assert spline.make_knots(13, 4).tolist() == [0, 4, 8, 12]
    assert spline.make_knots(15, 4).tolist() == [0, 4, 8, 12, 14]
    assert spline.make_knots(5, 1).tolist() == [0, 1, 2, 3, 4]
    assert spline.make_knots(3, 16).tolist() == [0, 2]
    assert spline.make_knots(1, 4).tolist() == [0]


def test_uniform_knots_spread_a_number_of_knots_over_the_frames():
    assert spline.uniform_knots(9, 3).tolist() == [0.0, 4.0, 8.0]
    assert spline.uniform_knots(8, 3).tolist() == [0.0, 3.5, 7.0]
    assert spline.uniform_knots(5, 1).tolist() == [0.0]
    assert spline.uniform_knots(1, 2).tolist() == [0.0, 1.0]  # distinct knots for one frame
    for bad in ((0, 3), (5, 0)):
        with pytest.raises(ValueError):
            spline.uniform_knots(*bad)


def test_four_point_example_matches_hand_formula():
    # worked example: p = (0, 1, 4, 2) at t = (0, 4, 8, 10) (non-uniform last knot)
    p = [0.0, 1.0, 4.0, 2.0]
    tk = [0.0, 4.0, 8.0, 10.0]
    # explicit value at t = 6 (segment 1, s = 0.5): m1 = (0.25 + 0.75)/2 = 0.5, m2 = (0.75 + -1)/2 =
    # -0.125 mu = 0.5*1 + 0.125*4*0.5 + 0.5*4 + (-0.125)*4*(-0.125) = 0.5 + 0.25 + 2 + 0.0625
    ctrl = torch.tensor(p, dtype=torch.float64).reshape(1, 4, 1)
    knots = torch.tensor(tk, dtype=torch.float64)
    assert spline.evaluate(ctrl, knots, 6.0).item() == pytest.approx(2.8125, abs=1e-12)
    ts = torch.linspace(0, 10, 41, dtype=torch.float64)
    got = spline.evaluate(ctrl, knots, ts)[0, :, 0].numpy()
    want = np.array([_hand_hermite(p, tk, float(t)) for t in ts])
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_passes_through_control_points_and_shapes():
    g = torch.Generator().manual_seed(0)
    ctrl = torch.randn(5, 6, 3, generator=g, dtype=torch.float64)
    knots = spline.make_knots(19, 4, dtype=torch.float64)  # [0,4,8,12,16,18]
    out = spline.evaluate(ctrl, knots, knots)
    assert out.shape == (5, 6, 3)
    torch.testing.assert_close(out, ctrl, atol=1e-12, rtol=0)
    assert spline.evaluate(ctrl, knots, 3.0).shape == (5, 3)
    # clamped outside the range
    torch.testing.assert_close(spline.evaluate(ctrl, knots, -2.0), ctrl[:, 0])
    torch.testing.assert_close(spline.evaluate(ctrl, knots, 25.0), ctrl[:, -1])


def test_c1_continuity_at_joins():
    g = torch.Generator().manual_seed(1)
    ctrl = torch.randn(3, 5, 2, generator=g, dtype=torch.float64)
    knots = torch.tensor([0.0, 4.0, 8.0, 12.0, 14.0], dtype=torch.float64)
    eps = 1e-6
    for tj in knots[1:-1].tolist():
        at = spline.evaluate(ctrl, knots, tj)
        left = (at - spline.evaluate(ctrl, knots, tj - eps)) / eps
        right = (spline.evaluate(ctrl, knots, tj + eps) - at) / eps
        torch.testing.assert_close(left, right, atol=1e-5, rtol=0)
        # and the value is continuous
        torch.testing.assert_close(spline.evaluate(ctrl, knots, tj - 1e-9), at, atol=1e-7, rtol=0)


def test_basis_matrix_matches_evaluate_and_gradients():
    knots = spline.make_knots(11, 4, dtype=torch.float64)
    ts = torch.linspace(0, 10, 23, dtype=torch.float64)
    b = spline.basis_matrix(knots, ts)
    torch.testing.assert_close(b.sum(1), torch.ones(23, dtype=torch.float64))
    g = torch.Generator().manual_seed(2)
    ctrl = torch.randn(4, knots.numel(), 3, generator=g, dtype=torch.float64, requires_grad=True)
    out = spline.evaluate(ctrl, knots, ts)
    torch.testing.assert_close(out, torch.einsum("tk,nkd->ntd", b, ctrl), atol=1e-12, rtol=0)
    assert torch.autograd.gradcheck(lambda c: spline.evaluate(c, knots, ts), (ctrl,))


@pytest.mark.parametrize("num_frames", [1, 2, 7, 50])
def test_fast_evaluate_matches_reference_values_and_gradients(num_frames):
    """`evaluate` (one contraction with the basis matrix) against the term-by-term Hermite formula
    of `evaluate_reference`, values and gradients, for scalar and vector times inside, on and
    outside the knots."""
    knots = spline.make_knots(num_frames, 4)
    g = torch.Generator().manual_seed(num_frames)
    ctrl = torch.randn(37, knots.numel(), 3, generator=g, dtype=torch.float64)
    times = [0.0, 0.5 * (num_frames - 1), float(num_frames - 1), -3.0, num_frames + 2.0]
    # two nearby times: a basis with a few nonzero columns (the narrowed product)
    times.append(torch.tensor([0.4, 0.45], dtype=torch.float64) * (num_frames - 1))
    times.append(torch.linspace(-1.0, num_frames, 11, dtype=torch.float64))
    w = torch.randn(37, 3, generator=g, dtype=torch.float64)
    for t in times:
        outs, grads = [], []
        for fn in (spline.evaluate, spline.evaluate_reference):
            c = ctrl.clone().requires_grad_(True)
            out = fn(c, knots, t)
            (out * (w if out.dim() == 2 else w[:, None])).sum().backward()
            outs.append(out.detach())
            grads.append(c.grad)
        torch.testing.assert_close(outs[0], outs[1], rtol=0, atol=1e-12)
        torch.testing.assert_close(grads[0], grads[1], rtol=0, atol=1e-12)
    # no Gaussians (an empty dynamic set): empty outputs of the right shape
    assert spline.evaluate(ctrl[:0], knots, times[-1]).shape == (0, 11, 3)
    assert spline.evaluate(ctrl[:0], knots, 1.0).shape == (0, 3)


def test_fit_recovers_known_spline_exactly():
    g = torch.Generator().manual_seed(3)
    t_count = 17
    knots = spline.make_knots(t_count, 4, dtype=torch.float64)
    times = torch.arange(t_count, dtype=torch.float64)
    ctrl = torch.randn(50, knots.numel(), 3, generator=g, dtype=torch.float64)
    traj = spline.evaluate(ctrl, knots, times)
    fit = spline.fit_control_points(traj, None, times, knots, smooth=0.0, damping=0.0)
    torch.testing.assert_close(fit, ctrl, atol=1e-8, rtol=0)
    # with a random visibility mask that keeps >= 2 frames per segment, still exact (NaN at invalid
    # frames ignored)
    valid = torch.rand(50, t_count, generator=g) > 0.3
    for s in range(knots.numel() - 1):
        lo, hi = int(knots[s]), int(knots[s + 1])
        valid[:, lo] = True
        valid[:, hi] = True
    traj_nan = traj.clone()
    traj_nan[~valid] = float("nan")
    fit = spline.fit_control_points(traj_nan, valid, times, knots, smooth=0.0, damping=0.0)
    torch.testing.assert_close(fit, ctrl, atol=1e-8, rtol=0)


def test_fit_fills_invisible_spans_linearly():
    # linear motion observed only on frames 0..5 and 14..16: the smoothness term is zero for lines,
    # so the fit is exact everywhere, including the hidden span and the non-uniform last knot.
    t_count = 17
    knots = spline.make_knots(t_count, 4)
    times = torch.arange(t_count, dtype=torch.float32)
    start = torch.tensor([[0.1, -0.3, 2.0], [0.5, 0.5, 1.0]])
    vel = torch.tensor([[0.01, 0.02, -0.03], [-0.02, 0.0, 0.05]])
    traj = start[:, None] + vel[:, None] * times[None, :, None]
    valid = torch.zeros(2, t_count, dtype=torch.bool)
    valid[:, :6] = True
    valid[:, 14:] = True
    fit = spline.fit_control_points(traj, valid, times, knots, smooth=1e-2, damping=0.0)
    dense = spline.evaluate(fit, knots, times)
    torch.testing.assert_close(dense, traj, atol=1e-4, rtol=0)
    # few visible frames: one visible frame -> constant at that value; no visible frame -> zeros, no
    # NaN
    valid1 = torch.zeros(2, t_count, dtype=torch.bool)
    valid1[0, 7] = True
    fit1 = spline.fit_control_points(traj, valid1, times, knots)
    assert torch.isfinite(fit1).all()
    torch.testing.assert_close(
        spline.evaluate(fit1[:1], knots, times)[0], traj[0, 7].expand(t_count, 3), atol=1e-4, rtol=0
    )
    assert (fit1[1] == 0).all()


def test_fit_single_knot_and_resample():
    traj = torch.tensor([[[1.0, 2.0, 3.0]]])
    knots = spline.make_knots(1, 4)
    fit = spline.fit_control_points(traj, None, torch.zeros(1), knots)
    torch.testing.assert_close(fit, traj)
    # resample: "sample" takes trajectory values at the knots; "lstsq" reproduces a smooth
    # trajectory closely
    t_count = 21
    times = torch.arange(t_count, dtype=torch.float64)
    knots = spline.make_knots(t_count, 4, dtype=torch.float64)
    traj = torch.stack([torch.sin(times / 5), torch.cos(times / 7), times / 20], -1)[None]
    samp = spline.resample_control_points(traj, times, knots, method="sample")
    torch.testing.assert_close(samp[0], traj[0, knots.long()])
    ls = spline.resample_control_points(traj, times, knots)
    # least squares minimises the squared error over all samples: lower RMS than interpolating the
    # knot samples
    err_ls = (spline.evaluate(ls, knots, times) - traj).pow(2).mean().sqrt()
    err_s = (spline.evaluate(samp, knots, times) - traj).pow(2).mean().sqrt()
    assert err_ls < err_s and err_ls < 1e-2
    with pytest.raises(ValueError):
        spline.resample_control_points(traj, times, knots, method="nope")


@pytest.mark.parametrize("d", [3, 4])
def test_basis_memo_gives_the_same_bits_and_gradients(d):
    """Every way of giving times on the host, first call (rows and plan built) and later calls
    (found), times that share rows with earlier sets: values and ctrl gradients equal bit for bit
    to the evaluation without a memo, which the reference tests above check against the formula."""
    g = torch.Generator().manual_seed(3)
    knots = spline.make_knots(23, 4)
    ctrl = torch.randn(50, knots.numel(), d, generator=g, requires_grad=True)
    memo = spline.BasisMemo()
    cases = [7.0, 7, [7.0, 8.0, 6.0], (8.0, 6.0, 21.5), torch.tensor(5.0), torch.arange(3, 9.0)]
    for t in cases + cases:
        a = spline.evaluate(ctrl, knots, t)
        b = spline.evaluate(ctrl, knots, t, memo)
        assert a.shape == b.shape and torch.equal(a, b)
        w = torch.randn(a.shape, generator=g)
        (ga,) = torch.autograd.grad((a * w).sum(), ctrl)
        (gb,) = torch.autograd.grad((b * w).sum(), ctrl)
        assert torch.equal(ga, gb)
    # a list of times is a set of times (it was read as one scalar time before the memo)
    assert spline.evaluate(ctrl, knots, [1.0, 2.0]).shape == (50, 2, d)
    ref = spline.evaluate_reference(ctrl, knots, torch.tensor([1.0, 2.0]))
    assert torch.allclose(spline.evaluate(ctrl, knots, [1.0, 2.0], memo), ref, atol=1e-6)


def test_basis_memo_costs_one_product_once_built(load_bench):
    # bench/step_bench.py's counter (tensor operations, views apart), its own test in
    # tests/test_bench_step_bench.py
    OpCounter = load_bench("step_bench").OpCounter
    knots = spline.make_knots(30, 4)
    ctrl = torch.randn(40, knots.numel(), 3)
    memo = spline.BasisMemo()
    times = [10.0, 11.0, 9.0]
    with OpCounter() as without:
        spline.evaluate(ctrl, knots, times)
    spline.evaluate(ctrl, knots, times, memo)
    with OpCounter() as found:
        spline.evaluate(ctrl, knots, times, memo)
    with OpCounter() as known_rows:
        spline.evaluate(ctrl, knots, [11.0, 9.0], memo)
    # without: the basis term by term and the product matrix; found: the narrowed coefficients'
    # copy and the product; known rows: the stacking and the product matrix, no basis
    without, found, known_rows = (sum(c.ops.values()) for c in (without, found, known_rows))
    assert without > 30
    assert found <= 3
    assert found < known_rows < without / 2


def test_basis_memo_misses_on_other_knots_and_device_times():
    ctrl = torch.randn(10, 6, 3)
    memo = spline.BasisMemo(max_entries=8)
    knots = spline.make_knots(21, 4)
    a = spline.evaluate(ctrl, knots, 9.0, memo)
    knots.mul_(0.5)  # changed in place: the version moves, the memo must not answer
    b = spline.evaluate(ctrl, knots, 9.0, memo)
    assert torch.equal(b, spline.evaluate(ctrl, knots, 9.0)) and not torch.equal(a, b)
    other = spline.make_knots(21, 4) * 0.25
    assert torch.equal(spline.evaluate(ctrl, other, 9.0, memo), spline.evaluate(ctrl, other, 9.0))
    # times on a device other than the CPU give no key (reading them would wait for the device)
    assert spline.BasisMemo.host_times(torch.zeros(3, device="meta")) is None
    # the memo starts over when full
    for v in range(20):
        spline.evaluate(ctrl, knots, float(v % 10), memo)
        assert len(memo.plans) + len(memo.rows) <= 8


def test_a_copied_model_starts_with_an_empty_memo():
    import copy
    import pickle

    from m4dgs.model.gaussians import VideoGaussians

    knots = spline.make_knots(9, 4)
    n, k = 5, knots.numel()
    g = VideoGaussians(
        torch.randn(n, k, 3),
        torch.randn(n, 2, 4),
        torch.zeros(n, 3),
        torch.zeros(n),
        torch.zeros(n, 3),
        knots,
        9,
    )
    want = g.positions([1.0, 2.0])
    assert len(g.spline_memo.plans) == 1
    for c in (copy.deepcopy(g), pickle.loads(pickle.dumps(g))):
        assert c.spline_memo is not g.spline_memo and not c.spline_memo.plans
        assert torch.equal(c.positions([1.0, 2.0]), want)


def _dense_weighted_reference(traj, weights, times, knots, smooth, damping, reg_scale):
    """The weighted fit as one stacked least-squares system per Gaussian, solved by numpy."""
    import numpy as np

    B = spline.basis_matrix(knots, times).numpy()
    k = knots.numel()
    d = traj.shape[-1]
    spacing = float(knots[-1] - knots[0]) / (k - 1)
    d2 = spline.second_difference_matrix(knots).numpy() * spacing**2
    d1 = spline.first_difference_matrix(knots).numpy() * spacing
    out = []
    for n in range(traj.shape[0]):
        rows, rhs = [], []
        for t in range(len(times)):
            w = weights[n, t].numpy()
            vals, vecs = np.linalg.eigh(w)
            half = (vecs * np.sqrt(np.clip(vals, 0, None))) @ vecs.T  # W^(1/2)
            rows.append(half @ np.kron(B[t][None], np.eye(d)))
            rhs.append(half @ traj[n, t].numpy())
        r = float(reg_scale[n])
        rows += [
            np.sqrt(smooth * r) * np.kron(d2, np.eye(d)),
            np.sqrt(damping * r) * np.kron(d1, np.eye(d)),
        ]
        rhs += [np.zeros(d2.shape[0] * d), np.zeros(d1.shape[0] * d)]
        sol, *_ = np.linalg.lstsq(np.concatenate(rows), np.concatenate(rhs), rcond=None)
        out.append(sol.reshape(k, d))
    return torch.from_numpy(np.stack(out))


def test_weighted_fit_matches_a_dense_least_squares_reference():
    g = torch.Generator().manual_seed(5)
    t_count, n = 13, 4
    knots = spline.make_knots(t_count, 4, dtype=torch.float64)
    times = torch.arange(t_count, dtype=torch.float64)
    traj = torch.randn(n, t_count, 3, generator=g, dtype=torch.float64)
    a = torch.randn(n, t_count, 3, 3, generator=g, dtype=torch.float64)
    weights = a @ a.transpose(-1, -2)  # symmetric positive semi-definite
    scale = torch.rand(n, generator=g, dtype=torch.float64) + 0.5
    fit = spline.fit_control_points_weighted(
        traj, weights, times, knots, smooth=0.3, damping=0.01, reg_scale=scale
    )
    ref = _dense_weighted_reference(traj, weights, times, knots, 0.3, 0.01, scale)
    torch.testing.assert_close(fit, ref, atol=1e-9, rtol=1e-9)


def test_weighted_fit_with_identity_weights_is_the_masked_fit():
    g = torch.Generator().manual_seed(6)
    t_count = 21
    knots = spline.make_knots(t_count, 4, dtype=torch.float64)
    times = torch.arange(t_count, dtype=torch.float64)
    traj = torch.randn(30, t_count, 3, generator=g, dtype=torch.float64)
    valid = torch.rand(30, t_count, generator=g) > 0.4
    valid[-1] = False  # a Gaussian never seen: zeros in both
    weights = valid[..., None, None].double() * torch.eye(3, dtype=torch.float64)
    fit_w = spline.fit_control_points_weighted(traj, weights, times, knots, smooth=1e-2)
    fit_m = spline.fit_control_points(traj, valid, times, knots, smooth=1e-2)
    torch.testing.assert_close(fit_w, fit_m, atol=1e-9, rtol=0)
    assert (fit_w[-1] == 0).all()


def test_weighted_fit_recovers_a_spline_from_errors_across_rays_only():
    # each sample constrains only the two directions across a ray that turns with time (rank-2
    # weights, as V2W's pixel weighting with no depth term): a spline path is still recovered
    g = torch.Generator().manual_seed(7)
    t_count = 17
    knots = spline.make_knots(t_count, 4, dtype=torch.float64)
    times = torch.arange(t_count, dtype=torch.float64)
    ctrl = torch.randn(5, knots.numel(), 3, generator=g, dtype=torch.float64)
    traj = spline.evaluate(ctrl, knots, times)
    ang = times / 3.0
    ray = torch.stack([torch.sin(ang), 0.3 * torch.cos(ang), torch.ones_like(ang)], -1)
    ray = ray / ray.norm(dim=-1, keepdim=True)
    across = torch.eye(3, dtype=torch.float64) - ray[:, :, None] * ray[:, None, :]  # [T, 3, 3]
    weights = across[None].expand(5, -1, -1, -1)
    fit = spline.fit_control_points_weighted(traj, weights, times, knots, smooth=0.0, damping=0.0)
    torch.testing.assert_close(fit, ctrl, atol=1e-7, rtol=0)
