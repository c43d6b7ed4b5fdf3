"""Geometry metrics beyond the paper: camera ATE / RPE after Sim(3) alignment, depth AbsRel, 2D
track error.

Conventions (docs/metrics.md):
- ATE: the estimated camera centres are aligned to the ground-truth centres by the least-squares
  Sim(3) (Umeyama, m4dgs.core.camera.umeyama_sim3: s R c_est + t ~ c_gt); ATE = RMSE of the aligned
  centre errors, in GT units.
- RPE: the same Sim(3) applied to the estimated c2w poses (R_i -> R R_i, c_i -> s R c_i + t); for
  each pair of
  consecutive frames, the relative motion error E = (G_i^-1 G_{i+1})^-1 (P_i^-1 P_{i+1}); RPE-trans
  = RMSE of |trans(E)|
  (GT units), RPE-rot = RMSE of the rotation angle of E in degrees.
- Depth AbsRel: valid pixels gt > 0 (and finite, pred > 0, and the optional mask); s = median(gt) /
  median(pred)
  over valid pixels (numpy median: mean of the two middle values); AbsRel = mean |s d - gt| / gt.
- Tracks: end-point error in pixels over the points visible in the ground truth; fraction within
  1/2/4/8/16 px and their average (TAP-Vid's <delta^x_avg). TAP-Vid measures at 256x256: pass
  `image_size=(W, H)` to rescale the coordinates to 256x256 first (labelled); by default pixels of
  the clip.
"""

from __future__ import annotations

import numpy as np
import torch

from m4dgs.core.camera import umeyama_sim3

from ._util import as_mask, as_tensor

TRACK_THRESHOLDS = (1.0, 2.0, 4.0, 8.0, 16.0)

CONVENTIONS = {
    "ate": "ATE: RMSE of camera centres after Sim(3) (Umeyama) alignment to GT, GT units",
    "rpe": "RPE: consecutive-frame relative pose error after Sim(3) alignment; translation RMSE "
    "(GT units), "
    "rotation RMSE (degrees)",
    "depth_absrel": "Depth AbsRel: mean |s d - gt| / gt over gt > 0, s = median(gt) / median(d)",
    "track": "Track error: mean EPE (px) over GT-visible points; <delta_avg = mean fraction "
    "within 1/2/4/8/16 px",
    "track_256": "Track error at 256x256 (TAP-Vid convention): coordinates rescaled before "
    "thresholds",
}


def _centres(poses: torch.Tensor) -> torch.Tensor:
    """[N, 4, 4] c2w -> [N, 3] centres; [N, 3] passes through."""
    if poses.dim() == 3 and poses.shape[-2:] in ((4, 4), (3, 4)):
        return poses[:, :3, 3]
    if poses.dim() == 2 and poses.shape[-1] == 3:
        return poses
    raise ValueError(
        f"expected [N, 3] camera centres or [N, 4, 4] c2w poses, got {tuple(poses.shape)}"
    )


def align_sim3(est, gt, with_scale: bool = True):
    """Least-squares Sim(3) (s, R [3, 3], t [3]) with s R c_est + t ~ c_gt (float64 torch)."""
    ce = _centres(as_tensor(est, uint8_scale=False))
    cg = _centres(as_tensor(gt, uint8_scale=False, device=ce.device))
    if ce.shape != cg.shape or ce.shape[0] < 3:
        raise ValueError(
            "align_sim3: need matching [N>=3, 3] trajectories, got "
            f"{tuple(ce.shape)}/{tuple(cg.shape)}"
        )
    s, r, t = umeyama_sim3(ce, cg, with_scale=with_scale)
    return (
        as_tensor(s, device=ce.device).reshape(()),
        as_tensor(r, device=ce.device),
        as_tensor(t, device=ce.device).reshape(3),
    )


def ate(est, gt, *, with_scale: bool = True) -> float:
    """Absolute trajectory error (RMSE of centres after Sim(3) alignment). est/gt: [N, 3] centres or
    [N, 4, 4] c2w."""
    ce = _centres(as_tensor(est, uint8_scale=False))
    cg = _centres(as_tensor(gt, uint8_scale=False, device=ce.device))
    s, r, t = align_sim3(ce, cg, with_scale=with_scale)
    aligned = s * ce @ r.T + t
    return float(((aligned - cg) ** 2).sum(dim=-1).mean().sqrt())


def _rot_angle_deg(r: torch.Tensor) -> torch.Tensor:
    c = ((r.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0) / 2.0).clamp(-1.0, 1.0)
    return torch.rad2deg(torch.arccos(c))


def rpe(est_c2w, gt_c2w, *, with_scale: bool = True) -> dict:
    """Relative pose error between consecutive frames after Sim(3) alignment.

    Args:
        est_c2w, gt_c2w: [N, 4, 4] camera-to-world poses (N >= 3).
    Returns:
        {"rpe_trans": RMSE of relative translation errors (GT units), "rpe_rot": RMSE of rotation
        errors (deg)}.
    """
    pe = as_tensor(est_c2w, uint8_scale=False)
    pg = as_tensor(gt_c2w, uint8_scale=False, device=pe.device)
    if pe.shape != pg.shape or pe.dim() != 3 or pe.shape[-2:] != (4, 4):
        raise ValueError(
            f"rpe: need matching [N, 4, 4] poses, got {tuple(pe.shape)}/{tuple(pg.shape)}"
        )
    s, r, t = align_sim3(pe, pg, with_scale=with_scale)
    pa = pe.clone()
    pa[:, :3, :3] = r @ pe[:, :3, :3]
    pa[:, :3, 3] = s * pe[:, :3, 3] @ r.T + t
    rel_e = torch.linalg.inv(pa[:-1]) @ pa[1:]
    rel_g = torch.linalg.inv(pg[:-1]) @ pg[1:]
    err = torch.linalg.inv(rel_g) @ rel_e
    te = err[:, :3, 3].norm(dim=-1)
    re = _rot_angle_deg(err[:, :3, :3])
    return {"rpe_trans": float((te**2).mean().sqrt()), "rpe_rot": float((re**2).mean().sqrt())}


def _median(x: torch.Tensor) -> torch.Tensor:
    """numpy-style median of a 1-D tensor (mean of the two middle values for an even count)."""
    xs, _ = torch.sort(x)
    n = xs.numel()
    return xs[n // 2] if n % 2 == 1 else 0.5 * (xs[n // 2 - 1] + xs[n // 2])


def depth_absrel(pred, gt, mask=None) -> float | None:
    """AbsRel after median scaling, over pixels with gt > 0 (finite) and pred > 0 (and `mask`).

    pred, gt: [H, W] (or [N, H, W], one pooled set of pixels) z-depth maps. Returns None when no
    pixel is valid."""
    g = as_tensor(gt, uint8_scale=False)
    d = as_tensor(pred, uint8_scale=False, device=g.device)
    if d.shape != g.shape:
        raise ValueError(f"depth_absrel: shape mismatch {tuple(d.shape)} vs {tuple(g.shape)}")
    valid = (g > 0) & torch.isfinite(g) & (d > 0) & torch.isfinite(d)
    if mask is not None:
        valid = valid & as_mask(mask, g)
    if int(valid.sum()) == 0:
        return None
    gv, dv = g[valid], d[valid]
    s = _median(gv) / _median(dv)
    return float(((dv * s - gv).abs() / gv).mean())


def track_error(pred, gt, visible, *, thresholds=TRACK_THRESHOLDS, image_size=None) -> dict:
    """2D track error against ground-truth tracks.

    Args:
        pred, gt: [N, T, 2] pixel coordinates (x, y). visible: [N, T] bool, ground-truth visibility
        (only visible points are scored). thresholds: pixel thresholds for the within-delta
        fractions (TAP-Vid: 1, 2, 4, 8, 16). image_size: optional (W, H); when given, coordinates
        are rescaled to 256x256 before measuring (TAP-Vid).
    Returns:
        {"epe": mean EPE, "delta_avg": mean of the fractions, "within_<d>": fraction within d px for
        each d}; values are None when no point is visible.
    """
    g = as_tensor(gt, uint8_scale=False)
    p = as_tensor(pred, uint8_scale=False, device=g.device)
    if p.shape != g.shape or p.shape[-1] != 2:
        raise ValueError(
            f"track_error: need matching [N, T, 2] tracks, got {tuple(p.shape)}/{tuple(g.shape)}"
        )
    v = as_mask(visible, g)
    if image_size is not None:
        w, h = image_size
        k = torch.tensor([256.0 / w, 256.0 / h], dtype=g.dtype, device=g.device)
        p, g = p * k, g * k
    keys = [f"within_{d:g}" for d in thresholds]
    if int(v.sum()) == 0:
        return {"epe": None, "delta_avg": None, **{k_: None for k_ in keys}}
    e = (p - g).norm(dim=-1)[v]
    fr = [float((e < d).to(torch.float64).mean()) for d in thresholds]
    out = {"epe": float(e.mean()), "delta_avg": float(np.mean(fr))}
    out.update(dict(zip(keys, fr)))
    return out


def rotation_error_deg(r_a, r_b) -> float:
    """Angle in degrees of R_a^T R_b (a convenience for single-pose checks)."""
    a = as_tensor(r_a, uint8_scale=False)
    b = as_tensor(r_b, uint8_scale=False, device=a.device)
    return float(_rot_angle_deg(a.transpose(-1, -2) @ b))


__all__ = [
    "align_sim3",
    "ate",
    "rpe",
    "depth_absrel",
    "track_error",
    "rotation_error_deg",
    "TRACK_THRESHOLDS",
    "CONVENTIONS",
]
