"""Camera conventions, in one place (the clip format's, docs/clip-format.md; cameras in
docs/cameras.md).

- OpenCV camera frame: x right, y down, z forward. Extrinsics are camera-to-world 4x4 matrices
  (`c2w`), so a camera-space point p_c maps to the world as p_w = R p_c + T with [R | T] = c2w[:3]
  (the paper's mu_w = R_t pi^-1(mu_v) + T_t, section 3.3.2).
- Intrinsics K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels; continuous pixel coordinates with
  pixel centres at integer + 0.5, so pixel (i, j) (column, row) covers [i, i+1) x [j, j+1) and its
  centre is (i+0.5, j+0.5).
- Depth is z-depth along the optical axis.
- Video (orthographic) space of stage 1 (paper appendix "Video Gaussian Representation"): x, y in
  [-1, 1] are the normalised image coordinates, u = (x + 1) * W / 2, v = (y + 1) * H / 2 (continuous
  pixels), z = depth. The matching rasterizer camera is orthographic with K_ortho = [[W/2, 0, W/2],
  [0, H/2, H/2], [0, 0, 1]], whose projection Jacobian is the paper's J_ortho = [[W/2, 0, 0], [0,
  H/2, 0]].
- Quaternions are (w, x, y, z), Hamilton convention, rotating column vectors.

All functions accept torch tensors (batched over leading dims, differentiable) and numpy arrays
(converted, returned as numpy)."""

from __future__ import annotations

from typing import Dict, Tuple

import numpy as np
import torch


def _as_torch(x, dtype=None):
    if isinstance(x, torch.Tensor):
        return x, False
    t = torch.as_tensor(np.asarray(x), dtype=dtype or torch.float64)
    return t, True


def _ret(x: torch.Tensor, was_numpy: bool):
    return x.detach().cpu().numpy() if was_numpy else x


# --------------------------------------------------------------------------------------------------
# Quaternions and rotations
# --------------------------------------------------------------------------------------------------
def quat_normalize(q):
    """Unit quaternion [..., 4] (w, x, y, z)."""
    t, np_in = _as_torch(q)
    return _ret(t / t.norm(dim=-1, keepdim=True).clamp_min(1e-12), np_in)


def quat_to_rotmat(q):
    """Rotation matrix [..., 3, 3] from a (not necessarily unit) quaternion [..., 4] (w, x, y,
    z)."""
    t, np_in = _as_torch(q)
    t = t / t.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = t.unbind(-1)
    r = torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    )
    return _ret(r.reshape(*t.shape[:-1], 3, 3), np_in)


def rotmat_to_quat(R):
    """Unit quaternion [..., 4] (w, x, y, z) with w >= 0 from a rotation matrix [..., 3, 3].

    Uses the numerically stable branch selection (largest of w, x, y, z computed from the diagonal).
    """
    t, np_in = _as_torch(R)
    m = t.reshape(-1, 3, 3)
    m00, m11, m22 = m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]
    cand = torch.stack(
        [
            1 + m00 + m11 + m22,
            1 + m00 - m11 - m22,
            1 - m00 + m11 - m22,
            1 - m00 - m11 + m22,
        ],
        dim=-1,
    )
    # each candidate row gives the quaternion scaled by 4 * component
    qs = torch.stack(
        [
            torch.stack(
                [
                    cand[:, 0],
                    m[:, 2, 1] - m[:, 1, 2],
                    m[:, 0, 2] - m[:, 2, 0],
                    m[:, 1, 0] - m[:, 0, 1],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[:, 2, 1] - m[:, 1, 2],
                    cand[:, 1],
                    m[:, 1, 0] + m[:, 0, 1],
                    m[:, 0, 2] + m[:, 2, 0],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[:, 0, 2] - m[:, 2, 0],
                    m[:, 1, 0] + m[:, 0, 1],
                    cand[:, 2],
                    m[:, 2, 1] + m[:, 1, 2],
                ],
                -1,
            ),
            torch.stack(
                [
                    m[:, 1, 0] - m[:, 0, 1],
                    m[:, 0, 2] + m[:, 2, 0],
                    m[:, 2, 1] + m[:, 1, 2],
                    cand[:, 3],
                ],
                -1,
            ),
        ],
        dim=1,
    )  # [B, 4 branches, 4]
    best = cand.argmax(dim=-1)
    q = qs[torch.arange(m.shape[0], device=qs.device), best]
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    q = torch.where(q[:, :1] < 0, -q, q)
    return _ret(q.reshape(*t.shape[:-2], 4), np_in)


def quat_multiply(a, b):
    """Hamilton product a * b of quaternions [..., 4] (w, x, y, z)."""
    ta, np_in = _as_torch(a)
    tb, _ = _as_torch(b, ta.dtype)
    aw, ax, ay, az = ta.unbind(-1)
    bw, bx, by, bz = tb.unbind(-1)
    out = torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )
    return _ret(out, np_in)


def slerp(q0, q1, s):
    """Spherical linear interpolation between unit quaternions q0, q1 [..., 4] at fraction s (scalar
    or [...]).

    Takes the short arc (q1 is sign-flipped when <q0, q1> < 0); falls back to normalised lerp for
    nearly equal inputs."""
    t0, np_in = _as_torch(q0)
    t1, _ = _as_torch(q1, t0.dtype)
    s_t = torch.as_tensor(s, dtype=t0.dtype, device=t0.device)
    if s_t.dim() > 0:
        s_t = s_t[..., None]
    t0 = t0 / t0.norm(dim=-1, keepdim=True)
    t1 = t1 / t1.norm(dim=-1, keepdim=True)
    d = (t0 * t1).sum(-1, keepdim=True)
    t1 = torch.where(d < 0, -t1, t1)
    d = d.abs().clamp(max=1.0)
    theta = torch.arccos(d)
    sin_t = torch.sin(theta)
    small = sin_t < 1e-6
    w0 = torch.where(
        small,
        1 - s_t,
        torch.sin((1 - s_t) * theta) / torch.where(small, torch.ones_like(sin_t), sin_t),
    )
    w1 = torch.where(
        small,
        s_t.expand_as(sin_t),
        torch.sin(s_t * theta) / torch.where(small, torch.ones_like(sin_t), sin_t),
    )
    q = w0 * t0 + w1 * t1
    return _ret(q / q.norm(dim=-1, keepdim=True), np_in)


# --------------------------------------------------------------------------------------------------
# Extrinsics
# --------------------------------------------------------------------------------------------------
def make_c2w(R, T):
    """4x4 camera-to-world [..., 4, 4] from rotation [..., 3, 3] and camera centre [..., 3]."""
    tR, np_in = _as_torch(R)
    tT, _ = _as_torch(T, tR.dtype)
    top = torch.cat([tR, tT[..., None]], dim=-1)
    bottom = torch.zeros(*tR.shape[:-2], 1, 4, dtype=tR.dtype, device=tR.device)
    bottom[..., 0, 3] = 1
    return _ret(torch.cat([top, bottom], dim=-2), np_in)


def invert_rigid(M):
    """Inverse of rigid 4x4 transforms [..., 4, 4] (c2w <-> w2c) without a general matrix
    inverse."""
    t, np_in = _as_torch(M)
    R = t[..., :3, :3]
    T = t[..., :3, 3]
    Rt = R.transpose(-1, -2)
    return _ret(make_c2w(Rt, -(Rt @ T[..., None])[..., 0]), np_in)


c2w_to_w2c = invert_rigid
w2c_to_c2w = invert_rigid


def transform_points(M, p):
    """Apply 4x4 transforms [..., 4, 4] to points [..., 3] (broadcasting)."""
    tM, np_in = _as_torch(M)
    tp, _ = _as_torch(p, tM.dtype)
    # einsum: one [P, 3] x [3, 3] product for one transform and an image of points, where the
    # broadcast `R @ p[..., None]` ran one 3x3 matrix-vector product per point (~2x slower)
    return _ret(torch.einsum("...ij,...j->...i", tM[..., :3, :3], tp) + tM[..., :3, 3], np_in)


def interpolate_pose(c2w0, c2w1, s):
    """Pose between two cameras: rotation by slerp, centre by lerp, at fraction s in [0, 1]. [...,
    4, 4]."""
    t0, np_in = _as_torch(c2w0)
    t1, _ = _as_torch(c2w1, t0.dtype)
    q = slerp(rotmat_to_quat(t0[..., :3, :3]), rotmat_to_quat(t1[..., :3, :3]), s)
    s_t = torch.as_tensor(s, dtype=t0.dtype, device=t0.device)
    if s_t.dim() > 0:
        s_t = s_t[..., None]
    T = (1 - s_t) * t0[..., :3, 3] + s_t * t1[..., :3, 3]
    return _ret(make_c2w(quat_to_rotmat(q), T), np_in)


def interpolate_trajectory(times_known, c2w_known, times_query):
    """Poses at query times from poses at sorted known times (piecewise slerp + lerp, clamped at the
    ends).

    Args:
        times_known: [K] increasing; c2w_known: [K, 4, 4]; times_query: [Q].
    Returns:
        [Q, 4, 4] camera-to-world poses.
    """
    tk, np_in = _as_torch(times_known)
    ck, _ = _as_torch(c2w_known, tk.dtype)
    tq, _ = _as_torch(times_query, tk.dtype)
    ck = ck.to(tk.dtype)
    if tk.numel() == 1:
        return _ret(ck[:1].expand(tq.shape[0], 4, 4).clone(), np_in)
    idx = torch.searchsorted(tk.contiguous(), tq.contiguous(), right=True).clamp(1, tk.numel() - 1)
    t_lo, t_hi = tk[idx - 1], tk[idx]
    s = ((tq - t_lo) / (t_hi - t_lo)).clamp(0.0, 1.0)
    return _ret(interpolate_pose(ck[idx - 1], ck[idx], s), np_in)


# --------------------------------------------------------------------------------------------------
# Intrinsics and projection
# --------------------------------------------------------------------------------------------------
def make_K(fx, fy, cx, cy):
    """3x3 intrinsics (float64 numpy)."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float64)


def K_from_fov(width: int, height: int, fov_x_deg: float) -> np.ndarray:
    """Pinhole intrinsics with square pixels, principal point at the image centre, horizontal field
    of view."""
    fx = (width / 2.0) / np.tan(np.deg2rad(fov_x_deg) / 2.0)
    return make_K(fx, fx, width / 2.0, height / 2.0)


def K_ortho(width: int, height: int) -> np.ndarray:
    """Orthographic 'intrinsics' of video space: u = W/2 x + W/2, v = H/2 y + H/2 (paper's
    J_ortho)."""
    return make_K(width / 2.0, height / 2.0, width / 2.0, height / 2.0)


def project_pinhole(points_cam, K):
    """Continuous pixel coordinates [..., 2] of camera-space points [..., 3] (z > 0), u = fx x / z +
    cx."""
    tp, np_in = _as_torch(points_cam)
    tK, _ = _as_torch(K, tp.dtype)
    tK = tK.to(tp)
    z = tp[..., 2]
    u = tK[..., 0, 0] * tp[..., 0] / z + tK[..., 0, 2]
    v = tK[..., 1, 1] * tp[..., 1] / z + tK[..., 1, 2]
    return _ret(torch.stack([u, v], dim=-1), np_in)


def unproject_pinhole(uv, depth, K):
    """Camera-space points [..., 3] from continuous pixel coordinates [..., 2] and z-depth [...]."""
    tu, np_in = _as_torch(uv)
    td, _ = _as_torch(depth, tu.dtype)
    tK, _ = _as_torch(K, tu.dtype)
    tK, td = tK.to(tu), td.to(tu)
    x = (tu[..., 0] - tK[..., 0, 2]) / tK[..., 0, 0] * td
    y = (tu[..., 1] - tK[..., 1, 2]) / tK[..., 1, 1] * td
    return _ret(torch.stack([x, y, td], dim=-1), np_in)


def pixel_centers(width: int, height: int, *, dtype=torch.float32, device=None) -> torch.Tensor:
    """[H, W, 2] continuous (u, v) coordinates of the pixel centres (i + 0.5, j + 0.5)."""
    ys, xs = torch.meshgrid(
        torch.arange(height, dtype=dtype, device=device) + 0.5,
        torch.arange(width, dtype=dtype, device=device) + 0.5,
        indexing="ij",
    )
    return torch.stack([xs, ys], dim=-1)


def pixel_to_ortho(uv, width: int, height: int):
    """Video-space (x, y) in [-1, 1] [..., 2] from continuous pixel coordinates [..., 2]."""
    t, np_in = _as_torch(uv)
    scale = torch.tensor([2.0 / width, 2.0 / height], dtype=t.dtype, device=t.device)
    return _ret(t * scale - 1.0, np_in)


def ortho_to_pixel(xy, width: int, height: int):
    """Continuous pixel coordinates [..., 2] from video-space (x, y) [..., 2]: u = (x + 1) W / 2."""
    t, np_in = _as_torch(xy)
    scale = torch.tensor([width / 2.0, height / 2.0], dtype=t.dtype, device=t.device)
    return _ret((t + 1.0) * scale, np_in)


def video_to_camera(points_video, K, width: int, height: int):
    """Camera-space points [..., 3] from video-space points (x, y in [-1, 1], z = depth) with
    pinhole K.

    pi_K^-1 of the paper (section 3.3.2): the video point's pixel is unprojected at its depth.
    """
    tp, np_in = _as_torch(points_video)
    uv = ortho_to_pixel(tp[..., :2], width, height)
    return _ret(unproject_pinhole(uv, tp[..., 2], K), np_in)


def camera_to_video(points_cam, K, width: int, height: int):
    """Video-space points [..., 3] (x, y in [-1, 1], z = depth) from camera-space points [...,
    3]."""
    tp, np_in = _as_torch(points_cam)
    uv = project_pinhole(tp, K)
    xy = pixel_to_ortho(uv, width, height)
    return _ret(torch.cat([xy, tp[..., 2:3]], dim=-1), np_in)


# --------------------------------------------------------------------------------------------------
# Similarity alignment (trajectory evaluation, BA initialisation)
# --------------------------------------------------------------------------------------------------
def umeyama_sim3(src, dst, with_scale: bool = True, weights=None) -> Tuple:
    """Least-squares similarity transform s, R, t minimising sum_i w_i |s R src_i + t - dst_i|^2
    (Umeyama 1991).

    Args:
        src, dst: [N, 3] corresponding points (N >= 3, not collinear for a unique rotation).
        with_scale: if False, s = 1 (rigid alignment).
        weights: optional [N] non-negative weights.
    Returns:
        (s: scalar, R: [3, 3], t: [3]) in the input's type (numpy or torch).
    """
    ts, np_in = _as_torch(src)
    td, _ = _as_torch(dst, ts.dtype)
    td = td.to(ts)
    n = ts.shape[0]
    w = (
        torch.ones(n, dtype=ts.dtype, device=ts.device)
        if weights is None
        else _as_torch(weights, ts.dtype)[0].to(ts)
    )
    w = w / w.sum()
    mu_s = (w[:, None] * ts).sum(0)
    mu_d = (w[:, None] * td).sum(0)
    xs, xd = ts - mu_s, td - mu_d
    cov = (w[:, None, None] * xd[:, :, None] * xs[:, None, :]).sum(0)
    U, S, Vh = torch.linalg.svd(cov)
    D = torch.eye(3, dtype=ts.dtype, device=ts.device)
    if torch.det(U) * torch.det(Vh) < 0:
        D[2, 2] = -1
    R = U @ D @ Vh
    var_s = (w * (xs**2).sum(-1)).sum()
    s = (
        (S * D.diagonal()).sum() / var_s
        if with_scale
        else torch.ones((), dtype=ts.dtype, device=ts.device)
    )
    t = mu_d - s * (R @ mu_s)
    if np_in:
        return float(s), R.cpu().numpy(), t.cpu().numpy()
    return s, R, t


# a reconstruction's world frame against the truth's (held-out views, estimated-camera exports)
def align_to_truth(run_c2w: np.ndarray, gt_c2w: np.ndarray) -> Dict[str, object]:
    """{"s", "R" [3, 3], "t" [3], "rmse", "n"}: the similarity with s R c_run + t ~ c_gt over the
    centres of [N, 4, 4] camera-to-world matrices (N >= 3), and the RMSE of the aligned centres."""
    cr = np.asarray(run_c2w, np.float64)[:, :3, 3]
    cg = np.asarray(gt_c2w, np.float64)[:, :3, 3]
    if cr.shape != cg.shape or cr.shape[0] < 3:
        raise ValueError(
            f"align_to_truth: need [N >= 3] matching cameras, got {cr.shape}/{cg.shape}"
        )
    s, R, t = umeyama_sim3(cr, cg)
    s, R, t = float(s), np.asarray(R, np.float64), np.asarray(t, np.float64)
    rmse = float(np.sqrt(np.mean(np.sum((s * cr @ R.T + t - cg) ** 2, axis=1))))
    return {"s": s, "R": R, "t": t, "rmse": rmse, "n": int(cr.shape[0])}


def truth_to_run(c2w_gt: np.ndarray, s: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """[4, 4] camera-to-world, in a reconstruction's frame, of a camera given in the truth's, for
    the similarity c_gt ~ s R c_run + t of align_to_truth: rotation R^T R_gt, centre
    R^T (c_gt - t) / s (how a run is shown the held-out views, m4dgs.outputs.views)."""
    c2w_gt = np.asarray(c2w_gt, np.float64)
    out = np.eye(4)
    out[:3, :3] = R.T @ c2w_gt[:3, :3]
    out[:3, 3] = R.T @ (c2w_gt[:3, 3] - t) / s
    return out
