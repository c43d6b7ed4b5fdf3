"""Step 5 of the video-to-world transform (m4dgs.training.v2w): the world Gaussians' scales,
refitted so that their 2D covariances in every camera match the video Gaussians' (`refit_scales`).
Both sides are computed by the rasterizer's own projection (m4dgs.raster.projection), so the
tan-fov clamp and the 0.3 px^2 dilation are exactly the rasterizer's (orthographic for the video
Gaussians, the pinhole EWA Jacobian for the world ones)."""

from __future__ import annotations

from typing import Any, Dict, Tuple

import numpy as np
import torch

from m4dgs.model.gaussians import scale_activation, scale_inverse
from m4dgs.raster.projection import intrinsics_ortho, project_gaussians

Tensor = torch.Tensor


def _as_tensor(x, like: Tensor) -> Tensor:
    if isinstance(x, np.ndarray):
        x = torch.from_numpy(x)
    return torch.as_tensor(x).to(device=like.device, dtype=like.dtype)


# --------------------------------------------------------------------------------------------------
# 2D covariances (through the rasterizer's projection code)
# --------------------------------------------------------------------------------------------------
def _project_cov2d(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    K: Tensor,
    width: int,
    height: int,
    camera_model: str,
) -> Tuple[Tensor, Tensor]:
    """cov2d [M, 2, 2] (with the rasterizer's dilation) and pixel means [M, 2] of camera-space
    Gaussians."""
    eye = torch.eye(4, dtype=means.dtype, device=means.device)
    ones = torch.ones(means.shape[0], dtype=means.dtype, device=means.device)
    proj = project_gaussians(
        means, quats, scales, ones, eye, K, width, height, camera_model=camera_model
    )
    return proj.cov2d, proj.means2d


def video_cov2d(
    positions_video: Tensor,
    quats_video: Tensor,
    scales_video: Tensor,
    width: int,
    height: int,
    chunk: int = 1 << 20,
) -> Tensor:
    """Sigma'^v_t: orthographic 2D covariance (J_ortho, W^v = identity) of video Gaussians at each
    frame.

    Args:
        positions_video: [N, T, 3]; quats_video: [N, T, 4]; scales_video: [N, 3] activated (standard
        deviations).
    Returns:
        [N, T, 2, 2] pixel^2 (includes the rasterizer's 0.3 px^2 dilation).
    """
    n, t_count, _ = positions_video.shape
    K = intrinsics_ortho(width, height, dtype=positions_video.dtype, device=positions_video.device)
    means = positions_video.reshape(-1, 3)
    quats = quats_video.reshape(-1, 4)
    scales = scales_video[:, None].expand(n, t_count, 3).reshape(-1, 3)
    out = []
    for s in range(0, means.shape[0], chunk):
        cov, _ = _project_cov2d(
            means[s : s + chunk],
            quats[s : s + chunk],
            scales[s : s + chunk],
            K,
            width,
            height,
            "ortho",
        )
        out.append(cov)
    cov = torch.cat(out) if out else positions_video.new_zeros(0, 2, 2)
    return cov.reshape(n, t_count, 2, 2)


def pinhole_cov2d(
    means_cam: Tensor,
    quats_cam: Tensor,
    scales: Tensor,
    K: Tensor,
    width: int,
    height: int,
    chunk: int = 1 << 20,
) -> Tuple[Tensor, Tensor]:
    """Sigma'^w_t: pinhole EWA 2D covariance of Gaussians given in camera coordinates.

    Args:
        means_cam: [N, T, 3]; quats_cam: [N, T, 4] (camera-frame rotations R_t^-1 R^w); scales: [N,
        3] activated.
    Returns:
        (cov2d [N, T, 2, 2], means2d [N, T, 2] pixels).
    """
    n, t_count, _ = means_cam.shape
    K = _as_tensor(K, means_cam)
    means = means_cam.reshape(-1, 3)
    quats = quats_cam.reshape(-1, 4)
    sc = scales[:, None].expand(n, t_count, 3).reshape(-1, 3)
    covs, mus = [], []
    for s in range(0, means.shape[0], chunk):
        cov, mu = _project_cov2d(
            means[s : s + chunk],
            quats[s : s + chunk],
            sc[s : s + chunk],
            K,
            width,
            height,
            "pinhole",
        )
        covs.append(cov)
        mus.append(mu)
    if not covs:
        return means_cam.new_zeros(n, t_count, 2, 2), means_cam.new_zeros(n, t_count, 2)
    return torch.cat(covs).reshape(n, t_count, 2, 2), torch.cat(mus).reshape(n, t_count, 2)


def cov2d_fit_error(
    target_cov2d: Tensor,
    means_cam: Tensor,
    quats_cam: Tensor,
    valid: Tensor,
    scales: Tensor,
    K: Tensor,
    width: int,
    height: int,
) -> Dict[str, Tensor]:
    """Per-Gaussian mismatch of the world 2D covariances against the video ones over the valid
    frames.

    Returns:
        {"l1": [N] mean over valid frames of sum |Sigma^v - Sigma^w| (px^2), "rel": [N] mean of
        ||Sigma^v - Sigma^w||_F / ||Sigma^v||_F, "count": [N] valid frames}; 0 where a Gaussian has
        none.
    """
    with torch.no_grad():
        cov, _ = pinhole_cov2d(means_cam, quats_cam, scales, K, width, height)
        diff = cov - target_cov2d
        w = valid.to(cov.dtype)
        cnt = w.sum(1)
        l1 = (diff.abs().sum((-1, -2)) * w).sum(1) / cnt.clamp_min(1)
        rel = (
            diff.flatten(-2).norm(dim=-1)
            / target_cov2d.flatten(-2).norm(dim=-1).clamp_min(1e-12)
            * w
        ).sum(1)
        rel = rel / cnt.clamp_min(1)
    return {"l1": l1, "rel": rel, "count": cnt}


def refit_scales(
    target_cov2d: Tensor,
    means_cam: Tensor,
    quats_cam: Tensor,
    valid: Tensor,
    K: Tensor,
    width: int,
    height: int,
    init_scales: Tensor,
    *,
    scale_kind: str = "exp",
    scale_max: float = 1.0,
    steps: int = 1000,
    lr: float = 0.1,
    lr_final_ratio: float = 0.01,
    frames_per_step: int = 1,
    seed: int = 0,
) -> Tuple[Tensor, Dict[str, Any]]:
    """World scales by 2D covariance invariance: min_{S^w} sum_t || Sigma'^v_t - Sigma'^w_t ||_1
    (paper sec. 3.3.2).

    Adam over the raw world scale parameters (log-scales for the "exp" activation), vectorised over
    Gaussians. Each step draws, per Gaussian, `frames_per_step` frames uniformly among its valid
    frames (the authors draw one random frame per step for all Gaussians; drawing per Gaussian only
    over its valid frames never wastes a step on a frame where it is off-screen) and takes the L1
    distance of the 2x2 covariances (sum of the 4 entries' absolute differences). The learning rate
    decays exponentially from `lr` to `lr * lr_final_ratio` over the steps, so the stochastic frame
    choice does not leave the scales jittering by ~lr (in log units) at the end.

    Args:
        target_cov2d: [N, T, 2, 2] video 2D covariances (`video_cov2d`). means_cam: [N, T, 3],
        quats_cam: [N, T, 4]: the world Gaussians in each camera (`world_to_cameras`). valid: [N, T]
        bool frames that enter the objective (in front of camera t and inside the image). K: [3, 3]
        pinhole intrinsics. init_scales: [N, 3] activated initial world scales. scale_kind /
        scale_max: the world scale activation (`m4dgs.model.gaussians.scale_activation`).
    Returns:
        (raw world scales [N, 3] (Gaussians without a valid frame keep their initial scales), info
        with "loss_l1" (mean over Gaussians with frames of the per-frame L1, px^2), "rel_err" (mean
        relative Frobenius error), "loss_l1_init", "rel_err_init", "num_fitted", "steps").
    """
    n, t_count = valid.shape
    K = _as_tensor(K, means_cam)
    raw0 = scale_inverse(init_scales.detach().to(means_cam.dtype), scale_kind, scale_max)
    valid = valid.to(torch.bool)
    has = valid.any(1)
    rows = torch.where(has)[0]
    target = target_cov2d.detach()
    before = cov2d_fit_error(
        target, means_cam, quats_cam, valid, init_scales.to(means_cam.dtype), K, width, height
    )
    raw_out = raw0.clone()
    if rows.numel() > 0 and steps > 0:
        raw = raw0[rows].clone().requires_grad_(True)
        opt = torch.optim.Adam([raw], lr=lr)
        gamma = lr_final_ratio ** (1.0 / max(steps - 1, 1)) if lr_final_ratio > 0 else 1.0
        sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma=gamma)
        gen = torch.Generator(device=means_cam.device)
        gen.manual_seed(int(seed))
        v_rows = valid[rows]
        cums = v_rows.long().cumsum(1)  # [n, T]
        count = cums[:, -1:]  # [n, 1]
        b = max(int(frames_per_step), 1)
        m_rows, q_rows, tgt_rows = means_cam[rows], quats_cam[rows], target[rows]
        ar = torch.arange(rows.numel(), device=means_cam.device)[:, None]
        for _ in range(steps):
            u = torch.rand(
                rows.numel(), b, generator=gen, device=means_cam.device, dtype=torch.float64
            )
            k = (u * count).floor().long().clamp_max(count - 1) + 1  # k-th valid frame, 1-based
            idx = torch.searchsorted(cums, k)  # first frame whose cumulative count reaches k
            m = m_rows[ar, idx].reshape(-1, 3)
            q = q_rows[ar, idx].reshape(-1, 4)
            tg = tgt_rows[ar, idx]  # [n, b, 2, 2]
            s = (
                scale_activation(raw, scale_kind, scale_max)[:, None]
                .expand(-1, b, -1)
                .reshape(-1, 3)
            )
            cov, _ = _project_cov2d(m, q, s, K, width, height, "pinhole")
            loss = (cov.reshape(-1, b, 2, 2) - tg).abs().sum((-1, -2)).mean(1).sum()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
        raw_out[rows] = raw.detach()
    after = cov2d_fit_error(
        target,
        means_cam,
        quats_cam,
        valid,
        scale_activation(raw_out, scale_kind, scale_max),
        K,
        width,
        height,
    )

    def _mean(x: Tensor) -> float:
        return float(x[has].mean()) if rows.numel() else 0.0

    info = {
        "loss_l1": _mean(after["l1"]),
        "rel_err": _mean(after["rel"]),
        "loss_l1_init": _mean(before["l1"]),
        "rel_err_init": _mean(before["rel"]),
        "num_fitted": int(rows.numel()),
        "steps": int(steps),
    }
    return raw_out, info
