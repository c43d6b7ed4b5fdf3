"""Initial cameras from the priors alone, MoSca-style (paper section 3.2 "Prior Precompute": "we can
also conduct bundle adjustment using static tracklets to obtain initial camera parameters as in
MoSca").

Pipeline (`initialize_cameras`):
1. Static tracks: a track is static when it has >= `min_visible` visible samples with a valid depth
   and at most a fraction `max_dynamic_fraction` of them fall inside the dynamic masks
   (m4dgs.priors.epipolar). At most `max_static_tracks` of them (seeded random subset) enter the
   optimisation.
2. Lifting: the depth prior of each frame is sampled bilinearly at the track pixel (pixel centres at
   +0.5).
3. Field of view: a linear search over [fov_min_deg, fov_max_deg] (horizontal fov, square pixels,
   principal point at the image centre). For each candidate, the static points of frame pairs 10-20
   frames apart (scaled down for short clips) are unprojected, a weighted Procrustes Sim(3)
   (m4dgs.core.camera.umeyama_sim3, reweighted a few times with Cauchy weights of the reprojection
   error) maps frame i's points onto frame j's, and the score is the mean over pairs of the median
   reprojection error (pixels) of the aligned points in frame j. The best candidate is refined on a
   finer grid around it; if the curve is monotonic (best at an end of the range) the fov falls back
   to 45 deg.
4. Poses: chained from consecutive-frame Sim(3) solutions (the nearest earlier frame with enough
   common static points); the Sim(3) scale is absorbed into a per-frame depth scale. World = the
   first camera (identity).
5. Bundle adjustment (Adam, float32 by default): per-frame camera rotation (quaternion) and centre,
   a shared focal length (log), per-frame log depth scale and, after `depth_correction_start` steps,
   a per-observation log-depth correction. Each static track's world point is the mean of its lifted
   world points (over its visible frames); losses: robust (Cauchy or Huber) reprojection error of
   that point in every visible frame (pixels), symmetric depth-ratio consistency max(z/d, d/z) - 1
   between its depth in each frame and the lifted depth there, camera smoothness (second differences
   of centres and quaternions) and a small L2 on the depth correction. Gauge: the first camera is
   fixed to the identity and its depth scale to 1.

Units: internally the depths are divided by the median static depth (so learning rates are
scale-free); the result is returned in the depth prior's units with world = frame 0's camera, i.e.
metric depth of frame t in world units = depth_scale[t] * depth_prior[t]."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Dict, List, Literal, Optional, Tuple

import numpy as np
import torch

from m4dgs.clip import TrackSet
from m4dgs.core.camera import (
    K_from_fov,
    invert_rigid,
    make_c2w,
    project_pinhole,
    quat_to_rotmat,
    rotmat_to_quat,
    umeyama_sim3,
    unproject_pinhole,
)
from m4dgs.core.progress import progress_bar
from m4dgs.core.warp import sample_per_frame


@dataclass
class CameraInitConfig:
    """MoSca-style camera initialisation (paper section 3.2; MoSca's defaults per
    the authors' released code, which uses MoSca's camera initialisation)."""

    # -- static tracks
    min_visible: int = 2
    # visible samples inside the dynamic masks, at most this fraction
    max_dynamic_fraction: float = 0.1
    max_static_tracks: int = 4096
    # a lifted depth is used only when the bilinear and nearest samples of the depth map agree
    # within this relative tolerance (a bilinear sample straddling a depth edge lies in the air
    # between two surfaces)
    depth_edge_tolerance: float = 0.05
    # -- field-of-view search (MoSca: linear search 10-90 deg on pairs 10-20 frames apart; fallback
    # 45 deg)
    fov_min_deg: float = 10.0
    fov_max_deg: float = 90.0
    fov_step_deg: float = 2.0
    fov_refine: bool = True  # second pass on a grid of fov_step_deg / 8 around the best candidate
    fov_fallback_deg: float = 45.0
    fov: Optional[float] = None  # known horizontal fov (deg): skips the search
    pair_gap_min: int = 10
    pair_gap_max: int = 20
    num_fov_pairs: int = 32
    min_common_points: int = 8
    procrustes_irls_iters: int = 3
    procrustes_robust_px: float = 4.0
    # -- bundle adjustment (MoSca: ~2000 Adam steps; per-point depth correction after 500 steps)
    ba_steps: int = 2000
    lr_rotation: float = 1e-3  # quaternion components
    lr_translation: float = 1e-3  # camera centres, in units of the median static depth
    lr_focal: float = 1e-3  # log focal
    lr_depth_scale: float = 1e-3  # log per-frame depth scale
    lr_depth_correction: float = 1e-3  # log per-observation depth correction
    # exponential decay of every learning rate to this factor at the last step
    lr_final_factor: float = 0.1
    depth_correction_start: int = 500
    optimize_focal: bool = True
    w_reproj: float = 1.0
    w_depth: float = 1.0
    w_smooth: float = 0.1
    w_depth_correction: float = 0.1
    robust: Literal["cauchy", "huber"] = "cauchy"  # on the reprojection error
    reproj_focal_invariant: bool = False  # residuals x f0 / f instead of pixels (see bundle_adjust)
    robust_scale_px: float = 2.0
    log_every: int = 100
    # floating-point type of the bundle adjustment's parameters and residuals. float32: the same
    # cameras as float64 to the printed digits (focal, ATE, RPE on three small clips) and camera
    # initialisation 1.5-1.8x faster (bench/camera_init_bench.py, docs/performance.md)
    ba_dtype: Literal["float64", "float32"] = "float32"
    seed: int = 0
    # too few static tracks for the bundle adjustment: the trainer stops with an error (False) or
    # goes on with identity cameras and the fallback field of view (True; recorded in diagnostics)
    allow_fallback: bool = False
    # device of the bundle adjustment (the lifting, fov search and chaining are small and run on the
    # CPU); None: the device of depth_priors when it is a torch tensor, else the CPU
    device: Optional[str] = None

    @staticmethod
    def for_preset(preset: str) -> "CameraInitConfig":
        """Config for a run preset: fewer BA steps and static tracks for the quick presets (tiny /
        small)."""
        steps, tracks = {"tiny": (300, 1024), "small": (800, 2048)}.get(preset, (2000, 4096))
        return CameraInitConfig(
            ba_steps=steps, depth_correction_start=min(500, steps // 4), max_static_tracks=tracks
        )


@dataclass
class CameraInitResult:
    K: torch.Tensor  # [3, 3] float64
    c2w: torch.Tensor  # [T, 4, 4] float64, c2w[0] = identity
    depth_scale: torch.Tensor  # [T] float64: world depth = depth_scale[t] * depth_prior[t]
    static_track_mask: torch.Tensor  # [N] bool over the input tracks
    diagnostics: Dict = field(default_factory=dict)


# --------------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------------
def _t64(x) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x.detach().to(torch.float64).cpu()
    return torch.as_tensor(np.asarray(x), dtype=torch.float64)


def select_static_tracks(
    visible: torch.Tensor,
    in_dynamic: torch.Tensor,
    depth_ok: torch.Tensor,
    min_visible: int = 2,
    max_dynamic_fraction: float = 0.1,
) -> torch.Tensor:
    """[N] bool: tracks with >= min_visible usable samples and at most max_dynamic_fraction inside
    dynamic masks.

    visible, in_dynamic, depth_ok: [N, T] bool.
    """
    usable = visible & depth_ok
    n = usable.sum(1)
    nd = (usable & in_dynamic).sum(1)
    return (n >= min_visible) & (nd.to(torch.float64) <= max_dynamic_fraction * n.to(torch.float64))


def robust_sim3(
    src: torch.Tensor,
    dst: torch.Tensor,
    uv_dst: torch.Tensor,
    K: torch.Tensor,
    iters: int = 3,
    scale_px: float = 4.0,
    symmetric_scale: bool = True,
):
    """Sim(3) s R src + t ~ dst by Umeyama with Cauchy reweighting on the reprojection error in the
    dst frame.

    With symmetric_scale, s is the geometric mean of the forward scale and the inverse of the
    backward (dst -> src) scale: Umeyama's scale is biased low when src is noisy (regression
    dilution), which makes chained scales drift; the symmetric estimate cancels that to first order.
    src, dst: [M, 3] camera-space points of two frames; uv_dst: [M, 2] observed pixels in the dst
    frame. Returns (s, R [3, 3], t [3], reprojection errors [M] in pixels)."""
    w = torch.ones(src.shape[0], dtype=src.dtype)
    for _ in range(max(iters, 1)):
        s, R, t = umeyama_sim3(src, dst, with_scale=True, weights=w)
        if symmetric_scale:
            sb, _, _ = umeyama_sim3(dst, src, with_scale=True, weights=w)
            s = torch.sqrt(s / sb)
            wn = w / w.sum()
            t = (wn[:, None] * dst).sum(0) - s * (R @ (wn[:, None] * src).sum(0))
        p = s * src @ R.T + t
        z_ok = p[:, 2] > 1e-9
        uv = project_pinhole(torch.where(z_ok[:, None], p, torch.ones_like(p)), K)
        err = torch.where(z_ok, (uv - uv_dst).norm(dim=-1), torch.full_like(p[:, 0], 1e6))
        w = 1.0 / (1.0 + (err / scale_px) ** 2)
    return s, R, t, err


def _pair_gaps(T: int, cfg: CameraInitConfig) -> Tuple[int, int]:
    gmin = max(1, min(cfg.pair_gap_min, (T - 1) // 3))
    gmax = max(gmin, min(cfg.pair_gap_max, (T - 1) // 2))
    return gmin, gmax


def fov_pairs(usable: torch.Tensor, cfg: CameraInitConfig) -> List[Tuple[int, int]]:
    """Frame pairs (i, j), j - i in the (scaled) gap range, with >= min_common_points common static
    points.

    usable: [N, T] bool (static, visible, valid depth). At most cfg.num_fov_pairs pairs, spread over
    the clip."""
    T = usable.shape[1]
    if T < 2:
        return []
    gmin, gmax = _pair_gaps(T, cfg)
    rng = np.random.default_rng(cfg.seed)
    common = usable.T.to(torch.float64) @ usable.to(torch.float64)  # [T, T]
    pairs = []
    for i in range(T - 1):
        gaps = [
            g
            for g in range(gmin, gmax + 1)
            if i + g < T and common[i, i + g] >= cfg.min_common_points
        ]
        if not gaps:
            gaps = [g for g in range(1, T - i) if common[i, i + g] >= cfg.min_common_points][-1:]
        if gaps:
            pairs.append((i, i + int(rng.choice(gaps))))
    if len(pairs) > cfg.num_fov_pairs:
        sel = np.linspace(0, len(pairs) - 1, cfg.num_fov_pairs).round().astype(int)
        pairs = [pairs[k] for k in sel]
    return pairs


def umeyama_sim3_batched(src: torch.Tensor, dst: torch.Tensor, weights: torch.Tensor):
    """Batched weighted Umeyama: the same estimator as m4dgs.core.camera.umeyama_sim3, over leading
    batch dims.

    Used where thousands of small problems are solved (the fov search); tests check it against
    umeyama_sim3. Args:
        src, dst: [..., M, 3]; weights: [..., M] >= 0 (zero for padding).
    Returns:
        s [...], R [..., 3, 3], t [..., 3] minimising sum_i w_i |s R src_i + t - dst_i|^2.
    """
    w = weights / weights.sum(-1, keepdim=True).clamp_min(1e-300)
    mu_s = (w[..., None] * src).sum(-2)
    mu_d = (w[..., None] * dst).sum(-2)
    xs = src - mu_s[..., None, :]
    xd = dst - mu_d[..., None, :]
    cov = torch.einsum("...m,...mi,...mj->...ij", w, xd, xs)
    U, S, Vh = torch.linalg.svd(cov)
    sign = torch.sign(torch.det(U) * torch.det(Vh))
    sign = torch.where(sign == 0, torch.ones_like(sign), sign)
    D = torch.ones(*sign.shape, 3, dtype=src.dtype, device=src.device)
    D[..., 2] = sign
    R = U @ torch.diag_embed(D) @ Vh
    var_s = (w * (xs**2).sum(-1)).sum(-1)
    s = (S * D).sum(-1) / var_s.clamp_min(1e-300)
    t = mu_d - s[..., None] * (R @ mu_s[..., None])[..., 0]
    return s, R, t


def fov_scores(
    fovs,
    uv: torch.Tensor,
    depth: torch.Tensor,
    usable: torch.Tensor,
    pairs: List[Tuple[int, int]],
    width: int,
    height: int,
    cfg: CameraInitConfig,
) -> np.ndarray:
    """Score [F] of each candidate fov (deg): mean over pairs of the median reprojection error (px)
    after the pairwise robust (Cauchy-reweighted) Sim(3) of frame i's static points onto frame
    j's."""
    fovs = torch.as_tensor(np.asarray(fovs, np.float64))
    if not pairs:
        return np.full(fovs.shape[0], np.nan)
    P = len(pairs)
    masks = [usable[:, i] & usable[:, j] for i, j in pairs]
    M = max(int(m.sum()) for m in masks)
    uvi = torch.zeros(P, M, 2, dtype=torch.float64)
    uvj = torch.zeros(P, M, 2, dtype=torch.float64)
    di = torch.ones(P, M, dtype=torch.float64)
    dj = torch.ones(P, M, dtype=torch.float64)
    valid = torch.zeros(P, M, dtype=torch.bool)
    for p, ((i, j), m) in enumerate(zip(pairs, masks)):
        n = int(m.sum())
        uvi[p, :n], uvj[p, :n] = uv[m, i], uv[m, j]
        di[p, :n], dj[p, :n] = depth[m, i], depth[m, j]
        valid[p, :n] = True
    f = (width / 2.0) / torch.tan(torch.deg2rad(fovs) / 2.0)  # [F]
    c = torch.tensor([width / 2.0, height / 2.0], dtype=torch.float64)
    fb = f[:, None, None, None]

    def lift(uvx, d):
        xy = (uvx[None] - c) / fb * d[None, ..., None]
        # [F, P, M, 3]
        return torch.cat([xy, d[None, ..., None].expand(fovs.shape[0], P, M, 1)], -1)

    Xi, Xj = lift(uvi, di), lift(uvj, dj)
    w = valid.to(torch.float64)[None].expand(fovs.shape[0], P, M).clone()
    for _ in range(max(cfg.procrustes_irls_iters, 1)):
        s, R, t = umeyama_sim3_batched(Xi, Xj, w)
        p3 = s[..., None, None] * Xi @ R.transpose(-1, -2) + t[..., None, :]
        z = p3[..., 2]
        zs = torch.where(z > 1e-9, z, torch.ones_like(z))
        proj = fb * p3[..., :2] / zs[..., None] + c
        err = torch.where(z > 1e-9, (proj - uvj[None]).norm(dim=-1), torch.full_like(z, 1e6))
        w = valid[None] / (1.0 + (err / cfg.procrustes_robust_px) ** 2)
    err = torch.where(valid[None], err, torch.full_like(err, float("inf")))
    n = valid.sum(-1)  # [P]
    srt = err.sort(-1).values
    # lower median [F, P]
    med = srt.gather(-1, ((n - 1) // 2)[None, :, None].expand(fovs.shape[0], P, 1))[..., 0]
    return med.mean(-1).numpy()


def search_fov(uv, depth, usable, width, height, cfg: CameraInitConfig) -> Tuple[float, dict]:
    """Linear field-of-view search (degrees). Returns (fov, diagnostics with the score curve)."""
    pairs = fov_pairs(usable, cfg)
    diag = {"fov_pairs": pairs}
    if not pairs:
        diag.update(
            fov_candidates=[],
            fov_scores=[],
            fov_fallback=True,
            fov_reason="no frame pair with common points",
        )
        return cfg.fov_fallback_deg, diag
    cands = np.arange(cfg.fov_min_deg, cfg.fov_max_deg + 1e-9, cfg.fov_step_deg)
    scores = fov_scores(cands, uv, depth, usable, pairs, width, height, cfg)
    diag.update(fov_candidates=cands.tolist(), fov_scores=scores.tolist())
    if not np.isfinite(scores).any():
        diag.update(fov_fallback=True, fov_reason="no finite score")
        return cfg.fov_fallback_deg, diag
    fin = scores[np.isfinite(scores)]
    if fin.max() - fin.min() <= 1e-6 * fin.max() + 1e-9:
        diag.update(
            fov_fallback=True,
            fov_reason="flat score curve (no parallax to tell focal lengths apart)",
        )
        return cfg.fov_fallback_deg, diag
    k = int(np.nanargmin(scores))
    if k == 0 or k == len(cands) - 1:
        diag.update(
            fov_fallback=True, fov_reason="monotonic score curve (best at the end of the range)"
        )
        return cfg.fov_fallback_deg, diag
    best = float(cands[k])
    if cfg.fov_refine:
        fine = np.arange(cands[k - 1], cands[k + 1] + 1e-9, cfg.fov_step_deg / 8.0)
        fs = fov_scores(fine, uv, depth, usable, pairs, width, height, cfg)
        if np.isfinite(fs).any():
            best = float(fine[int(np.nanargmin(fs))])
        diag.update(fov_fine_candidates=fine.tolist(), fov_fine_scores=fs.tolist())
    diag.update(fov_fallback=False, fov_coarse=float(cands[k]))
    return best, diag


def chain_poses(uv, depth, usable, K, cfg: CameraInitConfig, max_back: int = 8):
    """Initial c2w [T, 4, 4] and depth scales [T] from consecutive-frame Sim(3) solutions (frame 0 =
    identity).

    For frame t the reference is the nearest earlier frame (at most max_back back) with >=
    min_common_points common points (else the one with the most, if >= 3); without any, frame t
    copies frame t-1's pose and scale."""
    T = uv.shape[1]
    w2c = [torch.eye(4, dtype=torch.float64)]
    sig = [1.0]
    info = []
    for t in range(1, T):
        best_k, best_n = None, 0
        for k in range(t - 1, max(-1, t - 1 - max_back), -1):
            n = int((usable[:, k] & usable[:, t]).sum())
            if n >= cfg.min_common_points:
                best_k, best_n = k, n
                break
            if n > best_n and n >= 3:
                best_k, best_n = k, n
        if best_k is None:
            w2c.append(w2c[-1].clone())
            sig.append(sig[-1])
            info.append((t, -1, 0))
            continue
        k = best_k
        m = usable[:, k] & usable[:, t]
        Xk = unproject_pinhole(uv[m, k], depth[m, k], K)
        Xt = unproject_pinhole(uv[m, t], depth[m, t], K)
        s, R, tr, _ = robust_sim3(
            Xk, Xt, uv[m, t], K, cfg.procrustes_irls_iters, cfg.procrustes_robust_px
        )
        s = float(s)
        rel = torch.eye(4, dtype=torch.float64)
        rel[:3, :3] = R
        rel[:3, 3] = sig[k] * tr / s
        w2c.append(rel @ w2c[k])
        sig.append(sig[k] / s)
        info.append((t, k, best_n))
    c2w = invert_rigid(torch.stack(w2c))
    return c2w, torch.tensor(sig, dtype=torch.float64), info


def _robust(r: torch.Tensor, kind: str, c: float) -> torch.Tensor:
    if kind == "cauchy":
        return c * c * torch.log1p((r / c) ** 2)
    if kind == "huber":
        return torch.where(r <= c, 0.5 * r * r, c * (r - 0.5 * c)) * 2.0
    raise ValueError(f"robust must be 'cauchy' or 'huber', got {kind!r}")


def bundle_adjust(
    uv, depth, vis, c2w0, sig0, focal0, width, height, cfg: CameraInitConfig, progress: str = ""
):
    """MoSca-style BA (see module docstring). uv [N, T, 2], depth [N, T] (normalised units), vis [N,
    T] bool. `progress`: the label of a progress bar over the BA steps ("" = none).

    Returns (c2w [T, 4, 4], log depth scale [T], focal, history list of dicts).
    """
    N, T = vis.shape
    dt = getattr(torch, cfg.ba_dtype)  # torch.float32 / torch.float64
    dev = uv.device
    uv, depth = uv.to(dt), depth.to(dt)
    c2w0, sig0 = c2w0.to(dev, dt), sig0.to(dev, dt)
    cx, cy = width / 2.0, height / 2.0
    q_all = rotmat_to_quat(c2w0[:, :3, :3])
    q = torch.nn.Parameter(q_all[1:].clone())
    c = torch.nn.Parameter(c2w0[1:, :3, 3].clone())
    ls = torch.nn.Parameter(torch.log(sig0[1:]).clone())
    logf = torch.nn.Parameter(torch.tensor(math.log(focal0), dtype=dt, device=dev))
    f0 = float(focal0)
    corr = torch.nn.Parameter(torch.zeros(N, T, dtype=dt, device=dev))
    groups = [
        {"params": [q], "lr": cfg.lr_rotation},
        {"params": [c], "lr": cfg.lr_translation},
        {"params": [ls], "lr": cfg.lr_depth_scale},
        {"params": [corr], "lr": cfg.lr_depth_correction},
    ]
    if cfg.optimize_focal:
        groups.append({"params": [logf], "lr": cfg.lr_focal})
    opt = torch.optim.Adam(groups)
    gamma = cfg.lr_final_factor ** (1.0 / max(cfg.ba_steps, 1))
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma)
    visf = vis.to(dt)
    nobs = visf.sum().clamp_min(1)
    cnt = visf.sum(1).clamp_min(1)
    q_fix = torch.tensor([[1.0, 0, 0, 0]], dtype=dt, device=dev)
    z3 = torch.zeros(1, 3, dtype=dt, device=dev)
    z1 = torch.zeros(1, dtype=dt, device=dev)
    hist = []

    def forward(step, want_stats=False):
        Q = torch.cat([q_fix, q], 0)
        C = torch.cat([z3, c], 0)
        L = torch.cat([z1, ls], 0)
        R = quat_to_rotmat(Q)  # [T, 3, 3]
        f = logf.exp()
        use_corr = step >= cfg.depth_correction_start
        dcorr = corr if use_corr else corr.detach() * 0
        d = depth * torch.exp(L[None] + dcorr)  # [N, T]
        rays = torch.stack([(uv[..., 0] - cx) / f, (uv[..., 1] - cy) / f, torch.ones_like(d)], -1)
        X = rays * d[..., None]
        # R X and R^T Y as sums of broadcast products (much faster than batched 3x3 matmuls on CPU)
        Pw = (
            R[None, :, :, 0] * X[..., 0:1]
            + R[None, :, :, 1] * X[..., 1:2]
            + R[None, :, :, 2] * X[..., 2:3]
            + C[None]
        )
        Pbar = (Pw * visf[..., None]).sum(1) / cnt[:, None]  # [N, 3]
        Y = Pbar[:, None] - C[None]
        Pc = (
            R[None, :, 0, :] * Y[..., 0:1]
            + R[None, :, 1, :] * Y[..., 1:2]
            + R[None, :, 2, :] * Y[..., 2:3]
        )
        z = Pc[..., 2]
        zc = z.clamp_min(1e-6)
        proj = torch.stack([f * Pc[..., 0] / zc + cx, f * Pc[..., 1] / zc + cy], -1)
        # option: residual in pixels of the INITIAL focal (normalised image coordinates x f0). Pixel
        # residuals scale with f, so with noisy depths a pixel loss is lowered by shrinking f (bias
        # to wide fovs); normalised ones are lowered by growing f when the TRACKS are noisy (bias to
        # narrow fovs). Pixels (default) are the ML choice for track noise; depth noise is absorbed
        # by the per-observation depth correction.
        r = (proj - uv).norm(dim=-1)
        if cfg.reproj_focal_invariant:
            r = r * (f0 / f)
        l_rep = (_robust(r, cfg.robust, cfg.robust_scale_px) * visf).sum() / nobs
        ratio = zc / d.clamp_min(1e-9)
        l_dep = ((torch.maximum(ratio, 1 / ratio) - 1) * visf).sum() / nobs
        l_neg = (torch.relu(1e-3 - z) * visf).sum() / nobs
        if T >= 3:
            acc = C[2:] - 2 * C[1:-1] + C[:-2]
            Qn = Q / Q.norm(dim=-1, keepdim=True)
            sgn = torch.sign((Qn[1:] * Qn[:-1]).sum(-1, keepdim=True)).detach()
            sgn = torch.where(sgn == 0, torch.ones_like(sgn), sgn)
            Qs = torch.cat([Qn[:1], Qn[1:] * torch.cumprod(sgn, 0)], 0)
            qacc = Qs[2:] - 2 * Qs[1:-1] + Qs[:-2]
            l_smooth = (acc**2).sum(-1).mean() + (qacc**2).sum(-1).mean()
        else:
            l_smooth = torch.zeros((), dtype=dt, device=dev)
        l_corr = ((dcorr**2) * visf).sum() / nobs
        loss = (
            cfg.w_reproj * l_rep
            + cfg.w_depth * l_dep
            + cfg.w_smooth * l_smooth
            + cfg.w_depth_correction * l_corr
            + 10.0 * l_neg
        )
        if not want_stats:
            return loss, None
        with torch.no_grad():
            stats = {
                "loss": float(loss),
                "reproj": float(l_rep),
                "depth": float(l_dep),
                "smooth": float(l_smooth),
                "corr": float(l_corr),
                "focal": float(f),
                "reproj_px_median": float(r[vis].median()) if bool(vis.any()) else float("nan"),
            }
        return loss, stats

    steps = range(cfg.ba_steps)
    if progress:
        steps = progress_bar(steps, desc=progress, unit="step", leave=False)
    for step in steps:
        opt.zero_grad(set_to_none=True)
        log = bool(cfg.log_every) and (step % cfg.log_every == 0 or step == cfg.ba_steps - 1)
        loss, stats = forward(step, log)
        loss.backward()
        opt.step()
        sched.step()
        if log:
            hist.append({"step": step, **stats})
    with torch.no_grad():
        _, stats = forward(cfg.ba_steps, True)
        hist.append({"step": cfg.ba_steps, **stats})
        Q = torch.cat([q_fix, q], 0)
        C = torch.cat([z3, c], 0)
        c2w = make_c2w(quat_to_rotmat(Q), C)
        L = torch.cat([z1, ls], 0)
    return (
        c2w.detach().cpu().double(),
        L.detach().cpu().double(),
        float(logf.detach().exp()),
        hist,
    )


# --------------------------------------------------------------------------------------------------
# Entry point
# --------------------------------------------------------------------------------------------------
def initialize_cameras(
    tracks: TrackSet,
    depth_priors,
    dynamic_masks,
    width: int,
    height: int,
    cfg: Optional[CameraInitConfig] = None,
    progress: str = "",
) -> CameraInitResult:
    """Initial cameras from the priors (see module docstring).

    Args:
        tracks: TrackSet over the T training frames (tracks [N, T, 2] pixels, visible [N, T]).
        depth_priors: [T, H, W] depth prior per training frame (any positive scale; <= 0 or
        non-finite = invalid). dynamic_masks: [T, H, W] bool (True = dynamic) or None (every track
        treated as static). width, height: image size in pixels. cfg: CameraInitConfig. progress:
        label of a progress bar over the bundle-adjustment steps ("" = none).
    Returns:
        CameraInitResult(K [3, 3], c2w [T, 4, 4] with c2w[0] = I, depth_scale [T], static_track_mask
        [N], diagnostics {fov curve, chosen fov, chaining, BA history, counts, timings}).
    """
    cfg = cfg or CameraInitConfig()
    t0 = time.perf_counter()
    uv_all = _t64(tracks.tracks)
    vis_all = (
        tracks.visible.bool().cpu()
        if isinstance(tracks.visible, torch.Tensor)
        else torch.as_tensor(np.asarray(tracks.visible), dtype=torch.bool)
    )
    N, T = vis_all.shape
    dmaps = _t64(depth_priors)
    if dmaps.shape != (T, height, width):
        raise ValueError(
            f"depth_priors must be [T={T}, H={height}, W={width}], got {tuple(dmaps.shape)}"
        )
    d_all = sample_per_frame(dmaps, uv_all)
    d_near = sample_per_frame(dmaps, uv_all, mode="nearest")
    inside = (
        (uv_all[..., 0] >= 0)
        & (uv_all[..., 0] <= width)
        & (uv_all[..., 1] >= 0)
        & (uv_all[..., 1] <= height)
    )
    # bilinear depth straddling a depth edge is unreliable: require agreement with the nearest
    # sample
    depth_ok = (
        torch.isfinite(d_all)
        & (d_all > 0)
        & inside
        & ((d_all - d_near).abs() <= cfg.depth_edge_tolerance * d_near.abs())
    )
    if dynamic_masks is None:
        in_dyn = torch.zeros(N, T, dtype=torch.bool)
    else:
        dm = (
            dynamic_masks
            if isinstance(dynamic_masks, torch.Tensor)
            else torch.as_tensor(np.asarray(dynamic_masks))
        )
        in_dyn = sample_per_frame(dm.to(torch.float64).cpu(), uv_all, mode="nearest") > 0.5
    static = select_static_tracks(
        vis_all, in_dyn, depth_ok, cfg.min_visible, cfg.max_dynamic_fraction
    )
    idx = torch.nonzero(static).flatten()
    if idx.numel() > cfg.max_static_tracks:
        g = torch.Generator().manual_seed(cfg.seed)
        idx = idx[torch.randperm(idx.numel(), generator=g)[: cfg.max_static_tracks]].sort().values
    uv = uv_all[idx]
    usable = (vis_all & depth_ok & ~in_dyn)[idx]
    depth_raw = torch.where(usable, d_all[idx], torch.ones_like(d_all[idx]))
    diag: Dict = {"num_tracks": N, "num_static": int(static.sum()), "num_used": int(idx.numel())}
    if idx.numel() < cfg.min_common_points:
        diag["warning"] = "too few static tracks; identity cameras and the fallback fov"
        K = torch.as_tensor(
            K_from_fov(width, height, cfg.fov if cfg.fov is not None else cfg.fov_fallback_deg)
        )
        eye = torch.eye(4, dtype=torch.float64).expand(T, 4, 4).clone()
        return CameraInitResult(K, eye, torch.ones(T, dtype=torch.float64), static, diag)
    med = float(depth_raw[usable].median())
    depth = depth_raw / med
    t1 = time.perf_counter()
    if cfg.fov is not None:
        fov = float(cfg.fov)
        diag["fov_fallback"] = False
    else:
        fov, fdiag = search_fov(uv, depth, usable, width, height, cfg)
        diag.update(fdiag)
    diag["fov_init_deg"] = fov
    K0 = torch.as_tensor(K_from_fov(width, height, fov))
    t2 = time.perf_counter()
    c2w0, sig0, chain = chain_poses(uv, depth, usable, K0, cfg)
    diag["chain"] = chain
    t3 = time.perf_counter()
    keep = usable.sum(1) >= 2
    if cfg.ba_steps > 0 and int(keep.sum()) >= cfg.min_common_points:
        dev = (
            torch.device(cfg.device)
            if cfg.device is not None
            else (
                depth_priors.device
                if isinstance(depth_priors, torch.Tensor)
                else torch.device("cpu")
            )
        )
        c2w, logs, focal, hist = bundle_adjust(
            uv[keep].to(dev),
            depth[keep].to(dev),
            usable[keep].to(dev),
            c2w0,
            sig0,
            float(K0[0, 0]),
            width,
            height,
            cfg,
            progress=progress,
        )
    else:
        c2w, logs, focal, hist = c2w0, torch.log(sig0), float(K0[0, 0]), []
    t4 = time.perf_counter()
    diag["ba_history"] = hist
    c2w = c2w.clone()
    c2w[:, :3, 3] *= med
    K = K0.clone()
    K[0, 0] = K[1, 1] = focal
    diag["fov_final_deg"] = float(2 * math.degrees(math.atan(width / 2.0 / focal)))
    diag["depth_normaliser"] = med
    diag["timings_s"] = {
        "lift": t1 - t0,
        "fov_search": t2 - t1,
        "chain": t3 - t2,
        "ba": t4 - t3,
        "total": t4 - t0,
    }
    return CameraInitResult(
        K=K, c2w=c2w, depth_scale=torch.exp(logs), static_track_mask=static, diagnostics=diag
    )
