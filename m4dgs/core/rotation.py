"""Gaussian rotation trajectories: a cubic polynomial of an unnormalised quaternion (paper sec.
3.1).

    r(t) = sum_{j=0}^{3} a_j t^j,   a_j in R^4 (w, x, y, z),   t in [0, 1] (normalised time, t =
    frame / (T - 1)),

the rotation being r(t) / |r(t)|. Coefficients are stored as [N, J, 4] with J = degree + 1 (the
power index first).

Initialisation: the paper (appendix "Video Gaussian Representation") initialises *all* coefficients
with [1, 0, 0, 0], i.e. r(t) = (1 + t + t^2 + t^3) [1, 0, 0, 0]; the authors' code sets only the
constant term to the identity and the higher terms to zero. Both give the identity rotation at all
times; `init_rotation_coeffs(mode=...)` offers both ("paper" default, "constant" for the code's
choice).

Also here: quaternion algebra (wxyz), the rotation logarithm and relative angles for the
motion-smoothness losses (appendix "Motion Smoothness"), Markley quaternion averaging for static
world Gaussians (sec. 3.3.2), and least-squares / refinement fits of the polynomial to target
quaternions (video-to-world transform of dynamic Gaussians)."""

from __future__ import annotations

from typing import Optional, Union

import torch

from m4dgs.core.camera import quat_multiply, quat_normalize
from m4dgs.core.spline import apply_basis

Tensor = torch.Tensor

ROTATION_INIT_MODES = ("paper", "constant")


# --------------------------------------------------------------------------------------------------
# quaternion algebra (w, x, y, z); product and normalisation come from m4dgs.core.camera
# --------------------------------------------------------------------------------------------------
def quat_conjugate(q: Tensor) -> Tensor:
    """Conjugate [..., 4] (the inverse rotation for a unit quaternion)."""
    return q * torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=q.dtype, device=q.device)


def _safe_norm(v: Tensor, eps: float = 1e-20) -> Tensor:
    # sqrt with a floor: finite gradient (zero) at v == 0
    return (v * v).sum(-1).clamp_min(eps).sqrt()


def quat_log(q: Tensor) -> Tensor:
    """Rotation logarithm as an axis-angle vector theta * axis, [..., 4] -> [..., 3].

    q need not be unit-norm. Uses the shorter rotation (theta in [0, pi]); differentiable and stable
    near the identity (theta / sin(theta / 2) -> 2 via the atan2 form)."""
    q = quat_normalize(q)
    w = q[..., :1]
    v = q[..., 1:]
    sign = torch.where(w < 0, -torch.ones_like(w), torch.ones_like(w))
    w = w * sign
    v = v * sign
    vn = _safe_norm(v)[..., None]
    theta = 2.0 * torch.atan2(vn, w)
    # theta / |v| -> 2 / w as |v| -> 0; atan2(vn, w)/vn is smooth, evaluated safely
    scale = torch.where(
        vn > 1e-6,
        theta / vn,
        2.0 / w.clamp_min(1e-12) * (1.0 - vn * vn / (3.0 * w * w).clamp_min(1e-12)),
    )
    return v * scale


def relative_rotation_angle(q_a: Tensor, q_b: Tensor) -> Tensor:
    """Angle (radians, in [0, pi]) of R_a R_b^{-1}, i.e. || log(R_a R_b^{-1}) || as axis-angle
    magnitude.

    Args:
        q_a, q_b: [..., 4] wxyz quaternions (any norm; sign-invariant).
    Returns:
        [...] angles; differentiable with finite (zero) gradient at q_a == q_b.
    """
    qa = quat_normalize(q_a)
    qb = quat_normalize(q_b)
    rel = quat_multiply(qa, quat_conjugate(qb))
    vn = _safe_norm(rel[..., 1:])
    return 2.0 * torch.atan2(vn, rel[..., 0].abs())


def quat_average_markley(q: Tensor, weights: Optional[Tensor] = None) -> Tensor:
    """Weighted quaternion average (Markley et al. 2007): the principal eigenvector of sum_i w_i q_i
    q_i^T.

    Args:
        q: [..., M, 4] quaternions (normalised here; sign-invariant).
        weights: optional [..., M] non-negative weights.
    Returns:
        [..., 4] unit quaternion with w >= 0.
    """
    qn = quat_normalize(q)
    if weights is None:
        weights = torch.ones(qn.shape[:-1], dtype=qn.dtype, device=qn.device)
    m = torch.einsum("...m,...mi,...mj->...ij", weights.to(qn.dtype), qn, qn)
    _, vecs = torch.linalg.eigh(m)
    avg = vecs[..., :, -1]
    return torch.where(avg[..., :1] < 0, -avg, avg)


def align_quat_signs(
    q: Tensor, valid: Optional[Tensor] = None, reference: Optional[Tensor] = None
) -> Tensor:
    """Flip signs along time so consecutive quaternions lie in the same hemisphere (continuous for a
    polynomial fit).

    Args:
        q: [N, T, 4] quaternions. valid: optional [N, T] mask; invalid samples do not become the
        reference for the next frame. reference: optional [N, 4] quaternion the first frame is
        aligned to (default: the first valid sample itself).
    Returns:
        [N, T, 4] sign-aligned copy.
    """
    n, t_count, _ = q.shape
    out = q.clone()
    if reference is None:
        ref = q[:, 0].clone()
        if valid is not None:
            first = valid.float().argmax(dim=1)
            ref = q[torch.arange(n, device=q.device), first]
    else:
        ref = reference.to(q.dtype).expand(n, 4).clone()
    for t in range(t_count):
        dot = (out[:, t] * ref).sum(-1, keepdim=True)
        out[:, t] = torch.where(dot < 0, -out[:, t], out[:, t])
        if valid is None:
            ref = out[:, t]
        else:
            ref = torch.where(valid[:, t, None], out[:, t], ref)
    return out


# --------------------------------------------------------------------------------------------------
# polynomial trajectories
# --------------------------------------------------------------------------------------------------
def normalize_time(t: Union[Tensor, float, int], num_frames: int) -> Tensor:
    """Frame time (0..T-1, fractional allowed) -> normalised time in [0, 1] (0 for a single
    frame)."""
    t = torch.as_tensor(t, dtype=torch.float32) if not torch.is_tensor(t) else t
    return t / max(num_frames - 1, 1)


def init_rotation_coeffs(
    n: int, degree: int = 3, mode: str = "paper", *, dtype=torch.float32, device=None
) -> Tensor:
    """Identity-rotation polynomial coefficients [n, degree + 1, 4].

    mode "paper": every coefficient is [1, 0, 0, 0] (the paper's wording); "constant": a_0 = [1, 0,
    0, 0] and the higher terms zero (the authors' code)."""
    if mode not in ROTATION_INIT_MODES:
        raise ValueError(
            f"unknown rotation init mode {mode!r}; expected one of {ROTATION_INIT_MODES}"
        )
    c = torch.zeros(n, degree + 1, 4, dtype=dtype, device=device)
    if mode == "paper":
        c[..., 0] = 1.0
    else:
        c[:, 0, 0] = 1.0
    return c


def vandermonde(t: Tensor, degree: int) -> Tensor:
    """[T] -> [T, degree + 1] with columns t^0 .. t^degree."""
    return torch.stack([t**j for j in range(degree + 1)], dim=-1)


def poly_evaluate(coeffs: Tensor, t: Union[Tensor, float, int], normalize: bool = False) -> Tensor:
    """Evaluate r(t) = sum_j a_j t^j.

    Args:
        coeffs: [N, J, 4] coefficients (power index first).
        t: [T] normalised times or a scalar.
        normalize: return unit quaternions instead of the raw polynomial value.
    Returns:
        [N, T, 4] (or [N, 4] for a scalar t).
    """
    scalar = not torch.is_tensor(t) or t.dim() == 0
    tt = torch.as_tensor(t, dtype=coeffs.dtype, device=coeffs.device).reshape(-1)
    v = vandermonde(tt, coeffs.shape[1] - 1)  # [T, J]
    out = apply_basis(coeffs, v)  # one matrix product (m4dgs.core.spline.apply_basis)
    if normalize:
        out = quat_normalize(out)
    return out[:, 0] if scalar else out


def fit_rotation_poly(
    target: Tensor,
    t: Tensor,
    valid: Optional[Tensor] = None,
    *,
    degree: int = 3,
    ridge: float = 1e-6,
    align: bool = True,
    reference: Optional[Tensor] = None,
    normalize_targets: bool = True,
) -> Tensor:
    """Least-squares polynomial coefficients reproducing target quaternions (video-to-world, sec.
    3.3.2).

    Targets are first sign-aligned along time (so the polynomial need not pass through a sign flip)
    and normalised; the polynomial then fits the unit quaternions in the least-squares sense (masked
    per Gaussian).

    Args:
        target: [N, T, 4] target quaternions. t: [T] normalised times. valid: optional [N, T] mask.
        ridge: Tikhonov weight on the coefficients of degree >= 1 (keeps sparse observations
        well-posed: an
            unobserved Gaussian falls back to a constant).
        reference: optional [N, 4] reference for the sign alignment. normalize_targets: fit the unit
        quaternions (default); False fits the targets as given (then a target
            sequence produced by a cubic polynomial is recovered exactly, up to the sign alignment).
    Returns:
        [N, degree + 1, 4] coefficients.
    """
    n, t_count, _ = target.shape
    work = torch.float64 if target.dtype == torch.float64 else torch.float32
    q = target.to(work)
    if normalize_targets:
        q = quat_normalize(q)
    if align:
        q = align_quat_signs(q, valid, reference)
    if valid is None:
        valid = torch.ones(n, t_count, dtype=torch.bool, device=target.device)
    v = vandermonde(t.to(device=target.device, dtype=work), degree)  # [T, J]
    w = valid.to(work)
    lhs = torch.einsum("nt,ti,tj->nij", w, v, v)
    reg = torch.full((degree + 1,), ridge, dtype=work, device=target.device)
    reg[0] = 1e-12
    lhs = lhs + torch.diag(reg)
    qz = torch.where(valid[..., None], q, torch.zeros((), dtype=work, device=target.device))
    rhs = torch.einsum("nt,tj,ntc->njc", w, v, qz)
    has = valid.any(dim=1)
    eye = torch.eye(degree + 1, dtype=work, device=target.device)
    lhs = torch.where(has[:, None, None], lhs, eye)
    coeffs = torch.linalg.solve(lhs, rhs)
    # Gaussians without observations: identity constant
    ident = init_rotation_coeffs(n, degree, "constant", dtype=work, device=target.device)
    coeffs = torch.where(has[:, None, None], coeffs, ident)
    return coeffs.to(target.dtype)


def quat_alignment_loss(pred: Tensor, target: Tensor, valid: Optional[Tensor] = None) -> Tensor:
    """Mean of 1 - |<q_pred / |q_pred|, q_target / |q_target|>| (sign-invariant; the authors' refit
    objective)."""
    d = 1.0 - (quat_normalize(pred) * quat_normalize(target)).sum(-1).abs()
    if valid is None:
        return d.mean()
    w = valid.to(d.dtype)
    return (d * w).sum() / w.sum().clamp_min(1.0)


def refine_rotation_poly(
    coeffs: Tensor,
    target: Tensor,
    t: Tensor,
    valid: Optional[Tensor] = None,
    *,
    steps: int = 200,
    lr: float = 1e-2,
) -> Tensor:
    """Refine coefficients with Adam on `quat_alignment_loss` (a refinement step after
    `fit_rotation_poly`).

    Args:
        coeffs: [N, J, 4] initial coefficients (e.g. from the least-squares fit).
        target: [N, T, 4]; t: [T] normalised times; valid: optional [N, T].
    Returns:
        [N, J, 4] refined coefficients (detached).
    """
    c = coeffs.detach().clone().requires_grad_(True)
    tgt = target.detach()
    opt = torch.optim.Adam([c], lr=lr)
    n = c.shape[0]
    for _ in range(steps):
        opt.zero_grad(set_to_none=True)
        # per-Gaussian scale for Adam
        loss = quat_alignment_loss(poly_evaluate(c, t), tgt, valid) * n
        loss.backward()
        opt.step()
    return c.detach()
