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

OIDN's HDR mode maps its input through one exposure (an automatic ``inputScale`` chosen from the
frame's average brightness) into a transfer function that is accurate over a few decades around
it. The benchmark's frames span seven to eight decades (a lamp of radiance ~5000 beside shadows lit
by an environment of ~0.005), so with one pass the darkest tenth of a frame came out 11-19 % off a
1024-spp render (median per-pixel relative error; the raw 80-spp render: 4 %) and its two-seed noise
stayed high. :func:`denoise_hdr` therefore runs the filter as an exposure ladder: passes whose input
scales are ``LADDER_STEP`` apart and span the frame's own brightness range (:func:`ladder_scales`);
every pixel is taken from the two passes whose exposure puts it nearest ``LADDER_TARGET``
(:func:`ladder_weights`, linear in log scale), so each band of brightness is denoised where the
network is accurate (docs/rendering.md, "Denoising").

Pure functions of numpy arrays; pyoidn is imported on first use.
"""

from __future__ import annotations

import functools
import math
from typing import List, Optional, Sequence, Tuple

import numpy as np

#: multiple of the non-emitter high percentile above which pixels bypass the denoiser
CAP_FACTOR = 4.0
#: percentile of the non-emitter pixels' brightest channel that sets the cap
CAP_PERCENTILE = 99.9
#: the exposure each pixel is denoised at: OIDN's HDR transfer is most accurate near 1 (frame 0 of
#: conveyor-occlusion-orbit: targets 1, 3 and 10 gave two-seed rel. std 0.038, 0.039, 0.040)
LADDER_TARGET = 1.0
#: ratio of consecutive input scales (100: 4-5 passes per frame; 1000 raised the two-seed noise by
#: 2-8 % on four clips, 10 gave the same as 100 at twice the passes)
LADDER_STEP = 100.0
#: the brightness range the ladder spans: these percentiles of the non-emitter pixels' mean channel
LADDER_PERCENTILES = (1.0, 99.9)


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
    vals = m[_non_emitter(emitter, m.shape)]
    vals = vals[vals > 0]
    if vals.size == 0:
        return float("inf")
    return float(cap_factor * np.percentile(vals, percentile))


def ladder_scales(
    color: np.ndarray,
    keep: Optional[np.ndarray] = None,
    target: float = LADDER_TARGET,
    step: float = LADDER_STEP,
    percentiles: Tuple[float, float] = LADDER_PERCENTILES,
) -> np.ndarray:
    """Input scales [n] (ascending, ratio `step`) of the ladder's passes for one frame.

    color [H, W, 3] linear HDR (capped); keep [H, W] bool: the pixels whose brightness counts
    (default: all). The first scale puts the `percentiles[1]` percentile of the positive
    mean-channel values at `target`, the last one puts the `percentiles[0]` percentile at `target`
    or above (one scale only for a frame of one brightness). Scaling the frame by k divides every
    scale by k, so the ladder's result scales with the frame."""
    lum = np.asarray(color, np.float64).mean(axis=-1)
    vals = lum[keep] if keep is not None else lum.ravel()
    vals = vals[vals > 0]
    if vals.size == 0:
        return np.array([1.0])
    lo, hi = np.percentile(vals, percentiles)
    s0 = target / hi
    n = 1 + max(0, int(math.ceil(math.log(max(hi / lo, 1.0)) / math.log(step) - 1e-9)))
    return s0 * step ** np.arange(n, dtype=np.float64)


def ladder_weights(lum: np.ndarray, scales: np.ndarray, target: float = LADDER_TARGET):
    """Which passes make each pixel: (lower pass index i [H, W], upper pass weight w [H, W]).

    lum [H, W] a brightness estimate per pixel; scales [n] ascending by a constant ratio. A pixel's
    wanted scale target / lum is placed on the ladder in log scale, clamped to its ends; the pixel
    is (1 - w) * pass[i] + w * pass[i + 1] (with one pass: i = 0, w = 0)."""
    n = len(scales)
    if n == 1:
        return np.zeros(lum.shape, np.int64), np.zeros(lum.shape, np.float64)
    ratio = math.log(scales[1] / scales[0])
    want = np.log(target / np.maximum(np.asarray(lum, np.float64), 1e-30))
    x = np.clip((want - math.log(scales[0])) / ratio, 0.0, n - 1.0)
    i = np.minimum(np.floor(x).astype(np.int64), n - 2)
    return i, x - i


def oidn_passes(
    color: np.ndarray,
    albedo: np.ndarray,
    normal: np.ndarray,
    input_scales: Sequence[Optional[float]] = (None,),
    quality: str = "high",
) -> List[np.ndarray]:
    """OIDN ``RT`` HDR filter passes of one frame, one per input scale: [H, W, 3] float32 each.

    color, albedo, normal [H, W, 3] float32. input_scales: OIDN's ``inputScale`` per pass (the
    exposure the network sees the frame at; None: its automatic choice from the frame's average
    brightness). One filter serves every pass (re-committed with the next scale)."""
    import pyoidn  # deferred: Open Image Denoise costs ~1.4 s to import, only when denoising

    dev = _oidn_device()
    flt = pyoidn.Filter(dev, pyoidn.OIDN_FILTER_TYPE_RT)
    # OIDN reads the arrays' memory when it executes: keep them referenced until then
    images = [np.ascontiguousarray(a, np.float32) for a in (color, albedo, normal)]
    outs = []
    try:
        for name, img in zip(
            (pyoidn.OIDN_IMAGE_COLOR, pyoidn.OIDN_IMAGE_ALBEDO, pyoidn.OIDN_IMAGE_NORMAL), images
        ):
            flt.set_image(name, img, pyoidn.OIDN_FORMAT_FLOAT3)
        flt.set_bool("hdr", True)
        flt.set_quality(_QUALITY[quality])
        for scale in input_scales:
            out = np.empty_like(images[0])
            flt.set_image(pyoidn.OIDN_IMAGE_OUTPUT, out, pyoidn.OIDN_FORMAT_FLOAT3)
            flt.set_float("inputScale", float("nan") if scale is None else float(scale))
            flt.commit()
            flt.execute()
            err = dev.get_error()
            if err:
                raise RuntimeError(f"Open Image Denoise failed: {err}")
            outs.append(out)
    finally:
        flt.release()
    return outs


_QUALITY = {"high": 6, "balanced": 5, "fast": 4}  # OIDN_QUALITY_* values (oidn.h)


@functools.lru_cache(maxsize=1)
def _oidn_device():
    """One OIDN CPU device per process (created on first use; ~10 ms)."""
    import pyoidn

    dev = pyoidn.Device()
    dev.commit()
    return dev


def denoise_hdr(
    color: np.ndarray,
    albedo: np.ndarray,
    normal: np.ndarray,
    emitter: Optional[np.ndarray] = None,
    cap_factor: float = CAP_FACTOR,
    quality: str = "high",
    ladder: bool = True,
) -> np.ndarray:
    """Denoise one linear HDR frame.

    Args:
        color: [H, W, 3] float linear radiance (>= 0).
        albedo: [H, W, 3] first-hit albedo in [0, 1] (clipped here).
        normal: [H, W, 3] first-hit shading normal (any frame; OIDN accepts world space).
        emitter: [H, W] bool, pixels whose centre ray hits an emitter (for the cap; optional).
        cap_factor: see :func:`emitter_cap`.
        quality: OIDN quality ("high" | "balanced" | "fast").
        ladder: denoise as an exposure ladder (:func:`ladder_scales`, :func:`ladder_weights`);
            False: one pass at OIDN's automatic exposure (generator versions 4 and 5).
    Returns:
        [H, W, 3] float32: the denoised frame, with pixels above the cap kept raw; >= 0 and finite.
    """
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
    if ladder:
        scales = ladder_scales(inp, _non_emitter(emitter, c.shape[:2]))
        passes = oidn_passes(inp, alb, nrm, scales, quality)
        # the brightness estimate that places a pixel on the ladder: the pass that sees the frame
        # darkest (accurate for the bright pixels, within ~40 % for the darkest: a tenth of a step)
        i, w = ladder_weights(passes[0].mean(axis=-1), scales)
        stack = np.stack(passes)
        yy, xx = np.indices(i.shape)
        w3 = w[..., None]
        out = (1.0 - w3) * stack[i, yy, xx] + w3 * stack[np.minimum(i + 1, len(scales) - 1), yy, xx]
    else:
        out = oidn_passes(inp, alb, nrm, (None,), quality)[0]
    out = np.where(over[..., None], c, np.nan_to_num(out, nan=0.0, posinf=0.0).clip(min=0.0))
    return np.ascontiguousarray(out.astype(np.float32))


def _non_emitter(emitter: Optional[np.ndarray], shape) -> np.ndarray:
    """[H, W] bool: pixels that neither hit an emitter nor touch one (all when none is known)."""
    if emitter is None or not np.asarray(emitter).any():
        return np.ones(shape, bool)
    e = np.asarray(emitter, bool)
    grown = e.copy()
    grown[1:] |= e[:-1]
    grown[:-1] |= e[1:]
    grown[:, 1:] |= e[:, :-1]
    grown[:, :-1] |= e[:, 1:]
    return ~grown
