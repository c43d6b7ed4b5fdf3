"""Camera-response recovery: the learned tone mapper against the clip's true response (crf_error).

crf_error is the mean absolute difference, in 8-bit codes (LDR value x 255), between the learned
response phi_c and the true response f_c of each colour channel c, over the exposures the clip
actually recorded, then the mean over channels:

    range_c  = [P1, P99] of x = H_gt[..., c] * dt over the training frames' pixels whose true 8-bit
    code is neither
               black (0) nor saturated (255), i.e. the exposures the input video measured in channel
               c;
    err_c    = mean over N = 256 log2-uniform x in range_c of 255 |phi_c(x) - f_c(x)|;
    crf_error = mean_c err_c.

Log-uniform sampling weighs every stop of the recorded range equally (a pixel-weighted mean would be
dominated by the mid-tones of the scene), and the range leaves out exposures the input never
measured (below code 0, above code 255), where any curve that is black / white fits the data equally
well. The comparison is absolute: the trainer fixes the HDR scale through the unit-exposure value
phi(1) = C0 = f(1), so a learned curve shifted along log x counts as an error. A constant offset of
d LDR units gives crf_error = 255 d (tested)."""

from __future__ import annotations

from typing import Callable, Iterable, List, Optional, Sequence, Tuple

import numpy as np

from m4dgs.core.crf import get_crf

CRF_ERROR_SAMPLES = 256
CRF_ERROR_PERCENTILES = (1.0, 99.0)
CRF_ERROR_MAX_PIXELS = 65536  # pixels per frame used for the range (strided sample)

CONVENTIONS = {
    "crf_error": "CRF error: mean |learned - true| response in 8-bit codes over "
    f"{CRF_ERROR_SAMPLES} log-uniform "
    f"exposures between the P{CRF_ERROR_PERCENTILES[0]:g} and P{CRF_ERROR_PERCENTILES[1]:g} of the "
    "exposures H_gt dt that the training frames recorded unclipped (codes 1-254), per channel, "
    "then the "
    "mean over RGB",
}


def observed_exposure_range(
    hdr_frames: Iterable[np.ndarray],
    dts: Sequence[float],
    crf,
    percentiles: Tuple[float, float] = CRF_ERROR_PERCENTILES,
    max_pixels: int = CRF_ERROR_MAX_PIXELS,
) -> List[Optional[Tuple[float, float]]]:
    """Per channel, the [lo, hi] exposure range x = H_gt dt recorded unclipped by the frames (None
    if empty).

    Args:
        hdr_frames: ground-truth linear HDR frames [H, W, C] (an iterable, consumed once). dts:
        exposure time of each frame. crf: the true response (m4dgs.core.crf.CRF; per-channel curves
        use channel c's curve for channel c). percentiles: the lower and upper percentile of the
        unclipped exposures. max_pixels: per frame, a strided sample of at most this many pixels is
        used.
    """
    f = get_crf(crf)
    per_c: List[list] = []
    for h, dt in zip(hdr_frames, dts):
        h = np.asarray(h, np.float64)
        c_n = h.shape[-1]
        flat = h.reshape(-1, c_n)
        step = max(1, int(np.ceil(flat.shape[0] / max_pixels)))
        x = flat[::step] * float(dt)
        while len(per_c) < c_n:
            per_c.append([])
        for c in range(c_n):
            per_c[c].append(x[:, c])
    out: List[Optional[Tuple[float, float]]] = []
    for c, parts in enumerate(per_c):
        fc = f.channel(c)
        x = np.concatenate(parts)
        lo_x, hi_x = float(fc.inverse(0.5 / 255.0)), float(fc.inverse(254.5 / 255.0))
        x = x[(x >= lo_x) & (x < hi_x)]
        if x.size < 2:
            out.append(None)
            continue
        lo, hi = np.percentile(x, percentiles)
        out.append((float(lo), float(hi)) if hi > lo > 0 else None)
    return out


def crf_error(
    learned: Callable,
    crf,
    ranges: Sequence[Optional[Tuple[float, float]]],
    n: int = CRF_ERROR_SAMPLES,
) -> dict:
    """crf_error of a learned response against the true one (module docstring).

    Args:
        learned: log2 exposures [n] (numpy) -> LDR values [n, C] (e.g. TrainedModel.tonemap_curve;
        torch or numpy
            out), or [n] for a curve shared by the channels.
        crf: the true response (m4dgs.core.crf name or CRF). ranges: per channel (lo, hi) exposure
        range, or None for a channel without recorded exposures. n: samples per channel,
        log2-uniform.
    Returns:
        {"crf_error": mean over channels (None if no channel has a range), "per_channel": [codes or
        None], "ranges": [[lo, hi] or None], "samples": n, "units": "8-bit codes"}.
    """
    f = get_crf(crf)
    per = []
    for c, r in enumerate(ranges):
        if r is None:
            per.append(None)
            continue
        z = np.linspace(np.log2(r[0]), np.log2(r[1]), int(n))
        y = curve_channel(learned, z, c)
        true = np.asarray(f.channel(c)(np.exp2(z)), np.float64)
        per.append(float(255.0 * np.mean(np.abs(y - true))))
    vals = [v for v in per if v is not None]
    return {
        "crf_error": float(np.mean(vals)) if vals else None,
        "per_channel": per,
        "ranges": [None if r is None else [float(r[0]), float(r[1])] for r in ranges],
        "samples": int(n),
        "units": "8-bit codes",
    }


def curve_channel(learned: Callable, z: np.ndarray, c: int) -> np.ndarray:
    """Channel c of a response learned(z) as float64 [len(z)] (learned returns torch or numpy,
    [n] for a curve shared by the channels or [n, C])."""
    y = learned(z)
    if hasattr(y, "detach"):
        y = y.detach().cpu().numpy()
    y = np.asarray(y, np.float64)
    return y[:, c] if y.ndim == 2 else y.reshape(len(z))


def crf_error_shifted(
    learned: Callable,
    crf,
    ranges: Sequence[Optional[Tuple[float, float]]],
    max_shift: float = 2.0,
    step: float = 0.01,
    n: int = CRF_ERROR_SAMPLES,
) -> dict:
    """crf_error left after the best exposure shift of the learned response: which part of the error
    is a mis-set HDR scale (the curve slid along log x) and which a wrong shape.

    For a shift s (EV) the learned curve is read at x 2^s: err(s) = crf_error of z -> learned(z + s)
    over the same ranges as crf_error. s is searched on a grid of `step` over [-max_shift,
    max_shift], once shared by the channels (a global HDR scale) and once per channel (a scale per
    channel, i.e. white balance). s > 0 means the learned curve needs s EV more exposure than the
    true one for the same code (it is darker); a learned curve equal to f(x 2^-s) gives shift s and
    error 0.

    Returns:
        {"shift": s [EV], "crf_error": err(s) [codes], "per_channel_shift": [s_c or None],
        "per_channel_error": [err_c(s_c) or None], "crf_error_per_channel_shift": mean_c
        err_c(s_c)}; the errors are None (and the shift 0.0) when no channel has a range.
    """
    f = get_crf(crf)
    shifts = np.arange(-round(max_shift / step), round(max_shift / step) + 1) * float(step)
    table = []  # [channel] -> errors over the shifts, or None
    for c, r in enumerate(ranges):
        if r is None:
            table.append(None)
            continue
        z = np.linspace(np.log2(r[0]), np.log2(r[1]), int(n))
        true = np.asarray(f.channel(c)(np.exp2(z)), np.float64)
        # one call for every shift: [len(shifts) * n] log2 exposures
        zz = (z[None, :] + shifts[:, None]).reshape(-1)
        y = curve_channel(learned, zz, c).reshape(len(shifts), len(z))
        table.append(255.0 * np.mean(np.abs(y - true[None, :]), axis=1))
    rows = [t for t in table if t is not None]
    if not rows:
        return {
            "shift": 0.0,
            "crf_error": None,
            "per_channel_shift": [None] * len(table),
            "per_channel_error": [None] * len(table),
            "crf_error_per_channel_shift": None,
        }
    mean = np.mean(rows, axis=0)
    i = int(np.argmin(mean))
    per_i = [None if t is None else int(np.argmin(t)) for t in table]
    per_err = [None if t is None else float(t[j]) for t, j in zip(table, per_i)]
    return {
        "shift": float(shifts[i]),
        "crf_error": float(mean[i]),
        "per_channel_shift": [None if j is None else float(shifts[j]) for j in per_i],
        "per_channel_error": per_err,
        "crf_error_per_channel_shift": float(np.mean([e for e in per_err if e is not None])),
    }


def crf_error_bands(
    learned: Callable,
    crf,
    ranges: Sequence[Optional[Tuple[float, float]]],
    bands: int = 6,
    n: int = CRF_ERROR_SAMPLES,
) -> dict:
    """Where along the exposure range the learned response departs from the true one, with its sign.

    Each channel's recorded range (as crf_error's) is cut into `bands` equal intervals of log2 x,
    dark to bright; per band the mean of 255 (learned - true) over the log2-uniform samples that
    fall in it (n, raised to a multiple of `bands`, so every band has n / bands of them). A curve
    too dark in the mid-tones reads negative in the middle bands; a constant offset d reads 255 d
    in every band.

    Returns:
        {"bands": [mean over channels, per band], "per_channel": [[per band] or None],
        "edges_log2": [[bands + 1 log2 x edges] or None], "units": "8-bit codes"}.
    """
    if int(bands) < 1:
        raise ValueError(f"bands must be >= 1, got {bands}")
    bands = int(bands)
    n = int(np.ceil(int(n) / bands)) * bands
    f = get_crf(crf)
    per, edges = [], []
    for c, r in enumerate(ranges):
        if r is None:
            per.append(None)
            edges.append(None)
            continue
        z = np.linspace(np.log2(r[0]), np.log2(r[1]), n)
        d = 255.0 * (
            curve_channel(learned, z, c) - np.asarray(f.channel(c)(np.exp2(z)), np.float64)
        )
        per.append([float(v) for v in d.reshape(bands, -1).mean(axis=1)])
        edges.append([float(v) for v in np.linspace(z[0], z[-1], bands + 1)])
    vals = [p for p in per if p is not None]
    return {
        "bands": [float(v) for v in np.mean(vals, axis=0)] if vals else None,
        "per_channel": per,
        "edges_log2": edges,
        "units": "8-bit codes",
    }
