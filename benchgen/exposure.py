"""Exposure levels, training-frame exposure schedules and the per-clip HDR scale (docs/exposure.md).

The input video is tone-mapped with a CRF (``m4dgs.crf``, HDR-NeRF by default) and quantised to 8 bits:
``LDR_g = floor(255 * f(s * H_g * dt_g) + 0.5)`` where ``H_g`` is the rendered linear HDR frame, ``s`` the clip's
single HDR scale (``choose_hdr_scale``, recorded in clip.json ``hdr_scale``) and ``dt_g`` the frame's exposure time.

Presets (DESIGN.md "Conventions"; HDR-NeRF's ladder 0.125, 0.5, 2, 8, 32 — two stops apart):

* ``--exposures 3``: observed {0.125, 2, 32}, novel {0.5, 8} (HDR-NeRF / Syn-Exp-3 protocol).
* ``--exposures 2``: observed {0.5, 8}, novel {0.125, 2, 32}: a 4-stop bracket (+-2 EV around 2, the geometric
  middle of the ladder, like the 2-exposure alternating videos of Real-Exp-2), one interpolated novel level (2) and
  the two extrapolated ends of the same ladder, so the novel LDR folders share names with the 3-level suite.

Schedules of the training frames (paper appendix "Other Exposure Schedules"):

* ``alternating`` (default): observed levels in the given order, repeated: [a, b, c, a, b, c, ...].
* ``random-order``: a random permutation of a balanced multiset of the observed levels (each level equally often;
  when the frame count is not a multiple of the level count the extra frames take distinct random levels).
* ``random-values``: log-uniform values between the shortest and the longest observed level.

Test frames are rendered at every observed and every novel level (``test_levels``). Exposure-value perturbation
(paper Table "random exposure perturbation") is a trainer option, never a property of the clip.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from m4dgs.crf import CRF, get_crf

SCHEDULES = ("alternating", "random-order", "random-values")

#: observed / novel levels of the presets, keyed by --exposures
PRESET_LEVELS: Dict[int, Tuple[Tuple[float, ...], Tuple[float, ...]]] = {
    3: ((0.125, 2.0, 32.0), (0.5, 8.0)),
    2: ((0.5, 8.0), (0.125, 2.0, 32.0)),
}


@dataclass(frozen=True)
class ExposureSettings:
    """Exposure levels of a clip.

    observed: exposure times (relative units, > 0) used on training frames, in schedule order.
    novel:    exposure times seen only on test frames (may be empty).
    schedule: one of SCHEDULES.
    """

    observed: Tuple[float, ...] = PRESET_LEVELS[3][0]
    novel: Tuple[float, ...] = PRESET_LEVELS[3][1]
    schedule: str = "alternating"

    def __post_init__(self):
        obs = tuple(float(v) for v in self.observed)
        nov = tuple(float(v) for v in self.novel)
        object.__setattr__(self, "observed", obs)
        object.__setattr__(self, "novel", nov)
        if not obs:
            raise ValueError("ExposureSettings.observed: at least one level is needed")
        for name, levels in (("observed", obs), ("novel", nov)):
            for v in levels:
                if not (math.isfinite(v) and v > 0):
                    raise ValueError(f"ExposureSettings.{name}: exposure must be finite and > 0, got {v!r}")
            if len(set(levels)) != len(levels):
                raise ValueError(f"ExposureSettings.{name}: duplicate level in {levels}")
        if set(obs) & set(nov):
            raise ValueError(f"ExposureSettings: levels {sorted(set(obs) & set(nov))} are both observed and novel")
        if self.schedule not in SCHEDULES:
            raise ValueError(f"ExposureSettings.schedule: expected one of {SCHEDULES}, got {self.schedule!r}")

    @property
    def num_levels(self) -> int:
        """N_e: the number of observed levels."""
        return len(self.observed)

    @property
    def shortest(self) -> float:
        return min(self.observed)

    @property
    def longest(self) -> float:
        return max(self.observed)

    @property
    def middle(self) -> float:
        """Geometric middle of the observed range, sqrt(shortest * longest) (= 2 for both presets)."""
        return math.sqrt(self.shortest * self.longest)

    def to_dict(self) -> dict:
        return {"observed": list(self.observed), "novel": list(self.novel), "schedule": self.schedule}


def exposure_preset(num_exposures: int = 3, schedule: str = "alternating", observed: Optional[Sequence[float]] = None,
                    novel: Optional[Sequence[float]] = None) -> ExposureSettings:
    """Settings for ``--exposures N`` (2 or 3) with optional overrides of the observed and/or novel levels."""
    if observed is None and num_exposures not in PRESET_LEVELS:
        raise ValueError(f"--exposures {num_exposures}: presets exist for {sorted(PRESET_LEVELS)}; give observed levels")
    obs_p, nov_p = PRESET_LEVELS.get(num_exposures, ((), ()))
    obs = tuple(observed) if observed is not None else obs_p
    if novel is not None:
        nov = tuple(novel)
    elif observed is None:
        nov = nov_p
    else:  # overridden observed levels: keep the preset novel levels that do not collide
        nov = tuple(v for v in nov_p if float(v) not in {float(o) for o in obs})
    return ExposureSettings(observed=obs, novel=nov, schedule=schedule)


def parse_levels(text: str) -> Tuple[float, ...]:
    """'0.125,2,32' -> (0.125, 2.0, 32.0) (for CLI overrides)."""
    return tuple(float(t) for t in str(text).replace(" ", "").split(",") if t)


def test_levels(settings: ExposureSettings) -> List[float]:
    """Every level a test frame is rendered at: observed + novel, ascending."""
    return sorted(set(settings.observed) | set(settings.novel))


test_levels.__test__ = False  # not a pytest test


def schedule_train_dt(num_train: int, settings: ExposureSettings, seed: int = 0) -> List[float]:
    """Exposure time of each training frame (in training-frame order).

    alternating:   observed[i % N_e] (deterministic, seed unused).
    random-order:  numpy Generator(seed).permutation of [each level repeated num_train // N_e times] plus
                   num_train % N_e distinct levels drawn without replacement.
    random-values: exp(U(log shortest, log longest)) per frame, numpy Generator(seed).
    """
    n = int(num_train)
    if n < 0:
        raise ValueError(f"num_train must be >= 0, got {num_train}")
    levels = list(settings.observed)
    ne = len(levels)
    if settings.schedule == "alternating":
        return [levels[i % ne] for i in range(n)]
    rng = np.random.default_rng(seed)
    if settings.schedule == "random-order":
        bag = levels * (n // ne)
        extra = rng.choice(ne, size=n % ne, replace=False) if n % ne else np.zeros(0, int)
        bag += [levels[int(i)] for i in extra]
        perm = rng.permutation(len(bag))
        return [bag[int(i)] for i in perm]
    lo, hi = math.log(settings.shortest), math.log(settings.longest)
    return [float(v) for v in np.exp(rng.uniform(lo, hi, size=n))]


# ----------------------------------------------------------------------------------------------------------------
# HDR scale
# ----------------------------------------------------------------------------------------------------------------
def _max_channel_sample(hdr_frames_sample, max_pixels: int) -> np.ndarray:
    """Per-pixel max over channels of every given frame, subsampled with a fixed stride to <= max_pixels."""
    if isinstance(hdr_frames_sample, np.ndarray):
        frames = [hdr_frames_sample]
    else:
        frames = list(hdr_frames_sample)
    parts = []
    for fr in frames:
        a = np.asarray(fr, dtype=np.float64)
        if a.ndim >= 3 and a.shape[-1] in (1, 3, 4):
            a = a[..., :3].max(axis=-1)
        parts.append(a.reshape(-1))
    m = np.concatenate(parts) if parts else np.zeros(0)
    if m.size == 0:
        raise ValueError("choose_hdr_scale: empty HDR sample")
    if not np.isfinite(m).all() or (m < 0).any():
        raise ValueError("choose_hdr_scale: HDR sample must be finite and >= 0")
    if m.size > max_pixels:
        m = m[:: int(math.ceil(m.size / max_pixels))]
    return m


def choose_hdr_scale(hdr_frames_sample, settings: ExposureSettings, crf: Union[str, CRF] = "hdrnerf", *,
                     target_saturated: float = 0.005, target_black: float = 0.005, median_target: float = 0.5,
                     priority: str = "saturation", max_pixels: int = 4_000_000) -> Tuple[float, dict]:
    """One global HDR scale s for a clip so that the clip genuinely needs exposure merging.

    A pixel (of a frame tone-mapped with ``tonemap_ldr(s * H, dt, crf)``) counts as *saturated* when its brightest
    channel is 255 and as *black* when all its channels are 0. The wanted scale satisfies

        fraction saturated at the longest observed level  >= target_saturated      (needs s >= s_sat)
        fraction black at the shortest observed level     >= target_black          (needs s <= s_black)

    and, inside [s_sat, s_black], puts the median brightest channel at LDR ``median_target`` at the middle level
    sqrt(shortest * longest) (s_mid). When the scene's dynamic range is too small for both (s_sat > s_black) the
    ``priority`` decides: "saturation" (default; s = s_sat: the smallest scale that still saturates, so as many
    pixels as possible go black), "black" (s = s_black), or "median" (s_mid clipped to [s_black, s_sat]). The result
    says so honestly (``feasible`` False, ``message``).

    Note that black at the shortest level is demanding with the hdrnerf CRF: code 0 needs x = s H dt < f^-1(0.5/255)
    = 1.1e-6, i.e. about 19.6 stops between the brightest and darkest pixel percentiles for the 3-level preset
    (``required_range_stops``), which only scenes with deep shadows or unlit regions reach.

    Args:
        hdr_frames_sample: one [H, W, 3] frame, an array [T, H, W, 3], or a list of frames (linear HDR, >= 0).
        settings: the clip's exposure settings.
        crf: the CRF (or its name) the clip is tone-mapped with.
        target_saturated, target_black: wanted pixel fractions (0..1).
        median_target: wanted LDR value (0..1) of the median pixel's brightest channel at the middle level.
        priority: "saturation" | "black" | "median" (only used when both targets cannot be met).
        max_pixels: the pixel sample is strided down to at most this many pixels.
    Returns:
        (scale, report) with report = {scale, feasible, message, saturated_fraction (at the longest level),
        black_fraction (at the shortest level), median_ldr (median brightest-channel LDR value at the middle level,
        0..1), s_saturation, s_black, s_median, required_range_stops, available_range_stops, longest, shortest,
        middle, targets}.
    """
    if priority not in ("saturation", "black", "median"):
        raise ValueError(f"priority must be 'saturation', 'black' or 'median', got {priority!r}")
    f = get_crf(crf)
    m = _max_channel_sample(hdr_frames_sample, max_pixels)
    n = m.size
    dt_long, dt_short, dt_mid = settings.longest, settings.shortest, settings.middle
    # exposure thresholds of the codes: 255 needs f(x) >= 254.5/255, 0 needs f(x) < 0.5/255
    x_sat = float(f.inverse(254.5 / 255.0))
    x_blk = float(f.inverse(0.5 / 255.0))
    x_mid = float(f.inverse(median_target))
    ms = np.sort(m)
    positive = ms[ms > 0]
    if positive.size == 0:
        raise ValueError("choose_hdr_scale: the HDR sample is entirely black")
    # saturation: the brightest ceil(target * n) pixels must reach x_sat at dt_long
    k_sat = max(1, int(math.ceil(target_saturated * n)))
    q_hi = ms[n - k_sat]
    s_sat = (x_sat / (dt_long * q_hi)) * (1.0 + 1e-9) if q_hi > 0 else math.inf
    # black: the darkest ceil(target * n) pixels must stay below x_blk at dt_short (zeros are black at any scale)
    k_blk = max(1, int(math.ceil(target_black * n)))
    q_lo = ms[k_blk - 1]
    s_blk = (x_blk / (dt_short * q_lo)) * (1.0 - 1e-9) if q_lo > 0 else math.inf
    s_mid = x_mid / (dt_mid * float(np.median(positive)))
    feasible = s_sat <= s_blk
    if feasible:
        s = min(max(s_mid, s_sat), s_blk)
        msg = "both targets met"
    else:
        if priority == "saturation":
            s = s_sat
        elif priority == "black":
            s = s_blk
        else:
            s = min(max(s_mid, s_blk), s_sat)
        msg = (f"dynamic range too small for both targets: saturation needs s >= {s_sat:.4g}, black needs "
               f"s <= {s_blk:.4g}; chose s by priority '{priority}'")
    if not math.isfinite(s):
        s = s_mid
    # measure what was achieved with the actual quantiser
    from m4dgs.crf import quantize_ldr  # local: keep the module namespace small

    sat = float(np.mean(quantize_ldr(f(m * s * dt_long)) == 255))
    blk = float(np.mean(quantize_ldr(f(m * s * dt_short)) == 0))
    med = float(quantize_ldr(f(np.median(positive) * s * dt_mid))) / 255.0
    required = math.log2((x_sat / dt_long) / (x_blk / dt_short))
    available = math.log2(q_hi / q_lo) if q_lo > 0 else math.inf
    report = {
        "scale": float(s), "feasible": bool(feasible), "message": msg,
        "saturated_fraction": sat, "black_fraction": blk, "median_ldr": med,
        "s_saturation": float(s_sat), "s_black": float(s_blk), "s_median": float(s_mid),
        "required_range_stops": float(required), "available_range_stops": float(available),
        "longest": dt_long, "shortest": dt_short, "middle": dt_mid,
        "targets": {"saturated": target_saturated, "black": target_black, "median_ldr": median_target},
        "crf": f.name, "num_pixels": int(n),
    }
    return float(s), report


def exposure_gap_ev(dt_a: float, dt_b: float) -> float:
    """|log2(dt_a / dt_b)|: exposure difference in stops (EV)."""
    return abs(math.log2(float(dt_a) / float(dt_b)))
