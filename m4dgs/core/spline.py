"""Cubic Hermite spline trajectories for Gaussian positions (paper, appendix "Cubic Hermite Spline
Interpolation").

For control points p_k at knot times t_k (k = 0..K-1) and t in [t_k, t_{k+1}]:

    mu(t) = h00(s) p_k + h10(s) (t_{k+1} - t_k) m_k + h01(s) p_{k+1} + h11(s) (t_{k+1} - t_k)
    m_{k+1}, s = (t - t_k) / (t_{k+1} - t_k), m_k = 1/2 ((p_{k+1} - p_k) / (t_{k+1} - t_k) + (p_k -
    p_{k-1}) / (t_k - t_{k-1}))   (Catmull-Rom tangent),

with h00 = 2s^3 - 3s^2 + 1, h10 = s^3 - 2s^2 + s, h01 = -2s^3 + 3s^2, h11 = s^3 - s^2. At the two
ends the tangent is the one-sided slope (m_0 = (p_1 - p_0) / (t_1 - t_0), m_{K-1} likewise), as in
the authors' code.

Time is measured in training-frame indices (0..T-1; test frames sit at fractional times i + 0.5).
Control points are placed every N_s frames (paper default 4, section "Implementation Details"), plus
a final knot at the last frame when T - 1 is not a multiple of N_s. Times outside [t_0, t_{K-1}] are
clamped to the ends.

The spline is linear in its control points, mu(t) = sum_k B[t, k] p_k, so fitting control points to
a trajectory is a (regularised, masked) linear least-squares problem per Gaussian
(`fit_control_points`; `fit_control_points_weighted` with a weight matrix per sample)."""

from __future__ import annotations

import numbers
from typing import Optional, Sequence, Union

import torch

Tensor = torch.Tensor


def make_knots(num_frames: int, every: int = 4, *, dtype=torch.float32, device=None) -> Tensor:
    """Knot times 0, N_s, 2 N_s, ... over frames 0..num_frames-1, plus the last frame if it is not
    on the grid.

    Args:
        num_frames: number of training frames T (>= 1).
        every: control-point spacing N_s in frames (>= 1).
    Returns:
        [K] increasing knot times (K = 1 when T == 1).
    """
    if num_frames < 1:
        raise ValueError(f"num_frames must be >= 1, got {num_frames}")
    if every < 1:
        raise ValueError(f"control-point spacing must be >= 1, got {every}")
    last = num_frames - 1
    knots = list(range(0, last + 1, every))
    if knots[-1] != last:
        knots.append(last)
    return torch.tensor(knots, dtype=dtype, device=device)


def uniform_knots(num_frames: int, count: int, *, dtype=torch.float32, device=None) -> Tensor:
    """`count` knot times spread evenly over frames 0..num_frames-1 (fractional in general), for
    curves whose resolution is a number of knots rather than a spacing in frames (the per-Gaussian
    brightness gain of `ModelConfig.appearance_knots`). A single frame spans [0, 1] instead, so
    that the knots stay distinct.

    Args:
        num_frames: number of training frames T (>= 1).
        count: number of knots K (>= 1).
    Returns:
        [K] increasing knot times from 0 to T - 1 ([0] when K == 1).
    """
    if num_frames < 1:
        raise ValueError(f"num_frames must be >= 1, got {num_frames}")
    if count < 1:
        raise ValueError(f"the number of knots must be >= 1, got {count}")
    return torch.linspace(0.0, float(max(num_frames - 1, 1)), count, dtype=dtype, device=device)


def hermite_basis(s: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Hermite basis functions (h00, h10, h01, h11) at local parameter s in [0, 1] (same shape as
    s)."""
    s2 = s * s
    s3 = s2 * s
    h00 = 2.0 * s3 - 3.0 * s2 + 1.0
    h10 = s3 - 2.0 * s2 + s
    h01 = -2.0 * s3 + 3.0 * s2
    h11 = s3 - s2
    return h00, h10, h01, h11


def tangents(ctrl: Tensor, knots: Tensor) -> Tensor:
    """Catmull-Rom tangents m_k: mean of the adjacent slopes, one-sided slope at the two ends.

    Args:
        ctrl: [..., K, D] control points.
        knots: [K] knot times.
    Returns:
        [..., K, D] tangents (zeros when K == 1).
    """
    k = ctrl.shape[-2]
    if k == 1:
        return torch.zeros_like(ctrl)
    dt = (knots[1:] - knots[:-1]).to(ctrl.dtype)  # [K-1]
    slopes = (ctrl[..., 1:, :] - ctrl[..., :-1, :]) / dt[:, None]  # [..., K-1, D]
    inner = 0.5 * (slopes[..., 1:, :] + slopes[..., :-1, :])  # [..., K-2, D]
    return torch.cat([slopes[..., :1, :], inner, slopes[..., -1:, :]], dim=-2)


def _as_times(t: Union[Tensor, float, int], like: Tensor) -> tuple[Tensor, bool]:
    scalar = t.dim() == 0 if torch.is_tensor(t) else isinstance(t, numbers.Real)
    tt = torch.as_tensor(t, dtype=like.dtype, device=like.device).reshape(-1)
    return tt, scalar


def evaluate(
    ctrl: Tensor,
    knots: Tensor,
    t: Union[Tensor, float, int, Sequence[float]],
    memo: Optional["BasisMemo"] = None,
) -> Tensor:
    """Evaluate the spline of each Gaussian at times t (differentiable wrt ctrl).

    The spline is linear in the control points, so this is one matrix product of the control
    points viewed as [N, K D] with the [K D, T D] matrix of the [T, K] basis (`basis_matrix`,
    computed on the K knots only, times the D x D identity): forward and backward are one
    contiguous matrix product each, instead of the tangents and four gathers of
    `evaluate_reference` over all N Gaussians (about 5x faster forward + backward at N = 10k,
    K = 14, one time, on a CPU). Equal to the reference up to float rounding.

    Args:
        ctrl: [N, K, D] control points.
        knots: [K] increasing knot times.
        t: [T] times (a tensor or a sequence of numbers), or a scalar time (clamped to
            [knots[0], knots[-1]]).
        memo: keeps the product matrix of times given on the host (numbers, sequences, CPU
            tensors) for the next call with the same knots and times (`BasisMemo`); the result is
            the same bit for bit.
    Returns:
        [N, T, D] positions, or [N, D] for a scalar t.
    """
    found = memo.plan(ctrl, knots, t) if memo is not None else None
    if found is not None:
        plan, scalar = found
        out = apply_plan(ctrl, plan)
        return out[:, 0] if scalar else out
    tt, scalar = _as_times(t, ctrl)
    out = apply_basis(ctrl, basis_matrix(knots.to(device=ctrl.device, dtype=ctrl.dtype), tt))
    return out[:, 0] if scalar else out


def product_plan(basis: Tensor, coeffs: Tensor) -> tuple[Tensor, int, int]:
    """The matrix and the coefficient range of `apply_basis` for `basis` [T, K] and coefficients
    shaped like `coeffs` [N, K, D]: (m [(hi - lo) D, T D], lo, hi).

    On the CPU only the coefficients of the basis's nonzero column range enter the product (a
    spline at a few nearby times reads 4-6 of its K control points): a column slice of the [N, K D]
    view, which the matrix product reads in place, so forward and backward touch a fraction of the
    coefficients. The column range is read on the host to slice with it: on CUDA that would be a
    device sync per spline evaluation, where the full product is cheap, so only CPU tensors are
    narrowed."""
    _, k, d = coeffs.shape
    lo, hi = 0, k
    if coeffs.device.type == "cpu":
        cols = torch.nonzero(basis.detach().abs().sum(0)).flatten()
        if 0 < cols.numel() and (cols[-1] - cols[0] + 1) < k:
            lo, hi = int(cols[0]), int(cols[-1]) + 1
            basis = basis[:, lo:hi]
    eye = torch.eye(d, dtype=coeffs.dtype, device=coeffs.device)
    m = (basis.to(coeffs.dtype).t()[:, None, :, None] * eye[None, :, None, :]).reshape(
        (hi - lo) * d, -1
    )
    return m, lo, hi


def apply_plan(coeffs: Tensor, plan: tuple[Tensor, int, int]) -> Tensor:
    """coeffs [N, K, D] through a `product_plan` (m, lo, hi): [N, T, D]."""
    m, lo, hi = plan
    n, k, d = coeffs.shape
    if hi - lo < k:
        coeffs = coeffs[:, lo:hi]
    return (coeffs.reshape(n, (hi - lo) * d) @ m).reshape(n, m.shape[1] // d, d)


def apply_basis(coeffs: Tensor, basis: Tensor) -> Tensor:
    """out[n, t] = sum_k basis[t, k] coeffs[n, k] as ONE matrix product of coeffs viewed as [N, K D]
    with the [K D, T D] matrix basis^T (x) I_D (forward and backward stay contiguous; an einsum
    permutes and copies the coefficients first); on the CPU narrowed to the basis's nonzero
    columns (`product_plan`).

    Args:
        coeffs: [N, K, D] per-Gaussian coefficients (spline control points, polynomial terms).
        basis: [T, K] weights of each coefficient at each time.
    Returns:
        [N, T, D].
    """
    return apply_plan(coeffs, product_plan(basis, coeffs))


class BasisMemo:
    """The basis rows and product plans (`product_plan`) of spline evaluations at times given on
    the host, kept per knot vector, coefficient width, dtype and device.

    Training evaluates its splines at the same frame times step after step (the frame, its TLR
    neighbours, the smoothness window); each evaluation otherwise rebuilds its [T, K] basis term by
    term from the knots, some 40 small tensor operations, each a kernel launch on a GPU (where a
    training step is bound by its launches, docs/performance.md). A set of times seen before costs
    no operation; a new set of known times costs the stacking of their rows and the plan. The rows
    of `basis_matrix` do not depend on the other times of the call (no reduction runs across
    times), so the result is the same bit for bit as without the memo.

    A memo belongs to one model (its Gaussians hold one). It keeps the knot tensors it has seen,
    so their identity stays unique, and their version, so knots changed in place miss. Times
    given as CUDA tensors are not memoised (reading them for a key would wait for the device).
    When it holds `max_entries` rows and plans, the memo starts over. A copied or pickled memo
    (a copied model) starts empty: its keys name the original's knot tensors."""

    def __init__(self, max_entries: int = 4096):
        self.max_entries = int(max_entries)
        self.plans: dict = {}
        self.rows: dict = {}
        self._knots: dict = {}

    def __copy__(self) -> "BasisMemo":
        return BasisMemo(self.max_entries)

    def __deepcopy__(self, _memo) -> "BasisMemo":
        return BasisMemo(self.max_entries)

    def __getstate__(self) -> dict:
        return {"max_entries": self.max_entries}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["max_entries"])

    @staticmethod
    def host_times(t) -> Optional[tuple[tuple, bool]]:
        """(times as floats, scalar) of t, or None when t is a tensor off the CPU."""
        if torch.is_tensor(t):
            if t.device.type != "cpu":
                return None
            return tuple(t.reshape(-1).tolist()), t.dim() == 0
        if isinstance(t, numbers.Real):
            return (float(t),), True
        return tuple(float(v) for v in t), False

    def plan(self, ctrl: Tensor, knots: Tensor, t) -> Optional[tuple[tuple, bool]]:
        """(the product plan of ctrl's shape at times t, scalar), or None when t is not on the
        host."""
        ht = self.host_times(t)
        if ht is None:
            return None
        times, scalar = ht
        dev = ctrl.device
        base = (id(knots), knots._version, ctrl.dtype, dev.type, dev.index)
        key = base + (ctrl.shape[-1], times)
        plan = self.plans.get(key)
        if plan is None:
            if len(self.plans) + len(self.rows) >= self.max_entries:
                self.plans.clear()
                self.rows.clear()
                self._knots.clear()
            self._knots[id(knots)] = knots
            missing = sorted({v for v in times if base + (v,) not in self.rows})
            if missing:
                kk = knots.to(device=dev, dtype=ctrl.dtype)
                tt = torch.as_tensor(missing, dtype=ctrl.dtype, device=dev)
                for v, row in zip(missing, basis_matrix(kk, tt)):
                    self.rows[base + (v,)] = row
            basis = torch.stack([self.rows[base + (v,)] for v in times])
            plan = product_plan(basis, ctrl)
            self.plans[key] = plan
        return plan, scalar


def evaluate_reference(ctrl: Tensor, knots: Tensor, t: Union[Tensor, float, int]) -> Tensor:
    """The Hermite formula term by term (the slow, obvious reference of `evaluate`; also builds
    `basis_matrix`): segment lookup, Catmull-Rom tangents of every control point, basis weights.

    Args:
        ctrl: [N, K, D] control points.
        knots: [K] increasing knot times.
        t: [T] times, or a scalar time (clamped to [knots[0], knots[-1]]).
    Returns:
        [N, T, D] positions, or [N, D] for a scalar t.
    """
    n, k, d = ctrl.shape
    tt, scalar = _as_times(t, ctrl)
    knots = knots.to(device=ctrl.device, dtype=ctrl.dtype)
    if k == 1:
        out = ctrl[:, :1, :].expand(n, tt.numel(), d)
        return out[:, 0] if scalar else out
    tt = tt.clamp(knots[0], knots[-1])
    # segment index i with knots[i] <= t <= knots[i+1]; t == knots[-1] goes to the last segment
    seg = torch.searchsorted(knots, tt, right=True) - 1
    seg = seg.clamp(0, k - 2)
    t0 = knots[seg]
    t1 = knots[seg + 1]
    h = t1 - t0  # [T]
    s = (tt - t0) / h
    h00, h10, h01, h11 = hermite_basis(s)
    m = tangents(ctrl, knots)  # [N, K, D]
    p0 = ctrl[:, seg]  # [N, T, D]
    p1 = ctrl[:, seg + 1]
    m0 = m[:, seg]
    m1 = m[:, seg + 1]
    out = (
        h00[None, :, None] * p0
        + (h10 * h)[None, :, None] * m0
        + h01[None, :, None] * p1
        + (h11 * h)[None, :, None] * m1
    )
    return out[:, 0] if scalar else out


def basis_matrix(knots: Tensor, t: Union[Tensor, float, int]) -> Tensor:
    """Linear map from control points to positions: evaluate(ctrl, knots, t)[n] == B @ ctrl[n].

    Args:
        knots: [K] knot times (float dtype).
        t: [T] times (or scalar -> T = 1).
    Returns:
        [T, K] basis matrix (rows sum to 1).
    """
    k = knots.numel()
    eye = torch.eye(k, dtype=knots.dtype, device=knots.device)[None]  # [1, K, K]: D = K
    tt, _ = _as_times(t, knots)
    return evaluate_reference(eye, knots, tt)[0]  # [T, K]


def second_difference_matrix(knots: Tensor) -> Tensor:
    """Divided second differences of the control points, [K-2, K] (empty for K < 3).

    Row k gives (p_{k+1} - p_k) / (t_{k+1} - t_k) - (p_k - p_{k-1}) / (t_k - t_{k-1}); it vanishes
    for control points on a straight line in time, so the smoothness term never biases linear
    motion."""
    k = knots.numel()
    d2 = torch.zeros(max(k - 2, 0), k, dtype=knots.dtype, device=knots.device)
    for i in range(1, k - 1):
        a = 1.0 / (knots[i] - knots[i - 1])
        b = 1.0 / (knots[i + 1] - knots[i])
        d2[i - 1, i - 1] = a
        d2[i - 1, i] = -a - b
        d2[i - 1, i + 1] = b
    return d2


def first_difference_matrix(knots: Tensor) -> Tensor:
    """Divided first differences (p_{k+1} - p_k) / (t_{k+1} - t_k), [K-1, K]."""
    k = knots.numel()
    d1 = torch.zeros(max(k - 1, 0), k, dtype=knots.dtype, device=knots.device)
    for i in range(k - 1):
        inv = 1.0 / (knots[i + 1] - knots[i])
        d1[i, i] = -inv
        d1[i, i + 1] = inv
    return d1


def _difference_regulariser(knots: Tensor, smooth: float, damping: float) -> Tensor:
    """[K, K] smooth * D2^T D2 + damping * D1^T D1 of the control-point fits (dtype / device of
    knots), D2 / D1 the divided second / first differences rescaled by the mean knot spacing: on
    uniform knots the plain differences p_{k+1} - 2 p_k + p_{k-1} and p_{k+1} - p_k (units of the
    trajectory)."""
    k = knots.numel()
    spacing = float(knots[-1] - knots[0]) / (k - 1) if k > 1 else 1.0
    reg = torch.zeros(k, k, dtype=knots.dtype, device=knots.device)
    if k >= 3 and smooth > 0:
        d2 = second_difference_matrix(knots) * spacing**2
        reg = reg + smooth * d2.T @ d2
    if k >= 2 and damping > 0:
        d1 = first_difference_matrix(knots) * spacing
        reg = reg + damping * d1.T @ d1
    return reg


def fit_control_points(
    traj: Tensor,
    valid: Optional[Tensor],
    times: Tensor,
    knots: Tensor,
    *,
    smooth: float = 1e-3,
    damping: float = 1e-6,
    chunk: int = 16384,
) -> Tensor:
    """Least-squares control points of a spline that follows each trajectory on its valid frames.

    Solves per Gaussian n:  min_c  sum_t v_nt |B_t c - y_nt|^2 + smooth * |D2 c|^2 + damping * |D1
    c|^2,
    with B the [T, K] basis matrix, D2 / D1 the divided second / first differences of the control
    points times the mean knot spacing h (h^2 for D2), so that on uniform knots they are the plain
    differences of the control points. The second-difference term lets the spline itself fill
    invisible spans (linear continuation) and makes points with few visible frames well-posed; the
    tiny first-difference term fixes the remaining slope when a Gaussian has a single visible frame
    (then it stays constant). A Gaussian with no valid frame gets all-zero control points (filter
    those before).

    Args:
        traj: [N, T, D] trajectories (values on invalid frames are ignored; they may be NaN).
        valid: [N, T] bool mask, or None for all frames valid.
        times: [T] frame times of the trajectory samples.
        knots: [K] knot times.
        smooth: weight of the second-difference (acceleration) term.
        damping: weight of the first-difference term.
        chunk: Gaussians solved per batch (memory bound).
    Returns:
        [N, K, D] control points (same dtype/device as traj). Exact when the trajectory is itself a
        spline on these knots observed on enough frames, up to the (small) smoothness bias.
    """
    n, t_count, d = traj.shape
    dtype = traj.dtype
    # K x K normal equations: solved in double precision (cheap, and well-conditioned)
    work = torch.float64
    knots = knots.to(device=traj.device, dtype=work)
    times = times.to(device=traj.device, dtype=work)
    k = knots.numel()
    if valid is None:
        valid = torch.ones(n, t_count, dtype=torch.bool, device=traj.device)
    basis = basis_matrix(knots, times)  # [T, K]
    reg = _difference_regulariser(knots, smooth, damping)
    if k == 1 or (smooth <= 0 and damping <= 0):
        reg = reg + 1e-12 * torch.eye(k, dtype=work, device=traj.device)
    out = torch.zeros(n, k, d, dtype=work, device=traj.device)
    outer = basis[:, :, None] * basis[:, None, :]  # [T, K, K]
    for start in range(0, n, chunk):
        sl = slice(start, min(start + chunk, n))
        w = valid[sl].to(work)  # [n, T]
        y = torch.where(
            valid[sl, :, None], traj[sl].to(work), torch.zeros((), dtype=work, device=traj.device)
        )
        lhs = torch.einsum("nt,tij->nij", w, outer) + reg  # [n, K, K]
        rhs = torch.einsum("nt,tk,ntd->nkd", w, basis, y)  # [n, K, D]
        has = valid[sl].any(dim=1)
        # Gaussians with no valid frame: solve the identity instead (-> zeros) to keep the batch
        # well-posed
        eye = torch.eye(k, dtype=work, device=traj.device)
        lhs = torch.where(has[:, None, None], lhs, eye)
        out[sl] = torch.linalg.solve(lhs, rhs)
    return out.to(dtype)


def fit_control_points_weighted(
    traj: Tensor,
    weights: Tensor,
    times: Tensor,
    knots: Tensor,
    *,
    smooth: float = 1e-3,
    damping: float = 1e-6,
    reg_scale: Optional[Tensor] = None,
    chunk: int = 1024,
) -> Tensor:
    """`fit_control_points` with a D x D weight matrix per sample instead of a valid mask.

    Solves per Gaussian n:  min_c  sum_t (B_t c - y_nt)^T W_nt (B_t c - y_nt)
    + r_n (smooth * |D2 c|^2 + damping * |D1 c|^2), the D coordinates now coupled through W (an
    anisotropic error: e.g. errors across a camera ray weighted like the pixels they move, errors
    along it by a depth tolerance; m4dgs.training.v2w). W = I on valid frames and 0 elsewhere is
    `fit_control_points`' problem.

    Args:
        traj: [N, T, D] trajectories (values where W is zero are ignored; they may be NaN).
        weights: [N, T, D, D] symmetric positive semi-definite weights.
        times: [T] frame times. knots: [K] knot times.
        smooth, damping: weights of the second- and first-difference terms (as in
            fit_control_points).
        reg_scale: optional [N] factor r_n on both terms (default 1), to keep their strength
            relative to a data term whose units W changes.
        chunk: Gaussians solved per batch (memory: chunk x (K D)^2 doubles).
    Returns:
        [N, K, D] control points (dtype of traj). Exact when the trajectory is itself a spline on
        these knots and W constrains it on enough frames, up to the small regularisation bias.
    """
    n, t_count, d = traj.shape
    if weights.shape != (n, t_count, d, d):
        raise ValueError(f"weights must be [{n}, {t_count}, {d}, {d}], got {list(weights.shape)}")
    dtype = traj.dtype
    work = torch.float64
    dev = traj.device
    knots = knots.to(device=dev, dtype=work)
    times = times.to(device=dev, dtype=work)
    k = knots.numel()
    basis = basis_matrix(knots, times)  # [T, K]
    reg = _difference_regulariser(knots, smooth, damping)
    eye_d = torch.eye(d, dtype=work, device=dev)
    reg = torch.kron(reg, eye_d)  # [K D, K D]: the same term on every coordinate
    tiny = 1e-12 * torch.eye(k * d, dtype=work, device=dev)
    scale = (
        torch.ones(n, dtype=work, device=dev)
        if reg_scale is None
        else reg_scale.to(device=dev, dtype=work)
    )
    outer = basis[:, :, None] * basis[:, None, :]  # [T, K, K]
    eye = torch.eye(k * d, dtype=work, device=dev)
    out = torch.zeros(n, k, d, dtype=work, device=dev)
    for start in range(0, n, chunk):
        sl = slice(start, min(start + chunk, n))
        w = weights[sl].to(work)  # [n, T, D, D]
        has = w.abs().sum(dim=(1, 2, 3)) > 0
        y = torch.where(w.abs().sum(-1) > 0, traj[sl].to(work), torch.zeros((), dtype=work))
        # sum_t (B_t kron I)^T W_t (B_t kron I): entry (k i, l j) = sum_t B_tk B_tl W_t,ij
        lhs = torch.einsum("tkl,ntij->nkilj", outer, w).reshape(-1, k * d, k * d)
        wy = torch.einsum("ntij,ntj->nti", w, y)  # [n, T, D]
        rhs = torch.einsum("tk,nti->nki", basis, wy).reshape(-1, k * d)
        lhs = lhs + scale[sl, None, None] * reg + tiny
        # a Gaussian with no weight at all gets zeros, as in the mask fit
        lhs = torch.where(has[:, None, None], lhs, eye)
        out[sl] = torch.linalg.solve(lhs, rhs).reshape(-1, k, d)
    return out.to(dtype)


# the smoothness weight of the video-to-world control-point fit (both of its error measures)
RESAMPLE_SMOOTH = 1e-4


def resample_control_points(
    traj: Tensor,
    times: Tensor,
    knots: Tensor,
    *,
    valid: Optional[Tensor] = None,
    method: str = "lstsq",
    smooth: float = RESAMPLE_SMOOTH,
) -> Tensor:
    """Control points for a dense trajectory (video-to-world transform, paper sec. 3.3.2).

    Args:
        traj: [N, T, D] dense trajectory at `times` [T]. knots: [K] knot times. valid: optional [N,
        T] mask (lstsq only). method: "lstsq" (least-squares spline fit of all samples, default) or
        "sample" (the spline interpolates its
            control points, so take the trajectory at the knot times, linearly interpolated between
            samples).
    Returns:
        [N, K, D] control points.
    """
    if method == "lstsq":
        return fit_control_points(traj, valid, times, knots, smooth=smooth)
    if method == "sample":
        times = times.to(device=traj.device, dtype=traj.dtype)
        kn = knots.to(device=traj.device, dtype=traj.dtype).clamp(times[0], times[-1])
        idx = (torch.searchsorted(times, kn, right=True) - 1).clamp(0, max(times.numel() - 2, 0))
        if times.numel() == 1:
            return traj[:, :1].expand(-1, kn.numel(), -1).clone()
        ta, tb = times[idx], times[idx + 1]
        wgt = ((kn - ta) / (tb - ta)).clamp(0, 1)[None, :, None]
        return traj[:, idx] * (1 - wgt) + traj[:, idx + 1] * wgt
    raise ValueError(f"unknown resample method {method!r} (expected 'lstsq' or 'sample')")
