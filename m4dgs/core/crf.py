"""Analytic camera response functions (CRFs) and 8-bit tone mapping.

A CRF maps the exposure-scaled irradiance ``x = H * dt >= 0`` (linear, relative units) to an LDR
value in [0, 1].
The paper's synthetic protocol uses the HDR-NeRF curve (paper appendix "Syn-Exp-3")::

    f(x) = (x / (x + 1)) ** (1 / 2.2),        f(1) = 0.5 ** (1 / 2.2) = 0.72974...   (the
    unit-exposure value C0)

The response of a benchmark clip is a clip property (clip.json ``crf``), drawn from the clip family
``CLIP_CRFS`` (``clip_crf(name)`` returns one and refuses any other curve). Every family member is
strictly increasing on [0, inf), never clips (f < 1 for every finite x in exact arithmetic; 8-bit
white is reached at a finite x), has f(0) = 0 and a unit-exposure value f(1) in [0.68, 0.75], so the
unit-exposure loss of the trainer, which fixes the HDR scale through C0 = f(1), stays a useful
anchor (a curve that clips at x = 1 has f(1) = 1). Curves built from a published shape take an
exposure pre-scale ``a`` (x -> a x) chosen so that f(1) = C0_HDRNERF = 0.72974:

=============  ===============================================================
========================  =======
name           f(x)                                                             source
f(1)
=============  ===============================================================
========================  =======
hdrnerf        (x / (x + 1))^(1/2.2)   (default; the paper protocol)            HDR-NeRF synthetic
data   0.72974 srgb-shoulder  sRGB_OETF(1 - exp(-a x)), a = 0.676318                           IEC
61966-2-1 toe,        0.72974
                                                                                exponential shoulder
aces-filmic    sRGB_OETF(k ACES(a x)), ACES(u) = u (2.51 u + 0.03) /            Narkowicz's ACES fit
0.72974
               (u (2.43 u + 0.59) + 0.14), k = 2.43 / 2.51, a = 0.364130
hdrnerf-g1.8   (x / (x + 1))^(1/1.8)                                            gamma 1.8 (classic
Mac)   0.68040 hdrnerf-g2.4   (x / (x + 1))^(1/2.4)                                            gamma
2.4 (ITU-R BT.1886) 0.74915 hdrnerf-rgb    per channel (x / (x + k_c))^(1/g_c), g = (2.0, 2.2, 2.4),
per-channel responses     0.72974
               k_c = C0^(-g_c) - 1 = (0.87786, 1, 1.13008)                      (Debevec & Malik
               1997)    (all c)
=============  ===============================================================
========================  =======

Display encodings and building blocks that are NOT clip responses (they clip at x = 1, so f(1) = 1):

=========  ====================================================  ==================================
=========
name       f(x)                                                  inverse f^-1(y), y in (0, 1)
f(1)
=========  ====================================================  ==================================
=========
gamma      clip(x, 0, 1)^(1/2.2)                                 y^2.2
1 srgb       sRGB OETF (IEC 61966-2-1) of clip(x, 0, 1)            sRGB EOTF
1 mulog      log(1 + mu clip(x, 0, 1)) / log(1 + mu), mu = 5000    ((1 + mu)^y - 1) / mu
1 linear     clip(x, 0, 1)                                         y
1
=========  ====================================================  ==================================
=========

All curves are registered (``get_crf(name)``; ``available_crfs()`` lists them, ``register_crf`` adds
one). Every curve accepts numpy arrays, Python scalars (returned as numpy float64) and torch tensors
(returned as tensors of the same dtype and device); negative inputs are treated as 0. Inverses are
exact on (0, 1); the clipping curves return 1 for y = 1 (the lowest irradiance that saturates) and
the never-clipping clip curves return +inf at y = 1.

Per-channel curves (``hdrnerf-rgb``): ``crf.rgb(x)`` / ``crf.inverse_rgb(y)`` apply channel c's
curve to ``x[..., c]`` (``tonemap_ldr`` does so for [..., 3] images); ``crf(x)``, ``crf.inverse(y)``
and ``crf.unit_exposure_value`` are those of the reference channel, green (``crf.channel(c)`` gives
any channel). The shipped per-channel curve has the same f_c(1) in every channel (a white-balanced
camera renders a neutral grey at unit exposure as a neutral pixel), so clip.json's single
``unit_exposure_value`` is every channel's C0.

``tonemap_ldr(hdr, dt, crf)`` produces the 8-bit LDR frame ``floor(255 * f(H * dt) + 0.5)`` (round
half up), clipped to [0, 255], as uint8."""

from __future__ import annotations

import math
from typing import Callable, Dict, Optional, Sequence, Union

import numpy as np
import torch

from m4dgs.core.hdr import MU, mu_law, mu_law_inverse

ArrayLike = Union[np.ndarray, torch.Tensor, float]

#: exponent of the display gamma used by the hdrnerf and gamma curves
GAMMA = 2.2


def _is_torch(x) -> bool:
    return isinstance(x, torch.Tensor)


def _as_array(x):
    """Torch tensors pass through; everything else becomes a float64 numpy array."""
    if _is_torch(x):
        return x if x.is_floating_point() else x.to(torch.float32)
    return np.asarray(x, dtype=np.float64)


def _clip(x, lo, hi):
    return torch.clamp(x, lo, hi) if _is_torch(x) else np.clip(x, lo, hi)


def _where(c, a, b):
    return torch.where(c, a, b) if _is_torch(c) else np.where(c, a, b)


def _expm1(x):
    return torch.expm1(x) if _is_torch(x) else np.expm1(x)


def _ret(x):
    """Return numpy 0-d results as numpy float64 scalars."""
    if not _is_torch(x) and isinstance(x, np.ndarray) and x.ndim == 0:
        return np.float64(x)
    return x


class CRF:
    """A named camera response function with its inverse.

    Args:
        name: registry name. forward: f(x) for x >= 0 (already clamped to >= 0 by ``__call__``),
        numpy or torch in, same kind out. inverse: f^-1(y) for y in [0, 1] (already clamped to [0,
        1] by ``inverse``). description: one-line formula, shown in docs and clip metadata. source:
        where the curve comes from (recorded in clip.json). params: its parameters (JSON-able;
        recorded in clip.json). channels: for a per-channel curve, one CRF per colour channel (R, G,
        B); forward / inverse may then be None
            and are those of ``channels[reference_channel]``.
        reference_channel: the channel that ``__call__``, ``inverse`` and ``unit_exposure_value``
        use (green).
    """

    def __init__(
        self,
        name: str,
        forward: Optional[Callable],
        inverse: Optional[Callable],
        description: str = "",
        *,
        source: str = "",
        params: Optional[dict] = None,
        channels: Optional[Sequence["CRF"]] = None,
        reference_channel: int = 1,
    ):
        self.name = str(name)
        self.channels = None if channels is None else tuple(channels)
        self.reference_channel = int(reference_channel)
        if self.channels is not None:
            ref = self.channels[self.reference_channel]
            forward = forward or ref._forward
            inverse = inverse or ref._inverse
        self._forward = forward
        self._inverse = inverse
        self.description = description
        self.source = source
        self.params = dict(params or {})

    def __call__(self, x: ArrayLike):
        """f(x): exposure-scaled irradiance x = H * dt (>= 0; negatives count as 0) -> LDR value in
        [0, 1]."""
        x = _as_array(x)
        return _ret(self._forward(_clip(x, 0.0, None) if _is_torch(x) else np.maximum(x, 0.0)))

    def inverse(self, y: ArrayLike):
        """f^-1(y): LDR value in [0, 1] (clamped) -> exposure-scaled irradiance x >= 0."""
        y = _as_array(y)
        return _ret(self._inverse(_clip(y, 0.0, 1.0)))

    @property
    def per_channel(self) -> bool:
        """True when the colour channels have different curves."""
        return self.channels is not None

    def channel(self, c: int) -> "CRF":
        """The curve of colour channel c (the curve itself for a curve shared by all channels)."""
        return self if self.channels is None else self.channels[int(c)]

    def _per_channel_apply(self, v, fn_name: str):
        if self.channels is None:
            return getattr(self, fn_name)(v)
        v = _as_array(v)
        if v.ndim == 0 or v.shape[-1] != len(self.channels):
            raise ValueError(
                f"CRF {self.name!r}: rgb/inverse_rgb need a last axis of size "
                f"{len(self.channels)}, "
                f"got shape {tuple(v.shape)}"
            )
        parts = [getattr(ch, fn_name)(v[..., c]) for c, ch in enumerate(self.channels)]
        return torch.stack(parts, dim=-1) if _is_torch(v) else np.stack(parts, axis=-1)

    def rgb(self, x: ArrayLike):
        """Per-channel f: x [..., C] -> [..., C] with channel c's curve on x[..., c] (== f(x) for a
        shared curve)."""
        return self._per_channel_apply(x, "__call__")

    def inverse_rgb(self, y: ArrayLike):
        """Per-channel f^-1: y [..., C] -> [..., C]."""
        return self._per_channel_apply(y, "inverse")

    @property
    def unit_exposure_value(self) -> float:
        """f(1), the LDR value of unit exposure (C0 of the unit-exposure loss; the reference
        channel's)."""
        return float(self(1.0))

    @property
    def unit_exposure_values(self) -> tuple:
        """f_c(1) of every channel (three equal values for a shared curve)."""
        return tuple(float(self.channel(c)(1.0)) for c in range(3))

    def metadata(self) -> dict:
        """What clip.json records about the curve: name, formula, source, parameters, f(1) per
        channel."""
        return {
            "name": self.name,
            "description": self.description,
            "source": self.source,
            "params": self.params,
            "per_channel": self.per_channel,
            "unit_exposure_values": list(self.unit_exposure_values),
        }

    def __repr__(self) -> str:
        return f"CRF({self.name!r}: {self.description})"


# --------------------------------------------------------------------------------------------------
# The curves
# --------------------------------------------------------------------------------------------------
def _hdrnerf_f(x):
    return (x / (x + 1.0)) ** (1.0 / GAMMA)


def _hdrnerf_inv(y):
    u = y**GAMMA
    if _is_torch(u):
        return u / (1.0 - u)  # inf at u == 1 (torch division by zero gives inf)
    with np.errstate(divide="ignore"):
        return u / (1.0 - u)


def _gamma_f(x):
    return _clip(x, 0.0, 1.0) ** (1.0 / GAMMA)


def _gamma_inv(y):
    return y**GAMMA


def _srgb_f(x):
    x = _clip(x, 0.0, 1.0)
    hi = 1.055 * _clip(x, 0.0031308, 1.0) ** (1.0 / 2.4) - 0.055
    return _where(x <= 0.0031308, 12.92 * x, hi)


def _srgb_inv(y):
    hi = ((_clip(y, 0.04045, 1.0) + 0.055) / 1.055) ** 2.4
    return _where(y <= 0.04045, y / 12.92, hi)


def _linear_f(x):
    return _clip(x, 0.0, 1.0)


def _linear_inv(y):
    return y * 1.0


# --- the clip family (never clipping, f(1) in the mid range)
# ------------------------------------------------------ : f(1) of the HDR-NeRF curve; the exposure
# pre-scales of the published shapes below are chosen to reproduce it
C0_HDRNERF = 0.5 ** (1.0 / GAMMA)


def _exp(x):
    return torch.exp(x) if _is_torch(x) else np.exp(x)


def _sqrt(x):
    return torch.sqrt(x) if _is_torch(x) else np.sqrt(x)


def _div(a, b):
    """a / b with b == 0 -> +inf (a > 0), without numpy warnings."""
    if _is_torch(a) or _is_torch(b):
        return a / b
    with np.errstate(divide="ignore", invalid="ignore"):
        return a / b


def _srgb_eotf_scalar(y: float) -> float:
    return y / 12.92 if y <= 0.04045 else ((y + 0.055) / 1.055) ** 2.4


def _reinhard_gamma(k: float, g: float) -> tuple:
    """(forward, inverse) of f(x) = (x / (x + k))^(1/g), the HDR-NeRF form with knee k and display
    gamma g."""

    def f(x):
        return (x / (x + k)) ** (1.0 / g)

    def inv(y):
        u = y**g
        return k * _div(u, 1.0 - u)

    return f, inv


#: srgb-shoulder: exposure pre-scale a with sRGB_OETF(1 - exp(-a)) = C0_HDRNERF
SRGB_SHOULDER_A = -math.log(1.0 - _srgb_eotf_scalar(C0_HDRNERF))


def _srgb_shoulder_f(x):
    return _srgb_f(-_expm1(-SRGB_SHOULDER_A * x))


def _srgb_shoulder_inv(y):
    v = _srgb_inv(y)  # 1 - exp(-a x); log1p(-1) = -inf gives x = inf at y = 1
    if _is_torch(v):
        return -torch.log1p(-v) / SRGB_SHOULDER_A
    with np.errstate(divide="ignore"):
        return -np.log1p(-v) / SRGB_SHOULDER_A


# : Narkowicz's fit of the ACES reference rendering + output transform: u (A u + B) / (u (C u + D) +
# E)
ACES_FIT = (2.51, 0.03, 2.43, 0.59, 0.14)
# 1 / asymptote: the normalised fit tends to 1 instead of reaching it at u = 7.2
ACES_NORM = ACES_FIT[2] / ACES_FIT[0]


def _aces_fit(u):
    a, b, c, d, e = ACES_FIT
    return ACES_NORM * u * (a * u + b) / (u * (c * u + d) + e)


def _aces_fit_inv(v):
    """u >= 0 with _aces_fit(u) = v, v in [0, 1]: the positive root of (A - C w) u^2 + (B - D w) u -
    E w = 0, w = v / ACES_NORM, in the form free of cancellation on each side of B - D w = 0."""
    a, b, c, d, e = ACES_FIT
    w = v / ACES_NORM
    qa = _clip(a - c * w, 0.0, None)  # 0 at v = 1 (u = inf)
    qb = b - d * w
    disc = _sqrt(qb * qb + 4.0 * qa * e * w)
    big = _div(disc - qb, 2.0 * qa)  # qb < 0: no cancellation
    small = _div(2.0 * e * w, qb + disc)  # qb >= 0: no cancellation
    return _where(qb < 0, big, small)


def _solve_prescale(fn, target: float) -> float:
    """a with fn(a) = target for an increasing fn (bisection in log a; exact to double
    precision)."""
    lo, hi = 1e-6, 1e6
    for _ in range(200):
        mid = math.sqrt(lo * hi)
        if float(fn(np.float64(mid))) < target:
            lo = mid
        else:
            hi = mid
    return math.sqrt(lo * hi)


#: aces-filmic: exposure pre-scale a with sRGB_OETF(ACES_NORM * ACES(a)) = C0_HDRNERF
ACES_FILMIC_A = _solve_prescale(_aces_fit, _srgb_eotf_scalar(C0_HDRNERF))


def _aces_filmic_f(x):
    return _srgb_f(_aces_fit(ACES_FILMIC_A * x))


def _aces_filmic_inv(y):
    return _aces_fit_inv(_srgb_inv(y)) / ACES_FILMIC_A


#: hdrnerf-rgb: display gammas of R, G, B; each knee k_c = C0^(-g_c) - 1 keeps f_c(1) = C0_HDRNERF
RGB_GAMMAS = (2.0, 2.2, 2.4)
RGB_KNEES = tuple(C0_HDRNERF ** (-g) - 1.0 for g in RGB_GAMMAS)


_REGISTRY: Dict[str, CRF] = {}


def register_crf(crf: CRF, overwrite: bool = False) -> CRF:
    """Add a curve to the registry (so that clip.json may name it)."""
    if crf.name in _REGISTRY and not overwrite:
        raise ValueError(f"CRF {crf.name!r} is already registered")
    _REGISTRY[crf.name] = crf
    return crf


register_crf(
    CRF(
        "hdrnerf",
        _hdrnerf_f,
        _hdrnerf_inv,
        "(x / (x + 1)) ** (1 / 2.2)",
        source="HDR-NeRF (Huang et al., CVPR 2022) synthetic data; the paper's Syn-Exp-3 protocol",
        params={"k": 1.0, "gamma": GAMMA},
    )
)
register_crf(
    CRF(
        "srgb-shoulder",
        _srgb_shoulder_f,
        _srgb_shoulder_inv,
        f"sRGB_OETF(1 - exp(-{SRGB_SHOULDER_A:.6f} x))",
        source="sRGB OETF (IEC 61966-2-1: linear toe 12.92 x, 1.055 v^(1/2.4) - 0.055) after an "
        "exponential "
        "highlight shoulder 1 - exp(-a x) (the exponential global tone-mapping operator); 8-bit "
        "white 3 stops above unit exposure, like a camera JPEG",
        params={"a": SRGB_SHOULDER_A},
    )
)
register_crf(
    CRF(
        "aces-filmic",
        _aces_filmic_f,
        _aces_filmic_inv,
        f"sRGB_OETF({ACES_NORM:.6f} u (2.51 u + 0.03) / (u (2.43 u + 0.59) + 0.14)), "
        f"u = {ACES_FILMIC_A:.6f} x",
        source="ACES filmic curve, K. Narkowicz's 2016 fit of the ACES RRT + ODT (a = 2.51, b = "
        "0.03, "
        "c = 2.43, d = 0.59, e = 0.14), divided by its asymptote a / c so that it never clips, "
        "then the sRGB OETF (IEC 61966-2-1)",
        params={"a": ACES_FILMIC_A, "fit": list(ACES_FIT), "norm": ACES_NORM},
    )
)
for _g in (1.8, 2.4):
    _f, _inv = _reinhard_gamma(1.0, _g)
    register_crf(
        CRF(
            f"hdrnerf-g{_g:g}",
            _f,
            _inv,
            f"(x / (x + 1)) ** (1 / {_g:g})",
            source=(
                "HDR-NeRF curve with display gamma 1.8 (classic Macintosh)"
                if _g == 1.8
                else "HDR-NeRF curve with display gamma 2.4 (ITU-R BT.1886 EOTF exponent)"
            ),
            params={"k": 1.0, "gamma": _g},
        )
    )
_rgb = []
for _c, (_k, _g) in enumerate(zip(RGB_KNEES, RGB_GAMMAS)):
    _f, _inv = _reinhard_gamma(_k, _g)
    _rgb.append(CRF(f"hdrnerf-rgb[{'RGB'[_c]}]", _f, _inv, f"(x / (x + {_k:.5f})) ** (1 / {_g:g})"))
register_crf(
    CRF(
        "hdrnerf-rgb",
        None,
        None,
        "per channel (x / (x + k_c)) ** (1 / g_c), g = (2.0, 2.2, 2.4), k_c = C0^(-g_c) - 1",
        source="per-channel responses as recovered from real cameras (Debevec & Malik, SIGGRAPH "
        "1997, "
        "recover R, G, B curves separately); HDR-NeRF form with gammas 2.0 / 2.2 / 2.4 and knees "
        "that keep a neutral grey neutral at unit exposure (illustrative spread, not a measured "
        "camera)",
        params={"gammas": list(RGB_GAMMAS), "knees": list(RGB_KNEES)},
        channels=_rgb,
    )
)
del _g, _f, _inv, _c, _k, _rgb
register_crf(CRF("gamma", _gamma_f, _gamma_inv, "clip(x, 0, 1) ** (1 / 2.2)"))
register_crf(CRF("srgb", _srgb_f, _srgb_inv, "sRGB OETF of clip(x, 0, 1)"))
register_crf(
    CRF(
        "mulog",
        mu_law,  # m4dgs.core.hdr: the metrics' mu-law curve as a response
        mu_law_inverse,
        f"log(1 + {MU:g} clip(x, 0, 1)) / log(1 + {MU:g})",
    )
)
register_crf(CRF("linear", _linear_f, _linear_inv, "clip(x, 0, 1)"))

#: name of the default synthetic CRF (HDR-NeRF protocol)
DEFAULT_CRF = "hdrnerf"

#: the responses a benchmark clip may have (module docstring); the paper's HDR-NeRF curve first
CLIP_CRFS = (
    "hdrnerf",
    "srgb-shoulder",
    "aces-filmic",
    "hdrnerf-g1.8",
    "hdrnerf-g2.4",
    "hdrnerf-rgb",
)


def available_crfs() -> list:
    """Names of the registered curves."""
    return sorted(_REGISTRY)


def get_crf(name: Union[str, CRF, None] = DEFAULT_CRF) -> CRF:
    """The registered CRF called ``name`` (a CRF object passes through; None gives the default)."""
    if isinstance(name, CRF):
        return name
    if name is None:
        name = DEFAULT_CRF
    try:
        return _REGISTRY[str(name)]
    except KeyError:
        raise KeyError(f"unknown CRF {name!r}; available: {', '.join(available_crfs())}") from None


def clip_crf(name: Union[str, CRF, None] = DEFAULT_CRF) -> CRF:
    """A curve of the clip family CLIP_CRFS (benchgen clips are tone-mapped with one); any other
    name is refused."""
    f = get_crf(name)
    if f.name not in CLIP_CRFS:
        raise ValueError(
            f"CRF {f.name!r} is not a clip response (f(1) = {f.unit_exposure_value:.4g}); "
            f"the clip family is {', '.join(CLIP_CRFS)}"
        )
    return f


def log_logistic(c0: float, slope: float = 0.5) -> CRF:
    """Generic curve anchored only at f(1) = c0: f(x) = c0 x^s / (c0 x^s + 1 - c0), s = slope.

    It is a logistic in the tone mapper's own input log2 x (sigmoid(s ln2 log2 x + logit c0)), i.e.
    the Naka-Rushton response x^s / (x^s + sigma^s) with sigma^s = (1 - c0) / c0 (Naka & Rushton
    1966; the photoreceptor tone-mapping operator of Reinhard & Devlin 2005 builds on it). The
    trainer's default pre-training target (m4dgs.training.stage1.pretrain_curve)."""
    c0, s = float(c0), float(slope)
    if not (0.0 < c0 < 1.0 and s > 0.0):
        raise ValueError(f"log_logistic needs 0 < c0 < 1 and slope > 0, got c0={c0!r}, slope={s!r}")
    r = (1.0 - c0) / c0

    def f(x):
        p = x**s
        return p / (p + r)

    def inv(y):
        return (r * _div(y, 1.0 - y)) ** (1.0 / s)

    return CRF(
        "log-logistic",
        f,
        inv,
        f"x^{s:g} / (x^{s:g} + {r:.5f})",
        source="Naka-Rushton / log-logistic",
        params={"c0": c0, "slope": s},
    )


def reinhard_anchored(c0: float, gamma: float = GAMMA) -> CRF:
    """(x / (x + k))^(1/gamma) with k = c0^(-gamma) - 1, so f(1) = c0: for c0 = 0.72974 exactly the
    hdrnerf curve (the trainer's former pre-training target, option "reinhard-c0")."""
    c0 = float(c0)
    if not 0.0 < c0 < 1.0:
        raise ValueError(f"reinhard_anchored needs 0 < c0 < 1, got {c0!r}")
    k = c0 ** (-gamma) - 1.0
    f, inv = _reinhard_gamma(k, gamma)
    return CRF(
        "reinhard-c0", f, inv, f"(x / (x + {k:.5f})) ** (1 / {gamma:g})", params={"c0": c0, "k": k}
    )


def quantize_ldr(ldr: ArrayLike):
    """LDR values in [0, 1] -> 8-bit codes floor(255 * v + 0.5) clipped to [0, 255] (uint8; numpy or
    torch)."""
    v = _as_array(ldr)
    if _is_torch(v):
        return torch.clamp(torch.floor(v * 255.0 + 0.5), 0, 255).to(torch.uint8)
    return np.clip(np.floor(v * 255.0 + 0.5), 0, 255).astype(np.uint8)


def tonemap_ldr(hdr: ArrayLike, dt: float, crf: Union[str, CRF] = DEFAULT_CRF):
    """8-bit LDR image of linear HDR irradiance seen with exposure time dt.

    Args:
        hdr: [..., C] linear HDR irradiance (>= 0), numpy or torch.
        dt: exposure time (relative units, > 0).
        crf: a CRF or its registry name.
    Returns:
        uint8 array of the same shape (numpy in -> numpy out, torch in -> torch out): floor(255 *
        f(H * dt) + 0.5); a per-channel curve applies channel c's curve to hdr[..., c] when the last
        axis has 3 channels.
    """
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"exposure time must be finite and > 0, got {dt!r}")
    f = get_crf(crf)
    h = _as_array(hdr)
    if not _is_torch(h):
        h = h.astype(np.float64, copy=False)
    if f.per_channel and h.ndim > 0 and h.shape[-1] == len(f.channels):
        return quantize_ldr(f.rgb(h * float(dt)))
    return quantize_ldr(f(h * float(dt)))
