"""Exposure levels, training-frame exposure schedules and the per-clip HDR scale (docs/exposure.md).

The input video is tone-mapped with a CRF (``m4dgs.core.crf``, HDR-NeRF by default) and quantised to
8 bits: ``LDR_g = floor(255 * f(s * H_g * dt_g) + 0.5)`` where ``H_g`` is the rendered linear HDR
frame, ``s`` the clip's single HDR scale (``benchgen.placement.choose_hdr_scale``, recorded in
clip.json ``hdr_scale``) and ``dt_g`` the frame's exposure time.

Presets (docs/exposure.md "Levels"; HDR-NeRF's ladder 0.125, 0.5, 2, 8, 32 — two stops apart):

* ``--exposures 3``: observed {0.125, 2, 32}, novel {0.5, 8} (HDR-NeRF / Syn-Exp-3 protocol).
* ``--exposures 2``: observed {0.5, 8}, novel {0.125, 2, 32}: a 4-stop bracket (+-2 EV around 2, the
  geometric middle of the ladder, like the 2-exposure alternating videos of Real-Exp-2), one
  interpolated novel level (2) and the two extrapolated ends of the same ladder, so the novel LDR
  folders share names with the 3-level suite.

Schedules of the training frames (paper appendix "Other Exposure Schedules"):

* ``alternating`` (default): observed levels in the given order, repeated: [a, b, c, a, b, c, ...].
* ``random-order``: a random permutation of a balanced multiset of the observed levels (each level
  equally often; when the frame count is not a multiple of the level count the extra frames take
  distinct random levels).
* ``random-values``: log-uniform values between the shortest and the longest observed level.
* ``random-values-banded`` (not in the paper; a control, docs/exposure.md): the random-order
  schedule with each frame's value moved off its level by a log-uniform amount within half a stop,
  reflected back into the observed range at its ends. Every value is new, as in random-values, but
  each level's band holds as many frames as in the alternating schedule, so the ends of the range
  (the shortest exposure records the highlights unclipped) are covered as often.

Test frames are rendered at every observed and every novel level (``test_levels``). Exposure-value
perturbation (paper Table "random exposure perturbation") is a trainer option, never a property of
the clip."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, Iterable, List, Optional, Sequence, Tuple

import numpy as np

SCHEDULES = ("alternating", "random-order", "random-values", "random-values-banded")
#: half-width, in stops, of a level's band in the random-values-banded schedule
BAND_HALF_WIDTH_EV = 0.5

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
                    raise ValueError(
                        f"ExposureSettings.{name}: exposure must be finite and > 0, got {v!r}"
                    )
            if len(set(levels)) != len(levels):
                raise ValueError(f"ExposureSettings.{name}: duplicate level in {levels}")
        if set(obs) & set(nov):
            raise ValueError(
                f"ExposureSettings: levels {sorted(set(obs) & set(nov))} are both observed and "
                "novel"
            )
        if self.schedule not in SCHEDULES:
            raise ValueError(
                f"ExposureSettings.schedule: expected one of {SCHEDULES}, got {self.schedule!r}"
            )

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
        """Geometric middle of the observed range, sqrt(shortest * longest) (= 2 for both
        presets)."""
        return math.sqrt(self.shortest * self.longest)

    def to_dict(self) -> dict:
        return {
            "observed": list(self.observed),
            "novel": list(self.novel),
            "schedule": self.schedule,
        }


def exposure_preset(
    num_exposures: int = 3,
    schedule: str = "alternating",
    observed: Optional[Sequence[float]] = None,
    novel: Optional[Sequence[float]] = None,
) -> ExposureSettings:
    """Settings for ``--exposures N`` (2 or 3) with optional overrides of the observed and/or novel
    levels."""
    if observed is None and num_exposures not in PRESET_LEVELS:
        raise ValueError(
            f"--exposures {num_exposures}: presets exist for {sorted(PRESET_LEVELS)}; give "
            "observed levels"
        )
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

    alternating:   observed[i % N_e] (deterministic, seed unused). random-order:  numpy
    Generator(seed).permutation of [each level repeated num_train // N_e times] plus
                   num_train % N_e distinct levels drawn without replacement.
    random-values: exp(U(log shortest, log longest)) per frame, numpy Generator(seed).
    random-values-banded: the random-order list, then log2 of each value moved by
                   U(-BAND_HALF_WIDTH_EV, +BAND_HALF_WIDTH_EV) and reflected into [log2 shortest,
                   log2 longest] (the same Generator, after the permutation).
    """
    n = int(num_train)
    if n < 0:
        raise ValueError(f"num_train must be >= 0, got {num_train}")
    levels = list(settings.observed)
    ne = len(levels)
    if settings.schedule == "alternating":
        return [levels[i % ne] for i in range(n)]
    rng = np.random.default_rng(seed)
    if settings.schedule in ("random-order", "random-values-banded"):
        bag = levels * (n // ne)
        extra = rng.choice(ne, size=n % ne, replace=False) if n % ne else np.zeros(0, int)
        bag += [levels[int(i)] for i in extra]
        perm = rng.permutation(len(bag))
        order = [bag[int(i)] for i in perm]
        if settings.schedule == "random-order":
            return order
        lo, hi = math.log2(settings.shortest), math.log2(settings.longest)
        ev = np.log2(np.asarray(order, float)) + rng.uniform(
            -BAND_HALF_WIDTH_EV, BAND_HALF_WIDTH_EV, size=n
        )
        ev = np.where(ev < lo, 2 * lo - ev, ev)
        ev = np.where(ev > hi, 2 * hi - ev, ev)
        return [float(v) for v in np.exp2(ev)]
    lo, hi = math.log(settings.shortest), math.log(settings.longest)
    return [float(v) for v in np.exp(rng.uniform(lo, hi, size=n))]


def exposure_gap_ev(dt_a: float, dt_b: float) -> float:
    """|log2(dt_a / dt_b)|: exposure difference in stops (EV)."""
    return abs(math.log2(float(dt_a) / float(dt_b)))


def dynamic_range_stops(hdr_frames: Iterable[np.ndarray]) -> float:
    """log2 of the ratio between the 99.99th and 0.01th percentiles of positive luminance (Rec. 709
    weights) over the given linear HDR frames [H, W, 3] (clip.json gt.dynamic_range_stops)."""
    lum = np.concatenate(
        [(0.2126 * h[..., 0] + 0.7152 * h[..., 1] + 0.0722 * h[..., 2]).ravel() for h in hdr_frames]
    )
    lum = lum[lum > 0]
    if lum.size == 0:
        return 0.0
    lo, hi = np.percentile(lum, [0.01, 99.99])
    return float(np.log2(hi / max(lo, 1e-12)))
