"""Epipolar error maps and dynamic masks from the flow prior (paper section 3.2 "Prior Precompute").

The paper thresholds per-frame epipolar error maps (RoDynRF-style) computed from dense optical flow
between training frames of the same exposure level; the thresholded maps are the dynamic masks M_t
used by camera initialisation and by the video-to-world transformation (section 3.3.2).

Method, per flow pair F_{a->b}:
1. correspondences x1 = pixel centre of a (integer + 0.5), x2 = x1 + F_{a->b}(x1), from the flow's
   valid pixels;
2. a fundamental matrix x2^T F x1 = 0 fitted robustly: normalised 8-point algorithm (Hartley)
   hypotheses from random minimal samples, all scored at once (vectorised, seeded) by the median
   squared Sampson error (LMedS, as the authors' OpenCV FM_LMEDS; MSAC optional), then least-squares
   refits on the inliers;
3. the error of EVERY pixel of a against that F: the squared Sampson distance (default) or the mean
   squared point-to-line (symmetric epipolar) distance.

Error units (`EpipolarConfig.units`):
- "px" (default): the errors are squared distances in pixels (px^2) of the clip's image.
- "ndc": the authors' (RoDynRF / MoSca) definition: coordinates stretched to [-1, 1] along each axis
  (x = 2u/W - 1, y = 2v/H - 1) before the Sampson distance, so the squared error is in (NDC
  units)^2. The paper's threshold 1e-5 (appendix "Implementation Details") is in these units.
  Converting, one NDC unit is W/2 pixels horizontally and H/2 vertically, so 1e-5 NDC^2 ~= 1e-5 *
  (W/2) * (H/2) px^2, i.e. about 1.04 px^2 at the paper's 864 x 480 -- hence our default threshold
  of 1.0 px^2 (a Sampson distance of 1 pixel), which keeps the same meaning at every resolution.

Combining pairs into one map per training frame (`EpipolarConfig.combine`): the maps of all pairs
(t, b) whose source frame is t are combined by the mean (default) or max over the pairs, counting
for each pixel only the pairs where its flow is valid; a pixel valid in no pair combines all its
pairs unmasked. A training frame that is the source of no pair takes the map of the nearest frame
(in training order) that has one; if no pair exists at all the maps are 0 (everything static).

Classical fallback for clips without flow priors (docs/cameras.md "Classical fallback"):
`opencv_flow_prior` computes
DIS optical flow (OpenCV, preset MEDIUM) between training frames of the same exposure level after
brightness normalisation, with a forward-backward validity mask, and `tracks_from_flow` chains a
FlowSet into long-term tracks."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Optional, Sequence, Tuple

import numpy as np
import torch

from m4dgs.clip import FlowSet, TrackSet
from m4dgs.core.warp import fb_consistency


@dataclass
class EpipolarConfig:
    """Epipolar error maps -> dynamic masks (paper section 3.2; threshold from the appendix
    "Implementation Details")."""

    # Error definition: "sampson" (squared Sampson distance) or "symmetric" (mean of the two squared
    # point-to-epipolar-line distances).
    error: Literal["sampson", "symmetric"] = "sampson"
    # "px": squared pixels; "ndc": the authors' stretched [-1, 1] coordinates (paper threshold 1e-5
    # in these units).
    units: Literal["px", "ndc"] = "px"
    # Dynamic if error > threshold. Paper: 1e-5 in NDC^2 ~= 1e-5 * (W/2)(H/2) px^2 = 1.04 px^2 at
    # 864x480, so 1.0 px^2 (Sampson distance 1 px) reproduces the paper's setting; use 1e-5 with
    # units="ndc" for the exact authors' definition.
    threshold: float = 1.0
    combine: Literal["mean", "max"] = "mean"  # over a frame's flow pairs
    # Robust fit (always in pixel units). "lmeds" (default, as the authors' OpenCV FM_LMEDS: no
    # threshold, needs a static majority) or "msac"; ransac_threshold_px2 is the msac inlier
    # threshold / the cap of the lmeds one.
    ransac_method: Literal["lmeds", "msac"] = "lmeds"
    ransac_threshold_px2: float = 1.0
    ransac_hypotheses: int = 256
    # correspondences used for RANSAC scoring (random subset of valid pixels)
    max_fit_points: int = 2048
    refine_iters: int = 3  # least-squares 8-point refits on the inliers of the best hypothesis
    seed: int = 0


# --------------------------------------------------------------------------------------------------
# Fundamental matrix
# --------------------------------------------------------------------------------------------------
def _homog(x: torch.Tensor) -> torch.Tensor:
    return torch.cat([x, torch.ones_like(x[..., :1])], dim=-1)


def _hartley_normalisation(x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Similarity T [B, 3, 3] moving the weighted centroid of x [B, N, 2] to 0 and the mean distance
    to sqrt(2)."""
    wn = w / w.sum(-1, keepdim=True).clamp_min(1e-12)
    c = (wn[..., None] * x).sum(-2)  # [B, 2]
    d = (wn * (x - c[:, None]).norm(dim=-1)).sum(-1).clamp_min(1e-9)  # [B]
    s = np.sqrt(2.0) / d
    T = torch.zeros(x.shape[0], 3, 3, dtype=x.dtype, device=x.device)
    T[:, 0, 0] = s
    T[:, 1, 1] = s
    T[:, 0, 2] = -s * c[:, 0]
    T[:, 1, 2] = -s * c[:, 1]
    T[:, 2, 2] = 1.0
    return T


def eight_point(x1, x2, weights=None) -> torch.Tensor:
    """Normalised (weighted) 8-point algorithm, batched.

    Args:
        x1, x2: [..., N, 2] corresponding pixel coordinates (N >= 8) with x2^T F x1 = 0.
        weights: optional [..., N] non-negative weights (0 drops a correspondence).
    Returns:
        F [..., 3, 3], rank 2, unit Frobenius norm (sign arbitrary), in the input's coordinates.
        float64.
    """
    x1 = torch.as_tensor(x1).to(torch.float64)
    x2 = torch.as_tensor(x2).to(torch.float64)
    batch = x1.shape[:-2]
    n = x1.shape[-2]
    x1 = x1.reshape(-1, n, 2)
    x2 = x2.reshape(-1, n, 2)
    w = (
        torch.ones(x1.shape[:2], dtype=x1.dtype, device=x1.device)
        if weights is None
        else torch.as_tensor(weights).to(x1).reshape(-1, n)
    )
    T1 = _hartley_normalisation(x1, w)
    T2 = _hartley_normalisation(x2, w)
    p1 = _homog(x1) @ T1.transpose(-1, -2)
    p2 = _homog(x2) @ T2.transpose(-1, -2)
    # row of A for x2^T F x1 = 0 with F flattened row-major: p2_i * p1_j
    A = (p2[..., :, None] * p1[..., None, :]).reshape(x1.shape[0], n, 9)
    A = A * w.sqrt()[..., None]
    M = A.transpose(-1, -2) @ A  # [B, 9, 9]
    _, evec = torch.linalg.eigh(M)
    F = evec[..., 0].reshape(-1, 3, 3)
    U, S, Vh = torch.linalg.svd(F)
    S = S.clone()
    S[:, 2] = 0.0
    F = U @ torch.diag_embed(S) @ Vh
    F = T2.transpose(-1, -2) @ F @ T1
    F = F / F.flatten(1).norm(dim=-1).clamp_min(1e-300)[:, None, None]
    return F.reshape(*batch, 3, 3)


def sampson_error(F, x1, x2) -> torch.Tensor:
    """Squared Sampson distance [..., N] of correspondences x1, x2 [..., N, 2] to F [..., 3, 3]
    (x2^T F x1 = 0).

    (x2^T F x1)^2 / ((F x1)_0^2 + (F x1)_1^2 + (F^T x2)_0^2 + (F^T x2)_1^2), in squared input units.
    """
    h1, h2 = _homog(x1), _homog(x2)
    Fx1 = h1 @ F.transpose(-1, -2)
    Ftx2 = h2 @ F
    num = (h2 * Fx1).sum(-1) ** 2
    den = Fx1[..., 0] ** 2 + Fx1[..., 1] ** 2 + Ftx2[..., 0] ** 2 + Ftx2[..., 1] ** 2
    return num / den.clamp_min(1e-30)


def symmetric_epipolar_error(F, x1, x2) -> torch.Tensor:
    """Mean squared point-to-line distance [..., N]: (d(x2, F x1)^2 + d(x1, F^T x2)^2) / 2, squared
    input units."""
    h1, h2 = _homog(x1), _homog(x2)
    Fx1 = h1 @ F.transpose(-1, -2)
    Ftx2 = h2 @ F
    num = (h2 * Fx1).sum(-1) ** 2
    d2 = num / (Fx1[..., 0] ** 2 + Fx1[..., 1] ** 2).clamp_min(1e-30)
    d1 = num / (Ftx2[..., 0] ** 2 + Ftx2[..., 1] ** 2).clamp_min(1e-30)
    return 0.5 * (d1 + d2)


def ransac_fundamental(
    x1,
    x2,
    *,
    method: str = "lmeds",
    threshold: float = 1.0,
    num_hypotheses: int = 256,
    max_points: int = 2048,
    refine_iters: int = 3,
    seed: int = 0,
) -> Tuple[torch.Tensor, torch.Tensor]:
    """Robust fundamental matrix from normalised 8-point hypotheses, evaluated all at once
    (vectorised, seeded).

    Args:
        x1, x2: [N, 2] correspondences (pixels), x2^T F x1 = 0 for inliers. method: "lmeds" (least
        median of squared Sampson errors, no threshold; the authors use OpenCV's LMedS; needs
            > 50 % static correspondences) or "msac" (truncated-quadratic score at `threshold`).
        threshold: msac: inlier threshold on the squared Sampson distance (squared input units).
        lmeds: the inlier
            threshold is (2.5 sigma)^2 with the robust sigma = 1.4826 (1 + 5 / (n - 8))
            sqrt(median), capped at `threshold`.
        num_hypotheses: minimal 8-point samples.
        max_points: correspondences used to score the hypotheses (random subset when N is larger).
        refine_iters: least-squares refits on the inliers after the best hypothesis.
        seed: torch generator seed (deterministic).
    Returns:
        (F [3, 3] float64 unit-norm, inliers [N] bool).
    """
    x1 = torch.as_tensor(x1).to(torch.float64)
    x2 = torch.as_tensor(x2).to(torch.float64)
    n = x1.shape[0]
    if n < 8:
        raise ValueError(f"ransac_fundamental: need at least 8 correspondences, got {n}")
    gen = torch.Generator(device="cpu").manual_seed(int(seed))
    if n > max_points:
        sub = torch.randperm(n, generator=gen)[:max_points].to(x1.device)
        s1, s2 = x1[sub], x2[sub]
    else:
        s1, s2 = x1, x2
    m = s1.shape[0]
    # minimal samples (with replacement: a repeated index among 8 of m is rare and only wastes a
    # hypothesis)
    idx = torch.randint(0, m, (num_hypotheses, 8), generator=gen).to(x1.device)
    Fs = eight_point(s1[idx], s2[idx])  # [B, 3, 3]
    # [B, m]
    err = torch.nan_to_num(sampson_error(Fs[:, None], s1[None], s2[None]), nan=float("inf"))
    if method == "lmeds":
        score = err.median(dim=-1).values
    elif method == "msac":
        score = err.clamp(max=threshold).sum(-1)
    else:
        raise ValueError(f"method must be 'lmeds' or 'msac', got {method!r}")
    best = int(score.argmin())
    F = Fs[best]

    def inlier_threshold(e):
        if method == "msac":
            return threshold
        sigma = 1.4826 * (1 + 5.0 / max(m - 8, 1)) * float(e.median()) ** 0.5
        return min(max((2.5 * sigma) ** 2, 1e-12), threshold)

    e = sampson_error(F, x1, x2)
    inl = e < inlier_threshold(e)
    for _ in range(refine_iters):
        if int(inl.sum()) < 8:
            break
        F_new = eight_point(x1[inl], x2[inl])
        e_new = sampson_error(F_new, x1, x2)
        # keep a refit only if it fits its inliers better
        if float(e_new[inl].mean()) > float(e[inl].mean()):
            break
        F, e = F_new, e_new
        new = e < inlier_threshold(e)
        if torch.equal(new, inl):
            break
        inl = new
    return F, inl


def analytic_fundamental(K1, K2, R, t) -> torch.Tensor:
    """F = K2^-T [t]_x R K1^-1 for cameras with x_cam2 = R x_cam1 + t (unit Frobenius norm)."""
    K1, K2, R, t = (torch.as_tensor(a).to(torch.float64) for a in (K1, K2, R, t))
    tx = torch.zeros(3, 3, dtype=torch.float64)
    tx[0, 1], tx[0, 2], tx[1, 0], tx[1, 2], tx[2, 0], tx[2, 1] = (
        -t[2],
        t[1],
        t[2],
        -t[0],
        -t[1],
        t[0],
    )
    F = torch.linalg.inv(K2).T @ tx @ R @ torch.linalg.inv(K1)
    return F / F.norm()


# --------------------------------------------------------------------------------------------------
# Error maps and masks
# --------------------------------------------------------------------------------------------------
def _ndc_matrix(width: int, height: int) -> torch.Tensor:
    """N with x_px = N x_ndc (stretched [-1, 1] coordinates of the authors)."""
    return torch.tensor(
        [[width / 2.0, 0.0, width / 2.0], [0.0, height / 2.0, height / 2.0], [0.0, 0.0, 1.0]],
        dtype=torch.float64,
    )


def pair_error_map(flow, valid=None, cfg: Optional[EpipolarConfig] = None, seed_offset: int = 0):
    """Epipolar error of every pixel of frame a for one flow F_{a->b}.

    Args:
        flow: [H, W, 2] F_{a->b} (pixels); valid: optional [H, W] bool (pixels used to fit F; all
        when None or
            when fewer than 8 are valid).
        cfg: EpipolarConfig (units, error kind, RANSAC settings).
    Returns:
        (error [H, W] float32 in cfg.units squared, F [3, 3] float64 in pixel coordinates, inlier
        fraction float).
    """
    cfg = cfg or EpipolarConfig()
    fl = torch.as_tensor(np.asarray(flow) if not isinstance(flow, torch.Tensor) else flow).to(
        torch.float64
    )
    H, W = fl.shape[:2]
    ys, xs = torch.meshgrid(
        torch.arange(H, dtype=torch.float64) + 0.5,
        torch.arange(W, dtype=torch.float64) + 0.5,
        indexing="ij",
    )
    x1 = torch.stack([xs, ys], -1).to(fl.device).reshape(-1, 2)
    x2 = x1 + fl.reshape(-1, 2)
    finite = torch.isfinite(x2).all(-1)
    fit = finite.clone()
    if valid is not None:
        v = torch.as_tensor(np.asarray(valid) if not isinstance(valid, torch.Tensor) else valid).to(
            fl.device
        )
        v = v.reshape(-1).bool() & finite
        if int(v.sum()) >= 8:
            fit = v
    F, inl = ransac_fundamental(
        x1[fit],
        x2[fit],
        method=cfg.ransac_method,
        threshold=cfg.ransac_threshold_px2,
        num_hypotheses=cfg.ransac_hypotheses,
        max_points=cfg.max_fit_points,
        refine_iters=cfg.refine_iters,
        seed=cfg.seed + seed_offset,
    )
    if cfg.units == "ndc":
        N = _ndc_matrix(W, H).to(fl.device)
        Ni = torch.linalg.inv(N)
        Fe = N.T @ F @ N
        p1 = (_homog(x1) @ Ni.T)[:, :2]
        p2 = (_homog(x2) @ Ni.T)[:, :2]
    elif cfg.units == "px":
        Fe, p1, p2 = F, x1, x2
    else:
        raise ValueError(f"EpipolarConfig.units must be 'px' or 'ndc', got {cfg.units!r}")
    if cfg.error == "sampson":
        e = sampson_error(Fe, p1, p2)
    elif cfg.error == "symmetric":
        e = symmetric_epipolar_error(Fe, p1, p2)
    else:
        raise ValueError(
            f"EpipolarConfig.error must be 'sampson' or 'symmetric', got {cfg.error!r}"
        )
    e = torch.where(finite, e, torch.zeros_like(e))
    return e.reshape(H, W).float(), F, float(inl.float().mean())


def epipolar_error_maps(
    flow_set: FlowSet,
    frames: Sequence[int],
    cfg: Optional[EpipolarConfig] = None,
    return_info: bool = False,
):
    """Per-training-frame epipolar error maps [T, H, W] (float32 torch, cfg.units squared) from a
    FlowSet.

    Each frame t combines (cfg.combine) the maps of the pairs (t, b) of the FlowSet over the pixels
    where the flow is valid; frames that are the source of no pair copy the nearest frame's map (0
    when there is no pair at all). With return_info=True also returns {"pairs": [(a, b,
    inlier_fraction)], "filled_from": {t: source t}}."""
    cfg = cfg or EpipolarConfig()
    frames = [int(g) for g in frames]
    H, W = flow_set.flow.shape[1:3]
    T = len(frames)
    out = torch.zeros(T, H, W, dtype=torch.float32)
    have = [False] * T
    info = {"pairs": [], "filled_from": {}}
    pairs = np.asarray(flow_set.pairs)
    for ti, g in enumerate(frames):
        rows = np.nonzero(pairs[:, 0] == g)[0] if len(pairs) else np.zeros(0, np.int64)
        if rows.size == 0:
            continue
        maps, vals = [], []
        for r in rows.tolist():
            e, _, frac = pair_error_map(flow_set.flow[r], flow_set.valid[r], cfg, seed_offset=r)
            maps.append(e)
            vals.append(torch.as_tensor(np.asarray(flow_set.valid[r])).bool())
            info["pairs"].append((int(pairs[r, 0]), int(pairs[r, 1]), frac))
        E = torch.stack(maps)  # [P, H, W]
        V = torch.stack(vals)
        anyv = V.any(0)
        V = torch.where(anyv[None], V, torch.ones_like(V))
        if cfg.combine == "mean":
            m = (E * V).sum(0) / V.sum(0).clamp_min(1)
        elif cfg.combine == "max":
            m = torch.where(V, E, torch.zeros_like(E)).amax(0)
        else:
            raise ValueError(f"EpipolarConfig.combine must be 'mean' or 'max', got {cfg.combine!r}")
        out[ti] = m
        have[ti] = True
    filled = fill_from_nearest([out], {i for i in range(T) if have[i]})
    info["filled_from"] = {frames[t]: frames[s] for t, s in filled.items()}
    return (out, info) if return_info else out


def fill_from_nearest(maps: Sequence[torch.Tensor], sources) -> dict:
    """In place: every frame t of the [T, ...] tensors in `maps` that is not in `sources` (frames
    with data) gets the data of the nearest source frame (the earlier one on a tie). Returns {t:
    source}; nothing without sources."""
    src = sorted(sources)
    filled = {}
    if not src:
        return filled
    for t in range(maps[0].shape[0]):
        if t not in sources:
            s = min(src, key=lambda i: (abs(i - t), i))
            for m in maps:
                m[t] = m[s]
            filled[t] = s
    return filled


def dynamic_masks(error_maps, threshold: float) -> torch.Tensor:
    """Dynamic masks [T, H, W] bool: error > threshold (same units as the maps)."""
    e = torch.as_tensor(
        np.asarray(error_maps) if not isinstance(error_maps, torch.Tensor) else error_maps
    )
    return e > threshold


# --------------------------------------------------------------------------------------------------
# Classical fallback: OpenCV flow and tracks chained from flow
# --------------------------------------------------------------------------------------------------
def normalise_brightness(
    ldr: np.ndarray, dt: float, ref_dt: float = 1.0, gamma: float = 2.2
) -> np.ndarray:
    """8-bit grey image of an LDR frame with its exposure divided out: ((ldr/255)^gamma / dt *
    ref_dt)^(1/gamma).

    ldr: [H, W, 3] or [H, W] uint8. Returns [H, W] uint8 (clipped to [0, 255]).
    """
    x = np.asarray(ldr, np.float32) / 255.0
    if x.ndim == 3:
        x = x[..., 0] * 0.299 + x[..., 1] * 0.587 + x[..., 2] * 0.114
    lin = np.power(np.clip(x, 0, 1), gamma) / float(dt) * float(ref_dt)
    y = np.power(np.clip(lin, 0, 1), 1.0 / gamma)
    return np.round(y * 255.0).astype(np.uint8)


def _dis_flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    import cv2  # deferred: OpenCV (~0.2 s), only for clips without a flow prior

    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    return dis.calc(np.ascontiguousarray(a), np.ascontiguousarray(b), None).astype(np.float32)


def opencv_flow_prior(
    ldr_frames,
    train_dt,
    frames: Optional[Sequence[int]] = None,
    *,
    mode: str = "same_exposure",
    fb_alpha: float = 0.05,
    fb_beta: float = 0.5,
) -> FlowSet:
    """Flow prior without learned weights: OpenCV DIS (preset MEDIUM), both directions,
    forward-backward valid mask.

    Args:
        ldr_frames: [T, H, W, 3] uint8 training frames (in training order). train_dt: [T] exposure
        time of each frame. frames: [T] global indices of the frames (default 0..T-1), used in
        FlowSet.pairs. mode: "same_exposure" (the paper's protocol: each frame to the next training
        frame with the same dt) or
            "consecutive" (adjacent training frames, across exposures; relies on the brightness
            normalisation).
        fb_alpha, fb_beta: forward-backward consistency (m4dgs.core.warp.fb_consistency).
    Returns:
        FlowSet with pairs (a, b) and (b, a) for every linked pair.
    """
    ldr = np.asarray(ldr_frames)
    dts = np.asarray(train_dt, np.float64)
    T = ldr.shape[0]
    frames = list(range(T)) if frames is None else [int(g) for g in frames]
    ref = float(np.exp(np.mean(np.log(dts))))
    grey = [normalise_brightness(ldr[i], dts[i], ref) for i in range(T)]
    links = []
    if mode == "same_exposure":
        for i in range(T):
            nxt = [j for j in range(i + 1, T) if np.isclose(dts[j], dts[i], rtol=1e-6)]
            if nxt:
                links.append((i, nxt[0]))
    elif mode == "consecutive":
        links = [(i, i + 1) for i in range(T - 1)]
    else:
        raise ValueError(f"mode must be 'same_exposure' or 'consecutive', got {mode!r}")
    pairs, flows, valids = [], [], []
    for i, j in links:
        f = _dis_flow(grey[i], grey[j])
        b = _dis_flow(grey[j], grey[i])
        tf, tb = torch.from_numpy(f), torch.from_numpy(b)
        vf = fb_consistency(tf, tb, fb_alpha, fb_beta).numpy()
        vb = fb_consistency(tb, tf, fb_alpha, fb_beta).numpy()
        pairs += [(frames[i], frames[j]), (frames[j], frames[i])]
        flows += [f, b]
        valids += [vf, vb]
    H, W = ldr.shape[1:3]
    if not pairs:
        return FlowSet(
            np.zeros((0, 2), np.int64),
            np.zeros((0, H, W, 2), np.float32),
            np.zeros((0, H, W), bool),
        )
    return FlowSet(np.asarray(pairs, np.int64), np.stack(flows), np.stack(valids))


def tracks_from_flow(
    flow_set: FlowSet,
    frames: Sequence[int],
    *,
    grid_step: int = 8,
    seed_every: int = 4,
    max_tracks: Optional[int] = None,
    seed: int = 0,
) -> TrackSet:
    """Long-term tracks chained through the forward pairs (a -> b, b later than a) of a FlowSet.

    Seeds on a regular grid (pixel centres, every `grid_step` pixels) in every frame that starts a
    chain and in every `seed_every`-th frame along a chain; a track follows x <- x + F_{a->b}(x)
    (bilinear) while the flow is valid at x (nearest pixel) and x stays inside the image; it is
    visible only at the frames it reached. With same-exposure flow, a track lives on the frames of
    one exposure level (the others are invisible) -- enough for camera init.

    Args:
        flow_set: FlowSet over global frame indices; frames: [T] global indices of the training
        frames. max_tracks: keep a seeded random subset of this size.
    Returns:
        TrackSet(tracks [N, T, 2] float32 (0 where invisible), visible [N, T], frames [T]).
    """
    frames = [int(g) for g in frames]
    pos_of = {g: i for i, g in enumerate(frames)}
    H, W = flow_set.flow.shape[1:3]
    T = len(frames)
    nxt = {}
    for r, (a, b) in enumerate(np.asarray(flow_set.pairs).tolist()):
        if a in pos_of and b in pos_of and pos_of[b] > pos_of[a]:
            if a not in nxt or pos_of[b] < pos_of[nxt[a][0]]:
                nxt[a] = (b, r)
    prevs = {b: a for a, (b, _) in nxt.items()}
    gy, gx = np.meshgrid(
        np.arange(grid_step / 2, H, grid_step),
        np.arange(grid_step / 2, W, grid_step),
        indexing="ij",
    )
    grid = np.stack([gx.ravel(), gy.ravel()], -1).astype(np.float64)
    all_tr, all_vis = [], []
    for start in frames:
        if start not in nxt:
            continue
        # chain position of `start`: seed where a chain begins, or every `seed_every` links along it
        k, g = 0, start
        while g in prevs:
            g = prevs[g]
            k += 1
        if k % max(seed_every, 1) != 0:
            continue
        tr = np.zeros((grid.shape[0], T, 2), np.float32)
        vis = np.zeros((grid.shape[0], T), bool)
        x = grid.copy()
        alive = np.ones(grid.shape[0], bool)
        g = start
        tr[:, pos_of[g]] = x
        vis[:, pos_of[g]] = True
        while g in nxt and alive.any():
            b, r = nxt[g]
            fl = torch.from_numpy(np.asarray(flow_set.flow[r], np.float32))
            val = np.asarray(flow_set.valid[r], bool)
            xi = np.clip(np.floor(x).astype(np.int64), [0, 0], [W - 1, H - 1])
            alive &= val[xi[:, 1], xi[:, 0]]
            # bilinear flow at continuous x: sample the [H, W, 2] map at (x - 0.5) in index space
            idx = torch.from_numpy((x - 0.5).astype(np.float32))
            gxn = idx[:, 0] / max(W - 1, 1) * 2 - 1
            gyn = idx[:, 1] / max(H - 1, 1) * 2 - 1
            samp = torch.nn.functional.grid_sample(
                fl.permute(2, 0, 1)[None],
                torch.stack([gxn, gyn], -1)[None, None],
                mode="bilinear",
                padding_mode="border",
                align_corners=True,
            )
            x = x + samp[0, :, 0].T.numpy().astype(np.float64)
            alive &= (x[:, 0] >= 0) & (x[:, 0] < W) & (x[:, 1] >= 0) & (x[:, 1] < H)
            g = b
            tr[alive, pos_of[g]] = x[alive]
            vis[alive, pos_of[g]] = True
        keep = vis.sum(1) >= 2
        all_tr.append(tr[keep])
        all_vis.append(vis[keep])
    if not all_tr:
        return TrackSet(
            np.zeros((0, T, 2), np.float32), np.zeros((0, T), bool), np.asarray(frames, np.int64)
        )
    tracks = np.concatenate(all_tr)
    visible = np.concatenate(all_vis)
    if max_tracks is not None and tracks.shape[0] > max_tracks:
        sel = np.sort(
            np.random.default_rng(seed).choice(tracks.shape[0], max_tracks, replace=False)
        )
        tracks, visible = tracks[sel], visible[sel]
    return TrackSet(tracks=tracks, visible=visible, frames=np.asarray(frames, np.int64))
