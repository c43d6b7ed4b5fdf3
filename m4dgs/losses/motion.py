"""Gaussian motion regularisation (paper appendix "Gaussian Motion Regularization").

- ARAP / distance preservation over the k = 5 nearest neighbours: the neighbour sets are found at
  time t (indices carry no gradient) and the loss compares each Gaussian's distances to the same
  neighbours at t and t':
  L_arap = mean_{i, j in N_k(mu_t^i)} (|mu_t^i - mu_t^j| - |mu_t'^i - mu_t'^j|)^2.
- Velocity / acceleration smoothness (MoSca):
  L_vel = sum_t |mu_{t+1} - mu_t|_2 + theta(R_t R_{t+1}^-1),
  L_acc = sum_t |mu_t - 2 mu_{t+1} + mu_{t+2}|_2 + |theta(R_t R_{t+1}^-1) - theta(R_{t+1}
  R_{t+2}^-1)|,
  where theta is the rotation angle, i.e. the norm of the axis-angle vector, which is what the paper
  means by
  ``||log(.)||_F`` ("the axis-angle of the rotation"); note that the Frobenius norm of the
  skew-symmetric log matrix
  itself would be sqrt(2) * theta. Sums run over the frames of the (sampled) time window; the mean
  is taken over Gaussians. ``stride`` > 1 compares frames that far apart; the authors' variant
  evaluates a window of +-2 frames around the query time (`window_times`).
- Beyond the paper (`loss.smooth_relative`): the same two terms on each Gaussian's position
  relative to the mean of its k nearest neighbours (`relative_to_neighbours`), so that they charge
  the Gaussians' motion against their neighbours' and leave a group's common motion free.
"""

from __future__ import annotations

import torch

from m4dgs.core.knn import knn
from m4dgs.core.rotation import relative_rotation_angle
from m4dgs.core.tensors import gather_rows

ARAP_K = 5  # paper appendix: k = 5


def _safe_norm(x: torch.Tensor, dim: int = -1) -> torch.Tensor:
    """Euclidean norm whose gradient is 0 (not NaN) at the zero vector."""
    sq = (x * x).sum(dim)
    nz = sq > 1e-24
    return torch.where(
        nz, torch.sqrt(torch.where(nz, sq, torch.ones_like(sq))), torch.zeros_like(sq)
    )


def arap_loss(
    pos_t: torch.Tensor, pos_tp: torch.Tensor, nbr_idx: torch.Tensor | None = None, k: int = ARAP_K
) -> torch.Tensor:
    """As-rigid-as-possible (distance-preserving) loss between times t and t'.

    Args:
        pos_t: [N, 3] Gaussian positions at t; pos_tp: [N, 3] positions at t'. nbr_idx: [N, k]
        neighbour indices found at time t (e.g. from `m4dgs.core.knn.knn`); computed from pos_t if
        None.
    Returns:
        scalar: mean over the N * k pairs of (|mu_t^i - mu_t^j| - |mu_t'^i - mu_t'^j|)^2.
    """
    if nbr_idx is None:
        nbr_idx, _ = knn(pos_t, k)
    d_t = _safe_norm(pos_t[:, None, :] - gather_rows(pos_t, nbr_idx))  # [N, k]
    d_tp = _safe_norm(pos_tp[:, None, :] - gather_rows(pos_tp, nbr_idx))
    return ((d_t - d_tp) ** 2).mean()


def quat_relative_angle(q1: torch.Tensor, q2: torch.Tensor) -> torch.Tensor:
    """Rotation angle of R(q1) R(q2)^-1 in [0, pi] (=
    m4dgs.core.rotation.relative_rotation_angle)."""
    return relative_rotation_angle(q1, q2)


def _reduce_time(x: torch.Tensor, time_reduction: str) -> torch.Tensor:
    """x [T', N] -> scalar: sum (paper) or mean over time, then mean over Gaussians."""
    if time_reduction == "sum":
        return x.sum(0).mean()
    if time_reduction == "mean":
        return x.mean()
    raise ValueError(f"unknown time_reduction {time_reduction!r}")


def smoothness_terms(
    positions: torch.Tensor,
    quats: torch.Tensor | None = None,
    stride: int = 1,
    time_reduction: str = "sum",
) -> dict[str, torch.Tensor]:
    """The four motion-smoothness terms on a time window.

    Args:
        positions: [T, N, 3] positions of N Gaussians at T window times (consecutive times, or any
        sampled window). quats: [T, N, 4] rotations (w, x, y, z) at the same times, or None
        (rotation terms are then 0). stride: frame gap s: velocity uses (t, t + s), acceleration (t,
        t + s, t + 2s). time_reduction: "sum" over the window (paper formula) or "mean".
    Returns:
        dict with scalar tensors "pos_vel", "rot_vel", "pos_acc", "rot_acc" (means over Gaussians).
    """
    s = int(stride)
    T = positions.shape[0]
    zero = positions.new_zeros(())
    out = {"pos_vel": zero, "rot_vel": zero, "pos_acc": zero, "rot_acc": zero}
    if T > s:
        out["pos_vel"] = _reduce_time(_safe_norm(positions[s:] - positions[:-s]), time_reduction)
    if T > 2 * s:
        acc = positions[: T - 2 * s] - 2.0 * positions[s : T - s] + positions[2 * s :]
        out["pos_acc"] = _reduce_time(_safe_norm(acc), time_reduction)
    if quats is not None and T > s:
        ang = quat_relative_angle(quats[:-s], quats[s:])  # [T - s, N]
        out["rot_vel"] = _reduce_time(ang, time_reduction)
        if T > 2 * s:
            out["rot_acc"] = _reduce_time((ang[: T - 2 * s] - ang[s:]).abs(), time_reduction)
    return out


def relative_to_neighbours(positions: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
    """Each Gaussian's position less the mean of its neighbours' at the same time (beyond the
    paper: `loss.smooth_relative`).

    Args:
        positions: [T, N, 3] positions of N Gaussians at T times; neighbours: [T, N, k, 3] the
            positions of each one's k neighbours at the same times.
    Returns:
        [T, N, 3]. Velocity and acceleration are linear in the positions, so those of the result
        are each Gaussian's own less its neighbours' mean: zero for a group that moves as one,
        however fast or curved its path, and the members' jitter against one another in full.
    """
    return positions - neighbours.mean(dim=2)


def velocity_loss(
    positions: torch.Tensor,
    quats: torch.Tensor | None = None,
    stride: int = 1,
    time_reduction: str = "sum",
) -> torch.Tensor:
    """L_vel = sum_t |mu_{t+s} - mu_t| + theta(R_t R_{t+s}^-1) (mean over Gaussians). See
    `smoothness_terms`."""
    t = smoothness_terms(positions, quats, stride, time_reduction)
    return t["pos_vel"] + t["rot_vel"]


def acceleration_loss(
    positions: torch.Tensor,
    quats: torch.Tensor | None = None,
    stride: int = 1,
    time_reduction: str = "sum",
) -> torch.Tensor:
    """L_acc = sum_t |mu_t - 2 mu_{t+s} + mu_{t+2s}| + |theta_t - theta_{t+s}| (mean over
    Gaussians)."""
    t = smoothness_terms(positions, quats, stride, time_reduction)
    return t["pos_acc"] + t["rot_acc"]


def window_times(t: int, n_frames: int, half_width: int = 2) -> list[int]:
    """Frame indices of a window t - half_width .. t + half_width shifted to lie inside [0,
    n_frames).

    The authors evaluate velocity / acceleration on +-2 frames around the query time; the window
    keeps its length 2 * half_width + 1 near the ends of the clip (when n_frames allows)."""
    length = min(2 * half_width + 1, n_frames)
    start = min(max(t - half_width, 0), n_frames - length)
    return list(range(start, start + length))
