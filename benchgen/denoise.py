"""Denoising of path-traced HDR frames with Intel Open Image Denoise (docs/rendering.md
"Denoising").

A 64-spp frame of a lamp-lit room has a per-pixel relative noise of 5-17 %; at the ground truth's
job (HDR-TAE, HDR PSNR) that noise is a floor no method can go below. OIDN's ``RT`` filter with the
first-hit albedo and shading normal (rendered by Mitsuba's ``aov`` integrator over the same box
pixel footprint, at a few samples per pixel) removes most of it at a few milliseconds per small
frame.

Directly visible emitters are 10^3-10^4 times brighter than the surfaces they light. Fed to the
denoiser as they are, their energy bleeds into the neighbourhood (measured: +12 % L1 bias against a
1024-spp reference on a window scene, against 3 % for the raw render). So the colour is capped
before denoising at ``cap_factor`` times a high percentile of the pixels that do not see an emitter,
and every pixel whose raw value exceeds the cap keeps its raw value (those pixels are emitters and
their rims, whose radiance is exact up to the pixel-footprint average).

Pure functions of numpy arrays; pyoidn is imported on first use.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

#: multiple of the non-emitter high percentile above which pixels bypass the denoiser
CAP_FACTOR = 4.0
#: percentile of the non-emitter pixels' brightest channel that sets the cap
CAP_PERCENTILE = 99.9


def emitter_cap(
    color: np.ndarray,
    emitter: Optional[np.ndarray] = None,
    cap_factor: float = CAP_FACTOR,
    percentile: float = CAP_PERCENTILE,
) -> float:
    """The value above which a pixel bypasses the denoiser.

    color [H, W, 3] linear HDR; emitter [H, W] bool: pixels whose centre ray hits an emitter (None:
    none known). Returns cap_factor * the `percentile` of the brightest channel over the pixels that
    are not emitters and do not touch one (the emitter mask grown by one pixel), or +inf when no
    such pixel is positive."""
    c = np.asarray(color, np.float32)
    m = c.max(axis=-1)
    keep = np.ones(m.shape, bool)
    if emitter is not None and np.asarray(emitter).any():
        e = np.asarray(emitter, bool)
        grown = e.copy()
        grown[1:] |= e[:-1]
        grown[:-1] |= e[1:]
        grown[:, 1:] |= e[:, :-1]
        grown[:, :-1] |= e[:, 1:]
        keep = ~grown
    vals = m[keep]
    vals = vals[vals > 0]
    if vals.size == 0:
        return float("inf")
    return float(cap_factor * np.percentile(vals, percentile))


def denoise_hdr(
    color: np.ndarray,
    albedo: np.ndarray,
    normal: np.ndarray,
    emitter: Optional[np.ndarray] = None,
    cap_factor: float = CAP_FACTOR,
    quality: str = "high",
) -> np.ndarray:
    """Denoise one linear HDR frame.

    Args:
        color: [H, W, 3] float linear radiance (>= 0).
        albedo: [H, W, 3] first-hit albedo in [0, 1] (clipped here).
        normal: [H, W, 3] first-hit shading normal (any frame; OIDN accepts world space).
        emitter: [H, W] bool, pixels whose centre ray hits an emitter (for the cap; optional).
        cap_factor: see :func:`emitter_cap`.
        quality: OIDN quality ("high" | "balanced" | "fast").
    Returns:
        [H, W, 3] float32: the denoised frame, with pixels above the cap kept raw; >= 0 and finite.
    """
    import pyoidn  # deferred: Open Image Denoise costs ~1.4 s to import, only when denoising

    c = np.ascontiguousarray(
        np.nan_to_num(np.asarray(color, np.float32), nan=0.0, posinf=0.0).clip(min=0.0)
    )
    if c.ndim != 3 or c.shape[-1] != 3:
        raise ValueError(f"denoise_hdr: color must be [H, W, 3], got {c.shape}")
    alb = np.ascontiguousarray(np.clip(np.asarray(albedo, np.float32), 0.0, 1.0))
    nrm = np.ascontiguousarray(np.nan_to_num(np.asarray(normal, np.float32)).clip(-1.0, 1.0))
    if alb.shape != c.shape or nrm.shape != c.shape:
        raise ValueError(
            f"denoise_hdr: albedo {alb.shape} and normal {nrm.shape} must match color {c.shape}"
        )
    cap = emitter_cap(c, emitter, cap_factor)
    over = c.max(axis=-1) > cap
    inp = np.minimum(c, cap).astype(np.float32) if np.isfinite(cap) else c
    out = np.asarray(
        pyoidn.denoise(np.ascontiguousarray(inp), alb, nrm, hdr=True, quality=quality), np.float32
    )
    out = np.where(over[..., None], c, np.nan_to_num(out, nan=0.0, posinf=0.0).clip(min=0.0))
    return np.ascontiguousarray(out.astype(np.float32))
