"""Exposure placement: the clip's HDR scale, chosen from its own converged frames, and what the clip
achieved.

A bracketing camera meters its middle exposure and spreads the others around it. benchgen's clips
imitate that with one global HDR scale ``s`` (LDR = CRF(s * H * dt) in 8 bits) chosen to meet four
targets, all measured on the TRAINING frames of the clip, each exposure level on the frames taken at
it:

=====================  ====================================================================
==================
target                 statistic                                                             wanted
=====================  ====================================================================
==================
``mid_median``         median over pixels of the brightest channel's LDR value (0..1) at     in
[0.35, 0.65]
                       the middle observed level (the one closest to sqrt(shortest*longest))
``short_highlights``   per channel, fraction of pixels with code >= 250 at the shortest      <= 2 %
(all channels)
                       level (the highlights are observed somewhere)
``long_saturated``     per channel, fraction of pixels with code >= 250 at the longest       >= 0.5
% (all channels)
                       level (the clip needs merging at the top)
``short_dark``         per channel, fraction of pixels with code <= 5 at the shortest level  >= 0.5
% (all channels)
                       (the clip needs merging at the bottom)
=====================  ====================================================================
==================

Every statistic is a monotone function of ``s`` (codes only grow with exposure), so each target is
an interval of scales, found exactly by bisection on the very quantiser the clip is written with
(``m4dgs.core.crf.tonemap_ldr``); the chosen scale is the one inside the intersection closest (in
log) to a middle-level median of 0.5. When the intersection is empty the targets are given up in
reverse priority (dark, then long saturation, then highlights; the middle-level median is always
kept) and the report says which cannot be met: `benchgen make` then fails with that message, because
a scene that cannot be placed needs a change of its spec (deeper shadows, smaller lamps), not looser
targets.

After the clip is written, :func:`measure_placement` recomputes every statistic from the 8-bit PNGs
on disk (what a user of the clip sees) and the result goes to clip.json ``gt.placement``."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from m4dgs.clip import frame_name, level_name
from m4dgs.core import io as mio
from m4dgs.core.crf import CRF, get_crf, tonemap_ldr

TARGET_NAMES = ("mid_median", "short_highlights", "long_saturated", "short_dark")
# : relative margin kept inside every interval of scales (float32 storage of the scaled frames
# rounds)
SCALE_MARGIN = 1e-5


@dataclass(frozen=True)
class PlacementTargets:
    """Placement targets of a clip (see the module docstring); codes are 8-bit values."""

    mid_median: Tuple[float, float] = (0.35, 0.65)
    short_highlights_max: float = 0.02
    long_saturated_min: float = 0.005
    short_dark_min: float = 0.005
    hi_code: int = 250
    lo_code: int = 5
    # inside the feasible interval, the scale closest to this middle-level median
    median_aim: float = 0.5

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class LevelStats:
    """Statistics of the 8-bit frames of one exposure level (channel lists are R, G, B)."""

    dt: float
    num_frames: int
    median: float  # median over pixels of the brightest channel, 0..1
    hi_fraction: List[float]  # per channel, fraction of pixels with code >= hi_code
    lo_fraction: List[float]  # per channel, fraction of pixels with code <= lo_code

    @staticmethod
    def of(ldr: np.ndarray, dt: float, targets: PlacementTargets) -> "LevelStats":
        """ldr: uint8 [N, H, W, 3] (or [H, W, 3]) frames of one level."""
        a = np.asarray(ldr)
        if a.ndim == 3:
            a = a[None]
        px = a.reshape(-1, a.shape[-1])[:, :3]
        return LevelStats(
            dt=float(dt),
            num_frames=int(a.shape[0]),
            median=float(np.median(px.max(axis=1))) / 255.0,
            hi_fraction=[float(np.mean(px[:, c] >= targets.hi_code)) for c in range(3)],
            lo_fraction=[float(np.mean(px[:, c] <= targets.lo_code)) for c in range(3)],
        )


def level_roles(levels: Sequence[float]) -> Dict[str, float]:
    """{"short": shortest, "middle": observed level closest (in log) to sqrt(shortest * longest),
    "long": longest}."""
    lv = sorted(float(v) for v in levels)
    if not lv:
        raise ValueError("placement: no exposure levels")
    geo = math.sqrt(lv[0] * lv[-1])
    mid = min(lv, key=lambda v: (abs(math.log(v / geo)), v))
    return {"short": lv[0], "middle": mid, "long": lv[-1]}


def evaluate_targets(
    stats: Dict[float, LevelStats],
    targets: PlacementTargets,
    levels: Optional[Sequence[float]] = None,
) -> Dict[str, dict]:
    """{target name: {value, wanted, met}} from per-level statistics (levels default to the keys of
    stats)."""
    roles = level_roles(levels if levels is not None else list(stats))
    s, m, l = stats[roles["short"]], stats[roles["middle"]], stats[roles["long"]]
    lo, hi = targets.mid_median
    return {
        "mid_median": {
            "value": m.median,
            "wanted": f"in [{lo}, {hi}] at dt={roles['middle']:g}",
            "met": bool(lo <= m.median <= hi),
        },
        "short_highlights": {
            "value": max(s.hi_fraction),
            "wanted": f"<= {targets.short_highlights_max} of pixels >= {targets.hi_code} in every "
            f"channel at dt={roles['short']:g}",
            "met": bool(max(s.hi_fraction) <= targets.short_highlights_max),
        },
        "long_saturated": {
            "value": min(l.hi_fraction),
            "wanted": f">= {targets.long_saturated_min} of pixels >= {targets.hi_code} in every "
            f"channel at dt={roles['long']:g}",
            "met": bool(min(l.hi_fraction) >= targets.long_saturated_min),
        },
        "short_dark": {
            "value": min(s.lo_fraction),
            "wanted": f">= {targets.short_dark_min} of pixels <= {targets.lo_code} in every "
            "channel at "
            f"dt={roles['short']:g}",
            "met": bool(min(s.lo_fraction) >= targets.short_dark_min),
        },
    }


# --------------------------------------------------------------------------------------------------
# Choosing the scale
# --------------------------------------------------------------------------------------------------
def _code(value: float, channel: int, exposure: float, f: CRF) -> int:
    """8-bit code of a single channel value at exposure (the clip's quantiser, per channel)."""
    v = np.zeros((1, 1, 3), np.float64)
    v[0, 0, channel] = value
    return int(tonemap_ldr(v, float(exposure), f)[0, 0, channel])


def _bisect_scale(pred, lo: float = 1e-12, hi: float = 1e12, iters: int = 200) -> float:
    """The boundary of a monotone predicate over s > 0: pred(s) is False below it and True above
    (log bisection). Returns the smallest s (to ~1e-12 relative) with pred True; +inf if pred(hi) is
    False, lo if pred(lo) is True."""
    if pred(lo):
        return lo
    if not pred(hi):
        return math.inf
    a, b = math.log(lo), math.log(hi)
    for _ in range(iters):
        m = 0.5 * (a + b)
        if pred(math.exp(m)):
            b = m
        else:
            a = m
        if b - a < 1e-12:
            break
    return math.exp(b)


def _kth_largest(x: np.ndarray, k: int) -> float:
    k = min(max(int(k), 1), x.size)
    return float(np.partition(x, x.size - k)[x.size - k])


def _kth_smallest(x: np.ndarray, k: int) -> float:
    k = min(max(int(k), 1), x.size)
    return float(np.partition(x, k - 1)[k - 1])


def _median_ldr(frames: np.ndarray, exposure: float, f: CRF, stride: int) -> float:
    ldr = tonemap_ldr(frames[:, ::stride, ::stride], exposure, f)
    return float(np.median(ldr.reshape(-1, 3).max(axis=1))) / 255.0


def choose_hdr_scale(
    frames_by_level: Dict[float, np.ndarray],
    crf: Union[str, CRF] = "hdrnerf",
    targets: Optional[PlacementTargets] = None,
    median_stride: int = 1,
) -> Tuple[float, dict]:
    """One HDR scale for a clip from its (unit-scale, converged) frames, grouped by the exposure
    they are shown at.

    Args:
        frames_by_level: {dt: [N, H, W, 3] linear HDR frames (>= 0) that will be tone-mapped at dt};
        needs the
            shortest, the middle and the longest level (see :func:`level_roles`).
        crf: the clip's CRF.
        targets: PlacementTargets (default: the benchmark's).
        median_stride: pixel stride for the middle-level median (1 = every pixel).
    Returns:
        (s, report): report = {scale, interval per target [lo, hi], feasible, given_up [names],
        predicted {target: {value, wanted, met}} (the statistics the clip will have at s), levels,
        crf, message}.
    """
    t = targets or PlacementTargets()
    f = get_crf(crf)
    levels = sorted(float(k) for k in frames_by_level)
    roles = level_roles(levels)
    arr = {
        k: np.asarray(v, np.float64).reshape((-1,) + np.asarray(v).shape[-3:])
        for k, v in frames_by_level.items()
    }
    for k, a in arr.items():
        if a.size == 0 or not np.isfinite(a).all() or (a < 0).any():
            raise ValueError(
                f"choose_hdr_scale: frames at dt={k:g} must be finite, >= 0 and non-empty"
            )
    short, mid, long_ = (arr[roles[r]] for r in ("short", "middle", "long"))
    if mid.max() <= 0:
        raise ValueError("choose_hdr_scale: the middle-level frames are entirely black")
    dt_s, dt_m, dt_l = roles["short"], roles["middle"], roles["long"]

    # middle-level median window and aim (median of the max-channel code is monotone in s)
    lo_med, hi_med = t.mid_median
    s_med_lo = _bisect_scale(lambda s: _median_ldr(mid, s * dt_m, f, median_stride) >= lo_med)
    s_med_hi_excl = _bisect_scale(lambda s: _median_ldr(mid, s * dt_m, f, median_stride) > hi_med)
    s_aim = _bisect_scale(lambda s: _median_ldr(mid, s * dt_m, f, median_stride) >= t.median_aim)
    intervals: Dict[str, Tuple[float, float]] = {
        "mid_median": (s_med_lo, s_med_hi_excl * (1 - 1e-9))
    }

    # per-channel order statistics of the short / long levels
    n_s = short[..., 0].size
    n_l = long_[..., 0].size
    # this many >= hi_code would be too many
    k_hl = int(math.floor(t.short_highlights_max * n_s)) + 1
    k_sat = max(1, int(math.ceil(t.long_saturated_min * n_l)))
    k_dark = max(1, int(math.ceil(t.short_dark_min * n_s)))
    hl_hi, sat_lo, dark_hi = math.inf, 0.0, math.inf
    for c in range(3):
        v = _kth_largest(short[..., c].ravel(), k_hl)
        if v > 0:  # the k_hl-th brightest short-level value must stay below hi_code
            hl_hi = min(
                hl_hi,
                _bisect_scale(lambda s, v=v, c=c: _code(v, c, s * dt_s, f) >= t.hi_code)
                * (1 - 1e-9),
            )
        v = _kth_largest(long_[..., c].ravel(), k_sat)
        sat_lo = max(
            sat_lo,
            _bisect_scale(lambda s, v=v, c=c: _code(v, c, s * dt_l, f) >= t.hi_code)
            if v > 0
            else math.inf,
        )
        v = _kth_smallest(short[..., c].ravel(), k_dark)
        if v > 0:  # the k_dark-th darkest short-level value must reach code <= lo_code
            dark_hi = min(
                dark_hi,
                _bisect_scale(lambda s, v=v, c=c: _code(v, c, s * dt_s, f) > t.lo_code)
                * (1 - 1e-9),
            )
    intervals["short_highlights"] = (0.0, hl_hi)
    intervals["long_saturated"] = (sat_lo, math.inf)
    intervals["short_dark"] = (0.0, dark_hi)

    # a relative margin inside every interval: gt/hdr stores scale * frame in float32 (rounding
    # ~6e-8)
    intervals = {
        k: (a * (1 + SCALE_MARGIN), b * (1 - SCALE_MARGIN)) for k, (a, b) in intervals.items()
    }
    lo, hi = intervals["mid_median"]
    given_up: List[str] = []
    for name in ("short_highlights", "long_saturated", "short_dark"):
        a, b = intervals[name]
        if max(lo, a) <= min(hi, b):
            lo, hi = max(lo, a), min(hi, b)
        else:
            given_up.append(name)
    if lo > hi:  # cannot happen unless the median window itself is empty (a flat image); aim anyway
        lo = hi = s_aim
    s = float(min(max(s_aim, lo), hi)) if math.isfinite(s_aim) else float(lo)

    # predicted statistics at s, with the real quantiser on every frame of each role
    stats = {lv: LevelStats.of(tonemap_ldr(arr[lv], s * lv, f), lv, t) for lv in {dt_s, dt_m, dt_l}}
    predicted = evaluate_targets(stats, t, levels)
    msg = (
        "all placement targets met"
        if not given_up
        else "cannot meet "
        + ", ".join(given_up)
        + " together with the middle-level median (intervals of s: "
        + "; ".join(f"{k} [{a:.4g}, {b:.4g}]" for k, (a, b) in intervals.items())
        + ")"
    )
    report = {
        "scale": s,
        "feasible": not given_up,
        "given_up": given_up,
        "message": msg,
        "intervals": {
            k: [float(a), float(b) if math.isfinite(b) else None] for k, (a, b) in intervals.items()
        },
        "aim_scale": float(s_aim),
        "predicted": predicted,
        "levels": roles,
        "crf": f.name,
        "targets": t.to_dict(),
    }
    return s, report


# --------------------------------------------------------------------------------------------------
# Measuring a written clip
# --------------------------------------------------------------------------------------------------
def measure_placement(clip_root, meta, targets: Optional[PlacementTargets] = None) -> dict:
    """What a written clip achieved, from its 8-bit PNGs: {source, levels {dt: LevelStats}, targets
    {name: {value, wanted, met}}, all_met, thresholds}.

    Each role's level is measured on the training frames taken at it (input/ldr); a role level that
    no training frame has (e.g. the random-values schedule) is measured on the test frames rendered
    at it (gt/ldr/<dt>) and the source says so."""
    t = targets or PlacementTargets()
    root = Path(clip_root)
    roles = level_roles(meta.exposures.observed)
    by_dt: Dict[float, List[int]] = {}
    for g, dt in zip(meta.split.train, meta.exposures.train_dt):
        by_dt.setdefault(float(dt), []).append(int(g))
    stats: Dict[float, LevelStats] = {}
    source: Dict[str, str] = {}
    for lv in roles.values():
        if lv in stats:
            continue
        if by_dt.get(lv):
            frames = np.stack(
                [mio.read_png(root / "input/ldr" / frame_name(g, "png")) for g in by_dt[lv]]
            )
            source[f"{lv:g}"] = "training frames (input/ldr)"
        else:
            frames = np.stack(
                [
                    mio.read_png(root / "gt/ldr" / level_name(lv) / frame_name(g, "png"))
                    for g in meta.split.test
                ]
            )
            source[f"{lv:g}"] = (
                f"test frames (gt/ldr/{level_name(lv)}): no training frame has this exposure"
            )
        stats[lv] = LevelStats.of(frames, lv, t)
    res = evaluate_targets(stats, t, meta.exposures.observed)
    return {
        "source": source,
        "levels": {f"{lv:g}": asdict(st) for lv, st in sorted(stats.items())},
        "targets": res,
        "all_met": all(v["met"] for v in res.values()),
        "thresholds": t.to_dict(),
    }


def placement_failures(placement: dict) -> List[str]:
    """Human-readable lines for the targets a measured placement misses (empty when all are met)."""
    return [
        f"{name}: {v['value']:.4g}, wanted {v['wanted']}"
        for name, v in placement.get("targets", {}).items()
        if not v.get("met")
    ]
