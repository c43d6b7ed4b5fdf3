"""Quaternion polynomial, relative angles and Markley averaging against hand computations and
scipy."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from m4dgs.core import rotation


def _wxyz_to_xyzw(q):
    q = np.asarray(q)
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def test_init_modes_are_identity():
    for mode in ("paper", "constant"):
        c = rotation.init_rotation_coeffs(3, mode=mode)
        assert c.shape == (3, 4, 4)
        q = rotation.poly_evaluate(c, torch.linspace(0, 1, 5), normalize=True)
        torch.testing.assert_close(q, torch.tensor([1.0, 0, 0, 0]).expand(3, 5, 4))
    paper = rotation.init_rotation_coeffs(1, mode="paper")
    assert (paper[0, :, 0] == 1).all() and (paper[0, :, 1:] == 0).all()
    const = rotation.init_rotation_coeffs(1, mode="constant")
    assert const[0, 0, 0] == 1 and const[0, 1:].abs().sum() == 0
    with pytest.raises(ValueError):
        rotation.init_rotation_coeffs(1, mode="bogus")


def test_poly_evaluate_hand_computation():
    a = torch.tensor(
        [[[1.0, 0.0, 0.0, 0.0], [0.5, 1.0, 0.0, 0.0], [0.0, 0.0, 2.0, 0.0], [0.0, 0.0, 0.0, -1.0]]]
    )
    # r(0.5) = a0 + 0.5 a1 + 0.25 a2 + 0.125 a3 = [1.25, 0.5, 0.5, -0.125]
    r = rotation.poly_evaluate(a, 0.5)
    torch.testing.assert_close(r, torch.tensor([[1.25, 0.5, 0.5, -0.125]]))
    rn = rotation.poly_evaluate(a, torch.tensor([0.0, 0.5]), normalize=True)
    assert rn.shape == (1, 2, 4)
    want = np.array([1.25, 0.5, 0.5, -0.125]) / np.linalg.norm([1.25, 0.5, 0.5, -0.125])
    np.testing.assert_allclose(rn[0, 1].numpy(), want, rtol=1e-6)


def test_poly_evaluate_matches_an_einsum_and_its_gradient():
    g = torch.Generator().manual_seed(3)
    a = torch.randn(7, 4, 4, generator=g, dtype=torch.float64, requires_grad=True)
    t = torch.linspace(-0.2, 1.0, 5, dtype=torch.float64)
    v = t[:, None] ** torch.arange(4, dtype=torch.float64)  # [T, J] powers t^j
    torch.testing.assert_close(rotation.poly_evaluate(a, t), torch.einsum("tj,njc->ntc", v, a))
    assert torch.autograd.gradcheck(lambda c: rotation.poly_evaluate(c, t, normalize=True), (a,))


def test_least_squares_refit_recovers_coefficients():
    g = torch.Generator().manual_seed(0)
    n, t_count = 20, 15
    coeffs = torch.randn(n, 4, 4, generator=g, dtype=torch.float64) * 0.3
    coeffs[:, 0, 0] += 2.0  # keep |r(t)| away from zero (w > 0 along the whole trajectory)
    t = torch.linspace(0, 1, t_count, dtype=torch.float64)
    # targets: the Vandermonde product computed by hand in numpy, with random per-frame sign flips
    tn = t.numpy()
    raw = np.einsum("tj,njc->ntc", np.stack([tn**0, tn, tn**2, tn**3], 1), coeffs.numpy())
    flips = np.where(np.random.default_rng(0).random((n, t_count, 1)) < 0.3, -1.0, 1.0)
    target = torch.tensor(raw * flips)
    fit = rotation.fit_rotation_poly(
        target, t, ridge=0.0, normalize_targets=False, reference=coeffs[:, 0]
    )
    torch.testing.assert_close(fit, coeffs, atol=1e-9, rtol=0)
    # on unit targets the fit reproduces the rotations closely (a cubic cannot be exactly unit-norm)
    fit_u = rotation.fit_rotation_poly(target, t)
    ang = rotation.relative_rotation_angle(rotation.poly_evaluate(fit_u, t), torch.tensor(raw))
    assert ang.max() < 2e-2
    # degree-0 (unit-valued) polynomial: recovered exactly after normalisation too
    q0 = rotation.quat_normalize(torch.randn(n, 4, generator=g, dtype=torch.float64))
    const = torch.zeros(n, 4, 4, dtype=torch.float64)
    const[:, 0] = q0
    fit0 = rotation.fit_rotation_poly(q0[:, None].expand(n, t_count, 4), t, ridge=0.0, reference=q0)
    torch.testing.assert_close(fit0, const, atol=1e-9, rtol=0)
    # no valid frame: identity constant
    none = rotation.fit_rotation_poly(target[:2], t, torch.zeros(2, t_count, dtype=torch.bool))
    torch.testing.assert_close(
        none, rotation.init_rotation_coeffs(2, mode="constant", dtype=torch.float64)
    )


def test_refit_recovers_cubic_on_unit_targets_with_mask():
    # targets exactly on a cubic (not normalised afterwards): fit on valid frames only, with ridge 0
    g = torch.Generator().manual_seed(1)
    n, t_count = 10, 12
    coeffs = torch.randn(n, 4, 4, generator=g, dtype=torch.float64) * 0.05
    coeffs[:, 0] = rotation.quat_normalize(torch.randn(n, 4, generator=g, dtype=torch.float64))
    t = torch.linspace(0, 1, t_count, dtype=torch.float64)
    target = rotation.poly_evaluate(coeffs, t)
    scale = target.norm(dim=-1, keepdim=True)
    valid = torch.rand(n, t_count, generator=g) > 0.4
    valid[:, :5] = True
    fit = rotation.fit_rotation_poly(target / scale, t, valid, ridge=0.0)
    # the fit of the normalised targets is close; refine with 1 - |<q, q*>| reduces the loss further
    before = rotation.quat_alignment_loss(rotation.poly_evaluate(fit, t), target, valid)
    ref = rotation.refine_rotation_poly(fit, target, t, valid, steps=100, lr=1e-3)
    after = rotation.quat_alignment_loss(rotation.poly_evaluate(ref, t), target, valid)
    assert after <= before + 1e-12
    assert before < 1e-4
    # unnormalised fit on the valid frames only recovers the generating coefficients exactly
    exact = rotation.fit_rotation_poly(
        target, t, valid, ridge=0.0, normalize_targets=False, reference=coeffs[:, 0]
    )
    torch.testing.assert_close(exact, coeffs, atol=1e-9, rtol=0)


def test_relative_rotation_angle_vs_scipy_and_gradient():
    rng = np.random.default_rng(2)
    ra = Rotation.random(64, random_state=rng)
    rb = Rotation.random(64, random_state=rng)
    qa = torch.tensor(np.concatenate([ra.as_quat()[:, 3:], ra.as_quat()[:, :3]], 1))
    qb = torch.tensor(np.concatenate([rb.as_quat()[:, 3:], rb.as_quat()[:, :3]], 1))
    want = (ra * rb.inv()).magnitude()
    got = rotation.relative_rotation_angle(qa * 3.0, -qb)  # scale and sign invariant
    np.testing.assert_allclose(got.numpy(), want, atol=1e-9)
    # log map magnitude and direction vs scipy rotvec
    rel = rotation.quat_multiply(qa, rotation.quat_conjugate(qb))
    np.testing.assert_allclose(
        rotation.quat_log(rel).numpy(), (ra * rb.inv()).as_rotvec(), atol=1e-9
    )
    # stable near zero: finite gradient at identical inputs, angle ~ 0
    q = qa[:4].clone().requires_grad_(True)
    ang = rotation.relative_rotation_angle(q, qa[:4].clone())
    ang.sum().backward()
    assert torch.isfinite(q.grad).all()
    assert ang.abs().max() < 1e-6
    # small angle accuracy (1e-4 rad) and gradient vs finite differences away from zero
    small = Rotation.from_rotvec(np.array([[1e-4, 0, 0]]))
    qs = torch.tensor(_wxyz_from_scipy(small))
    ident = torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64)
    assert rotation.relative_rotation_angle(qs, ident).item() == pytest.approx(1e-4, rel=1e-6)
    x = qa[:3].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda z: rotation.relative_rotation_angle(z, qb[:3]), (x,))
    y = (qa[:3] * 0.5).clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda z: rotation.quat_log(z), (y,))


def _wxyz_from_scipy(r):
    q = r.as_quat()
    return np.concatenate([q[..., 3:], q[..., :3]], axis=-1)


def test_markley_average_vs_scipy_mean():
    rng = np.random.default_rng(3)
    base = Rotation.random(random_state=rng)
    noise = Rotation.from_rotvec(rng.normal(scale=0.3, size=(30, 3)))
    rots = base * noise
    q = torch.tensor(_wxyz_from_scipy(rots))
    q = (
        q
        * torch.where(
            torch.rand(30, 1, generator=torch.Generator().manual_seed(0)) < 0.5, -1.0, 1.0
        ).double()
    )
    w = torch.tensor(rng.uniform(0.1, 2.0, size=30))
    got = rotation.quat_average_markley(q, w)
    want = rots.mean(weights=w.numpy())
    ang = (Rotation.from_quat(_wxyz_to_xyzw(got.numpy())) * want.inv()).magnitude()
    assert ang < 1e-9
    got_u = rotation.quat_average_markley(q)
    ang_u = (Rotation.from_quat(_wxyz_to_xyzw(got_u.numpy())) * rots.mean().inv()).magnitude()
    assert ang_u < 1e-9 and got_u[0] >= 0
    # batched
    qb = torch.stack([q, q.flip(0)])
    out = rotation.quat_average_markley(qb)
    assert out.shape == (2, 4)
    torch.testing.assert_close(out[0], out[1])


def test_align_quat_signs():
    q = torch.tensor(
        [[[1.0, 0, 0, 0], [-0.99, -0.1, 0, 0], [0.98, 0.2, 0, 0], [-0.97, -0.3, 0, 0]]]
    )
    out = rotation.align_quat_signs(q)
    assert (out[0, :, 0] > 0).all()
    valid = torch.tensor([[True, False, True, True]])
    q2 = q.clone()
    # garbage on an invalid frame must not break the chain
    q2[0, 1] = torch.tensor([0.0, 0.0, 0.0, 1.0])
    out2 = rotation.align_quat_signs(q2, valid)
    assert out2[0, 2, 0] > 0 and out2[0, 3, 0] > 0
