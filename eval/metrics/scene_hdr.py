"""HDR scores that count the whole scene, and the highlights only exposure fusion recovers.

The paper's HDR PSNR (eval.metrics.hdr.hdr_psnr) divides by the ground truth's maximum, so one
emitter pixel sets its scale: on lamp-room-orbit that maximum is a lamp at 1,170 while the 99th
percentile of the scene is 1.43, so 99 % of the scene lies in the bottom quarter of the mu-law
range, an all-black prediction scores 21.3 dB (the method 40.2), and a lamp rendered 24 times too
bright is clipped away. Beside it (kept for comparability with the paper) the tables carry:

- `hdr_psnr_p99`: mu-law PSNR with the truth's 99th percentile of luminance as the unit and no
  clipping above it: T(H) = log(1 + mu H / p99) / log(1 + mu), mu = 5000, for the prediction and
  the truth, data range 1. One pixel cannot move p99, the bulk of the scene spans the curve's
  steep part, and a too-bright highlight still costs (logarithmically) instead of vanishing at 1.
- `highlight_stops`: the mean absolute log2 error (stops) over the highlight pixels: saturated in
  the longest observed exposure (a code of 255 in some channel) yet measured in the shortest (every
  channel below 255); only fusing exposures recovers them.
- `highlight_peak_ratio`: the render's largest value over those pixels divided by the truth's
  (1 = right; a runaway highlight shows as a large ratio, which the clipped metric barely sees).
- `highlight_peak_ratio_resolved`: the same over the highlight pixels the shortest exposure
  resolves, its code at most `resolved_short_code` (the largest code whose HDR bin spans at most
  2x). Just under clipping one code covers a wide range of HDR values (with the HDR-NeRF response
  code 254 spans 3.0x, 253 1.68x), so the plain peak ratio is often decided by pixels where a render
  4x too bright reads one code off; over the resolved pixels a render that reproduces the frames'
  codes is within the 0.5-2 band.

All take linear HDR [H, W, 3] or [N, H, W, 3] (numpy or torch) and return the mean over frames
(the peak ratio: the geometric mean); frames without a highlight pixel are left out (NaN when no
frame has one).
"""

from __future__ import annotations

import numpy as np

from m4dgs.core.crf import tonemap_ldr

MU = 5000.0
P99 = 99.0
LUMA = np.array([0.2126, 0.7152, 0.0722])

CONVENTIONS = {
    "hdr_psnr_p99": "HDR PSNR, whole scene: mu-law (mu=5000) of H / p99(luminance of H_gt) "
    "without clipping (prediction and GT), data range 1, mean over frames",
    "highlight_stops": "mean |log2(pred) - log2(gt)| over pixels saturated at the longest "
    "observed exposure and measured at the shortest (gt through the clip's response)",
    "highlight_peak_ratio": "max(pred) / max(gt) over those pixels, geometric mean over frames",
    "highlight_peak_stops": "peak (stops): log2 of max(pred) / max(gt) over those pixels "
    "(geometric mean over frames), averaged over runs in stops: 0 is right, -1 and +1 bound the "
    "0.5-2 band",
    "highlight_peak_ratio_resolved": "max(pred) / max(gt) over the highlight pixels whose "
    "shortest-exposure code (every channel) is at most the largest code whose HDR bin through the "
    "clip's response spans at most 2x (253 with hdrnerf), geometric mean over frames",
    "highlight_peak_resolved_stops": "peak, resolved (stops): as peak, over the highlight pixels "
    "whose shortest-exposure code (every channel) is at most the largest code whose HDR bin "
    "through the clip's response spans at most 2x (253 with hdrnerf)",
}

#: the widest HDR bin, as a factor, of a code the resolved peak counts: the 0.5-2 band's own
RESOLVED_BIN = 2.0


def code_bin_span(crf, code: int) -> float:
    """The factor one 8-bit code spans in HDR through `crf` (the widest over its channels):
    f^-1((code + 1/2) / 255) / f^-1((code - 1/2) / 255), the exposure time cancelling; inf when the
    bin's lower end is 0 (code 0) or the curve cannot be inverted there."""
    if not 0 < code < 255:
        return float("inf")
    curves = [crf.channel(c) for c in range(len(crf.channels))] if crf.per_channel else [crf]
    lo, hi = (code - 0.5) / 255.0, (code + 0.5) / 255.0
    spans = []
    for f in curves:
        a, b = (float(np.asarray(f.inverse(np.float64(y)))) for y in (lo, hi))
        spans.append(b / a if a > 0 and np.isfinite(b) else float("inf"))
    return max(spans)


def resolved_short_code(crf, factor: float = RESOLVED_BIN) -> int:
    """The largest code c <= 254 whose HDR bin through the CRF `crf` (code_bin_span) spans at most
    `factor` (253 with hdrnerf, 254 with srgb-shoulder); 0 when no code's does."""
    for c in range(254, 0, -1):
        if code_bin_span(crf, c) <= factor:
            return c
    return 0


def peak_geomean(ratios) -> float:
    """The geometric mean of per-frame peak ratios (each floored at 1e-12); NaN for none."""
    if len(ratios) == 0:
        return float("nan")
    return float(np.exp(np.mean(np.log(np.maximum(ratios, 1e-12)))))


def _frames(x) -> np.ndarray:
    a = np.asarray(x.detach().cpu().numpy() if hasattr(x, "detach") else x, np.float64)
    return a[None] if a.ndim == 3 else a


def _mu(x: np.ndarray) -> np.ndarray:
    return np.log1p(MU * np.maximum(x, 0.0)) / np.log1p(MU)


def p99_unit(gt: np.ndarray) -> float:
    """The 99th percentile of a frame's luminance [H, W, 3] (at least 1e-12)."""
    return max(float(np.percentile(gt @ LUMA, P99)), 1e-12)


def hdr_psnr_p99(pred, gt) -> float:
    """Whole-scene HDR PSNR (module docstring), mean over frames."""
    p, g = _frames(pred), _frames(gt)
    if p.shape != g.shape:
        raise ValueError(f"hdr_psnr_p99: shapes differ, {p.shape} vs {g.shape}")
    out = []
    for pf, gf in zip(p, g):
        s = p99_unit(gf)
        mse = float(np.mean((_mu(pf / s) - _mu(gf / s)) ** 2))
        out.append(10.0 * np.log10(1.0 / max(mse, 1e-20)))
    return float(np.mean(out))


def highlight_mask(
    gt: np.ndarray, crf, dt_long: float, dt_short: float, max_short_code: int = 254
) -> np.ndarray:
    """[H, W] bool: pixels of one ground-truth frame [H, W, 3] (linear, the clip's units) that
    the longest exposure saturates (255 in some channel) and the shortest measures (every channel
    at max_short_code or below; 254, the default, is every unclipped code), both through the
    clip's response `crf`. Near clipping one code spans a wide range of HDR values (with the
    HDR-NeRF response at the shortest benchmark exposure, code 254 spans 3x and 253 1.7x), so a
    lower max_short_code keeps only pixels the shortest exposure measures finely."""
    long_ = tonemap_ldr(gt, dt_long, crf)
    short = tonemap_ldr(gt, dt_short, crf)
    return (long_ == 255).any(-1) & (short <= max_short_code).all(-1)


def highlight_scores(
    pred, gt, crf, dt_long: float, dt_short: float, max_short_code: int = 254
) -> dict:
    """{"highlight_stops", "highlight_peak_ratio", "highlight_pixels"} over the highlight pixels
    (highlight_mask, with max_short_code) of every frame; NaN scores when no frame has one."""
    p, g = _frames(pred), _frames(gt)
    stops, ratios, n = [], [], 0
    for pf, gf in zip(p, g):
        m = highlight_mask(gf, crf, dt_long, dt_short, max_short_code)
        if not m.any():
            continue
        n += int(m.sum())
        a = np.maximum(pf[m], 1e-12)
        b = np.maximum(gf[m], 1e-12)
        stops.append(float(np.mean(np.abs(np.log2(a) - np.log2(b)))))
        ratios.append(float(pf[m].max() / max(gf[m].max(), 1e-12)))
    return {
        "highlight_stops": float(np.mean(stops)) if stops else float("nan"),
        "highlight_peak_ratio": peak_geomean(ratios),
        "highlight_pixels": n,
    }
