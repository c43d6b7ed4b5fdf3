"""EWA projection of 3D Gaussians to the image plane (vectorised torch, differentiable).

Follows gsplat's numerical conventions (``fully_fused_projection``), so every backend agrees:

- quaternions are (w, x, y, z), normalised here (unnormalised input is fine);
- ``scales`` are the actual standard deviations (not log);
- 2D covariance ``J W Sigma W^T J^T + eps2d * I`` with ``eps2d = 0.3`` (pixels^2);
- pinhole ``J = [[fx/z, 0, -fx x/z^2], [0, fy/z, -fy y/z^2]]`` with x/z, y/z clamped to the field of
  view widened by 30 % (only inside J; the projected mean is not clamped);
- orthographic ``u = fx x + cx``, ``v = fy y + cy``, ``J = [[fx, 0, 0], [0, fy, 0]]`` (the paper's
  J_ortho);
- depth is camera-space z; Gaussians with z outside ``[near_plane, far_plane]``, a non-positive 2D
  determinant, opacity below 1/255 or a footprint entirely off the image are culled (radii 0);
- opacity-aware extent: ``extend = min(3.33, sqrt(2 log(255 opacity)))``, per-axis radius
  ``ceil(extend * sqrt(cov2d_ii))``: exactly the box where ``opacity * G >= 1/255``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import torch
from torch import Tensor

from m4dgs.core.camera import quat_to_rotmat as _camera_quat_to_rotmat

ALPHA_THRESHOLD = 1.0 / 255.0  # contributions below this are skipped (gsplat's ALPHA_THRESHOLD)
EPS2D = 0.3  # 2D covariance dilation in pixels^2 (gsplat default)
NEAR_PLANE = 0.01
FAR_PLANE = 1e10
MAX_EXTEND = 3.33  # cap on the footprint in standard deviations (gsplat)
CAMERA_MODELS = ("pinhole", "ortho")


@dataclass
class Projection:
    """Per-Gaussian screen-space quantities for one camera (N Gaussians).

    means_cam: [N, 3] camera-space means (None from the fused cpu projection). means2d: [N, 2] pixel
    coordinates (pixel centres at +0.5). cov2d: [N, 2, 2] dilated 2D covariance.  conics: [N, 3]
    (inv00, inv01, inv11) of ``cov2d``. depths: [N] camera z.  radii: [N, 2] int32 per-axis pixel
    radius, 0 when culled.  visible: [N] bool."""

    means_cam: Optional[Tensor]
    means2d: Tensor
    cov2d: Tensor
    conics: Tensor
    depths: Tensor
    radii: Tensor
    visible: Tensor


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """Rotation matrices [N, 3, 3] from quaternions [N, 4] (w, x, y, z), normalised
    (m4dgs.core.camera's convention)."""
    return _camera_quat_to_rotmat(quats)


def covariance_3d(quats: Tensor, scales: Tensor) -> Tensor:
    """World covariances [N, 3, 3] = R S S R^T from quats [N, 4] and scales [N, 3]."""
    m = quat_to_rotmat(quats) * scales[:, None, :]
    return m @ m.transpose(-1, -2)


def _check_camera(viewmat: Tensor, K: Tensor, camera_model: str) -> None:
    if camera_model not in CAMERA_MODELS:
        raise ValueError(f"camera_model must be one of {CAMERA_MODELS}, got {camera_model!r}")
    if tuple(viewmat.shape) != (4, 4):
        raise ValueError(f"viewmat must be [4, 4] (world-to-camera), got {tuple(viewmat.shape)}")
    if tuple(K.shape) != (3, 3):
        raise ValueError(f"K must be [3, 3], got {tuple(K.shape)}")


def project_gaussians(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    camera_model: str = "pinhole",
    eps2d: float = EPS2D,
    near_plane: float = NEAR_PLANE,
    far_plane: float = FAR_PLANE,
) -> Projection:
    """Project Gaussians (means [N, 3], quats [N, 4], scales [N, 3], opacities [N]) with a
    world-to-camera ``viewmat`` [4, 4] and intrinsics ``K`` [3, 3] onto a ``width`` x ``height``
    image.

    Differentiable w.r.t. means, quats, scales, viewmat and K (radii / culling are not
    differentiable)."""
    _check_camera(viewmat, K, camera_model)
    dtype = means.dtype
    viewmat = viewmat.to(dtype)
    K = K.to(dtype)
    R = viewmat[:3, :3]
    t = viewmat[:3, 3]
    n = means.shape[0]
    means_cam = means @ R.T + t  # [N, 3]
    # camera-space square root of the covariance, Sigma_c = Mc Mc^T with Mc = R_view R(q) S;
    # computed as one [3N, 3] x [3, 3] product on Mc^T (batched 3x3 matmuls are slow on the CPU)
    M = quat_to_rotmat(quats) * scales[:, None, :]  # [N, 3, 3]
    McT = (M.transpose(1, 2).reshape(n * 3, 3) @ R.T).reshape(n, 3, 3)  # McT[n, j, i] = Mc[n, i, j]
    mc0, mc1, mc2 = McT[:, :, 0], McT[:, :, 1], McT[:, :, 2]  # rows of Mc, each [N, 3]

    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    x, y, z = means_cam.unbind(-1)
    in_depth = (z >= near_plane) & (z <= far_plane)
    if camera_model == "pinhole":
        # culled anyway; keeps gradients finite
        z_safe = torch.where(in_depth, z, torch.ones_like(z))
        tan_fovx = 0.5 * width / fx
        tan_fovy = 0.5 * height / fy
        lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx
        lim_x_neg = cx / fx + 0.3 * tan_fovx
        lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy
        lim_y_neg = cy / fy + 0.3 * tan_fovy
        inv_z = 1.0 / z_safe
        # J = [[fx/z, 0, -fx tx/z^2], [0, fy/z, -fy ty/z^2]] with tx/z, ty/z clamped to the widened
        # fov
        ux = torch.minimum(torch.maximum(x * inv_z, -lim_x_neg), lim_x_pos)
        uy = torch.minimum(torch.maximum(y * inv_z, -lim_y_neg), lim_y_pos)
        j00, j02 = fx * inv_z, -fx * ux * inv_z
        j11, j12 = fy * inv_z, -fy * uy * inv_z
        T0 = j00[:, None] * mc0 + j02[:, None] * mc2  # rows of J Mc, [N, 3]
        T1 = j11[:, None] * mc1 + j12[:, None] * mc2
        means2d = torch.stack([fx * x * inv_z + cx, fy * y * inv_z + cy], dim=-1)
    else:  # ortho: J = [[fx, 0, 0], [0, fy, 0]]
        T0 = fx * mc0
        T1 = fy * mc1
        means2d = torch.stack([fx * x + cx, fy * y + cy], dim=-1)

    a = (T0 * T0).sum(-1) + eps2d
    b = (T0 * T1).sum(-1)
    c = (T1 * T1).sum(-1) + eps2d
    cov2d = torch.stack([a, b, b, c], dim=-1).reshape(n, 2, 2)
    det = a * c - b * b
    det_safe = torch.where(det > 0, det, torch.ones_like(det))
    conics = torch.stack([c / det_safe, -b / det_safe, a / det_safe], dim=-1)

    radii, visible = footprint_radii(
        means2d, a, c, det, z, opacities, width, height, near_plane, far_plane
    )
    return Projection(means_cam, means2d, cov2d, conics, z, radii, visible)


@torch.no_grad()
def footprint_radii(
    means2d: Tensor,
    a: Tensor,
    c: Tensor,
    det: Tensor,
    depths: Tensor,
    opacities: Tensor,
    width: int,
    height: int,
    near_plane: float = NEAR_PLANE,
    far_plane: float = FAR_PLANE,
) -> tuple[Tensor, Tensor]:
    """Opacity-aware per-axis radii [N, 2] int32 (0 = culled) and visibility [N] from the dilated 2D
    covariance diagonal (a, c) [N], its determinant [N], depths [N] and opacities [N]."""
    op = opacities.detach().to(a.dtype)
    a, c, det, depths, m2 = a.detach(), c.detach(), det.detach(), depths.detach(), means2d.detach()
    extend = torch.sqrt(2.0 * torch.log(op.clamp_min(ALPHA_THRESHOLD) / ALPHA_THRESHOLD)).clamp_max(
        MAX_EXTEND
    )
    rx = torch.ceil(extend * torch.sqrt(a.clamp_min(0)))
    ry = torch.ceil(extend * torch.sqrt(c.clamp_min(0)))
    in_depth = (depths >= near_plane) & (depths <= far_plane)
    valid = in_depth & (det > 0) & (op >= ALPHA_THRESHOLD) & ((rx > 0) | (ry > 0))
    inside = (
        (m2[:, 0] + rx > 0)
        & (m2[:, 0] - rx < width)
        & (m2[:, 1] + ry > 0)
        & (m2[:, 1] - ry < height)
    )
    visible = valid & inside
    radii = torch.stack([rx, ry], dim=-1).to(torch.int32) * visible[:, None]
    return radii.to(torch.int32), visible


def intrinsics_ortho(width: int, height: int, dtype=torch.float32, device=None) -> Tensor:
    """K = [[W/2, 0, W/2], [0, H/2, H/2], [0, 0, 1]]: maps normalised video coordinates x, y in [-1,
    1] to the pixel range [0, W] x [0, H] under the ``ortho`` camera."""
    return torch.tensor(
        [[width / 2.0, 0.0, width / 2.0], [0.0, height / 2.0, height / 2.0], [0.0, 0.0, 1.0]],
        dtype=dtype,
        device=device,
    )


def tile_grid(width: int, height: int, tile_size: int) -> tuple[int, int]:
    """(tiles_x, tiles_y) covering the image."""
    return math.ceil(width / tile_size), math.ceil(height / tile_size)
