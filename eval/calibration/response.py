"""A camera response estimated from bracketed 8-bit frames, the classical way (Debevec and Malik,
SIGGRAPH 1997), and the radiance a set of differently exposed frames gives through it.

The calibration rows of the tables (eval.calibration.predict) must get no more than a method
gets: a method learns its tone mapper from the training frames, so these rows estimate theirs from
the same frames instead of reading the clip's true response. Debevec-Malik solves, per colour
channel, for g(z) = ln f^-1(z), the log exposure that gives code z, from pixels seen at several
exposure times:

    minimise  sum_ij [w(z_ij) (g(z_ij) - ln E_i - ln dt_j)]^2 + lam^2 sum_z [w(z) g''(z)]^2

with a hat weight w (codes near 0 and 255 say little), a smoothness weight lam, and the unknown
scale fixed by one code: g(anchor) = 0. With anchor = the code of the clip's unit exposure
(clip.json unit_exposure_value, the C_0 the method's unit-exposure loss also uses), radiances come
out in the clip's units.

Frames of a moving camera are not aligned, so the samples are quantiles (`quantile_samples`): the
q-th brightest pixel of each exposure of a bracket sees the same radiance, since a response keeps
the order of brightness (Grossberg and Nayar's brightness transfer function). `bracket_samples`
takes pixels of flat patches instead, for aligned frames. Pure numpy.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

CODES = 256


#: weight of the end codes 0 and 255 (clipped: they bound the radiance, they do not measure it):
#: small, so that a pixel clipped in every frame still has a value
END_WEIGHT = 1e-3


def hat_weight(z: np.ndarray) -> np.ndarray:
    """Debevec-Malik's weight of 8-bit codes z (any shape): min(z, 255 - z), and END_WEIGHT at the
    clipped codes 0 and 255."""
    z = np.asarray(z, np.float64)
    return np.maximum(np.minimum(z, 255.0 - z), END_WEIGHT)


def solve_response(
    codes: np.ndarray, log_dt: Sequence[float], smoothness: float = 20.0, anchor: int = 128
) -> np.ndarray:
    """g [256]: log exposure of each code for one channel, from codes [P, N] uint8 (P pixels, each
    seen at the N exposures log_dt [N], natural log), with g(anchor) = 0 and g made non-decreasing
    (the least squares can dip where codes are rare). Codes no pixel shows are filled by the
    smoothness term."""
    z = np.asarray(codes, np.int64)
    P, N = z.shape
    ldt = np.asarray(log_dt, np.float64)
    if ldt.shape != (N,):
        raise ValueError(f"log_dt: expected {N} values, got shape {ldt.shape}")
    n_rows = P * N + 1 + (CODES - 2)
    A = np.zeros((n_rows, CODES + P))
    b = np.zeros(n_rows)
    w = hat_weight(z)
    rows = np.arange(P * N)
    A[rows, z.ravel()] = w.ravel()
    A[rows, CODES + np.repeat(np.arange(P), N)] = -w.ravel()
    b[: P * N] = (w * ldt[None, :]).ravel()
    A[P * N, anchor] = 1.0  # the scale
    k = P * N + 1
    zz = np.arange(1, CODES - 1)
    wz = smoothness * hat_weight(zz)
    A[k + zz - 1, zz - 1] = wz
    A[k + zz - 1, zz] = -2 * wz
    A[k + zz - 1, zz + 1] = wz
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    g = x[:CODES]
    return _monotone(g - g[anchor], anchor)


def _monotone(g: np.ndarray, anchor: int) -> np.ndarray:
    """g made non-decreasing while keeping g(anchor): a running max upwards from the anchor and a
    running min downwards."""
    out = g.copy()
    out[anchor:] = np.maximum.accumulate(g[anchor:])
    out[: anchor + 1] = np.minimum.accumulate(g[: anchor + 1][::-1])[::-1]
    return out


def bracket_samples(
    groups: Sequence[np.ndarray],
    n_per_group: int = 60,
    patch: int = 2,
    seed: int = 0,
) -> np.ndarray:
    """Codes [P, N, 3]: pixels seen in every frame of each group (N frames of one group, [N, H, W,
    3] uint8, one per exposure, consecutive in time), taken where the measured (unclipped) codes
    are flattest (the smallest spread over a (2 patch + 1)^2 window, summed over the group's
    frames and channels) among pixels measured in at least two frames; n_per_group per group,
    drawn from the flattest tenth with a fixed seed."""
    rng = np.random.default_rng(seed)
    out = []
    for frames in groups:
        f = np.asarray(frames, np.float64)
        N, H, W, _ = f.shape
        spread = np.zeros((H, W))
        measured = (f > 5) & (f < 250)  # [N, H, W, 3]
        for i in range(N):
            for c in range(3):
                # a clipped code stays clipped when the frame moves a little: only the measured
                # codes' spread tells how much a misalignment would change them
                spread += np.where(measured[i, :, :, c], _local_range(f[i, :, :, c], patch), 0)
        informative = measured.all(axis=3).sum(axis=0) >= 2
        border = np.zeros((H, W), bool)
        border[patch : H - patch, patch : W - patch] = True
        cand = np.flatnonzero((informative & border).ravel())
        if cand.size == 0:
            continue
        order = cand[np.argsort(spread.ravel()[cand], kind="stable")]
        pool = order[: max(n_per_group, len(order) // 10)]
        pick = rng.choice(pool, size=min(n_per_group, pool.size), replace=False)
        v, u = np.unravel_index(np.sort(pick), (H, W))
        out.append(np.transpose(f[:, v, u, :], (1, 0, 2)))  # [n, N, 3]
    if not out:
        raise ValueError("bracket_samples: no pixel with a code between black and white")
    return np.concatenate(out, 0).astype(np.uint8)


def _local_range(img: np.ndarray, r: int) -> np.ndarray:
    """max - min of img over a (2r + 1)^2 window (edges padded by replication)."""
    p = np.pad(img, r, mode="edge")
    H, W = img.shape
    hi = np.full((H, W), -np.inf)
    lo = np.full((H, W), np.inf)
    for dy in range(2 * r + 1):
        for dx in range(2 * r + 1):
            win = p[dy : dy + H, dx : dx + W]
            hi = np.maximum(hi, win)
            lo = np.minimum(lo, win)
    return hi - lo


def quantile_samples(frames: np.ndarray, n: int = 64) -> np.ndarray:
    """Codes [n, N, 3]: for n quantiles q, the code at quantile q of each frame's channel (frames
    [N, H, W, 3] uint8 of one scene at N exposures). Brightening preserves order, so the q-th
    brightest pixel of each exposure is the same scene radiance: a pixel seen at every exposure
    without aligning the frames (the brightness transfer function of histogram specification,
    Grossberg and Nayar, CVPR 2003). Frames of a moving camera see nearly the same content, so
    their histograms match where their pixels would not."""
    f = np.asarray(frames)
    q = (np.arange(n) + 0.5) / n
    out = np.quantile(f.reshape(f.shape[0], -1, 3), q, axis=1)  # [n, N, 3]
    return np.round(out).astype(np.uint8)


def estimate_response(
    groups: Sequence[np.ndarray],
    dts: Sequence[Sequence[float]],
    anchor: int = 128,
    smoothness: float = 20.0,
    sampling: str = "quantiles",
    n_per_group: int = 64,
) -> np.ndarray:
    """g [3, 256] per channel (solve_response) from groups of bracketed frames: groups[k] [N, H,
    W, 3] uint8 with exposure times dts[k] [N] (every group has the same N levels, in any order:
    the samples are sorted by level). sampling: "quantiles" (quantile_samples; frames of a moving
    camera need no alignment) or "pixels" (bracket_samples: flat patches, for aligned frames)."""
    levels = sorted({float(d) for ds in dts for d in ds})
    take = {"quantiles": quantile_samples, "pixels": lambda f, n: bracket_samples([f], n)}
    if sampling not in take:
        raise ValueError(f"sampling must be one of {sorted(take)}, got {sampling!r}")
    samples = []
    for frames, ds in zip(groups, dts):
        if sorted(float(d) for d in ds) != levels:
            raise ValueError(f"every group must hold each level {levels} once, got {list(ds)}")
        order = np.argsort(np.asarray(ds, np.float64))
        samples.append(take[sampling](np.asarray(frames)[order], n_per_group))
    z = np.concatenate(samples, 0)  # [P, N, 3]
    ldt = np.log(np.asarray(levels))
    return np.stack([solve_response(z[..., c], ldt, smoothness, anchor) for c in range(3)])


def radiance(ldr: np.ndarray, dt: float, g: np.ndarray) -> np.ndarray:
    """[H, W, 3] radiance of one 8-bit frame [H, W, 3] at exposure time dt through g [3, 256]."""
    z = np.asarray(ldr, np.int64)
    return np.exp(np.stack([g[c][z[..., c]] for c in range(3)], -1) - np.log(dt))


def merge_radiance(
    ldrs: Sequence[np.ndarray], dts: Sequence[float], g: np.ndarray, weights=None
) -> np.ndarray:
    """[H, W, 3] radiance of aligned frames ldrs [N][H, W, 3] uint8 at times dts through g [3,
    256]: the hat-weighted mean of ln radiance (Debevec-Malik's radiance map), times optional
    per-frame weight maps weights [N][H, W] (e.g. 0 where a warp had no source)."""
    num = 0.0
    den = 0.0
    for i, (z, dt) in enumerate(zip(ldrs, dts)):
        z = np.asarray(z, np.int64)
        w = hat_weight(z)
        if weights is not None:
            w = w * np.asarray(weights[i], np.float64)[..., None]
        lg = np.stack([g[c][z[..., c]] for c in range(3)], -1) - np.log(dt)
        num = num + w * lg
        den = den + w
    return np.exp(num / np.maximum(den, 1e-12))


def expose(hdr: np.ndarray, dt: float, g: np.ndarray) -> np.ndarray:
    """[H, W, 3] uint8: the codes g [3, 256] gives radiance hdr [H, W, 3] at exposure time dt
    (the nearest code in log exposure; below g(0) is 0, above g(255) is 255)."""
    le = np.log(np.maximum(np.asarray(hdr, np.float64), 1e-30) * dt)
    out = np.empty(le.shape, np.uint8)
    for c in range(3):
        gc = g[c]
        # midpoints between consecutive codes' log exposures: code k wins between its two
        mids = (gc[1:] + gc[:-1]) / 2
        out[..., c] = np.searchsorted(mids, le[..., c], side="right").clip(0, 255)
    return out
