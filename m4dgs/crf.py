"""Analytic camera response functions (CRFs) and 8-bit tone mapping.

A CRF maps the exposure-scaled irradiance ``x = H * dt >= 0`` (linear, relative units) to an LDR value in [0, 1].
The synthetic benchmark uses the HDR-NeRF curve (paper appendix "Syn-Exp-3", DESIGN.md "Conventions")::

    f(x) = (x / (x + 1)) ** (1 / 2.2),        f(1) = 0.5 ** (1 / 2.2) = 0.72974...   (the unit-exposure value C0)

Registered curves (``get_crf(name)``; ``available_crfs()`` lists them, ``register_crf`` adds one):

=========  ====================================================  ==================================  =========
name       f(x)                                                  inverse f^-1(y), y in (0, 1)         f(1)
=========  ====================================================  ==================================  =========
hdrnerf    (x / (x + 1))^(1/2.2)   (never clips; default)         u / (1 - u), u = y^2.2              0.72974
gamma      clip(x, 0, 1)^(1/2.2)                                 y^2.2                               1
srgb       sRGB OETF (IEC 61966-2-1) of clip(x, 0, 1)            sRGB EOTF                           1
mulog      log(1 + mu clip(x, 0, 1)) / log(1 + mu), mu = 5000    ((1 + mu)^y - 1) / mu               1
linear     clip(x, 0, 1)                                         y                                   1
=========  ====================================================  ==================================  =========

Every curve accepts numpy arrays, Python scalars (returned as numpy float64) and torch tensors (returned as tensors
of the same dtype and device); negative inputs are treated as 0. Inverses are exact on (0, 1); the clipping curves
return 1 for y = 1 (the lowest irradiance that saturates) and hdrnerf returns +inf at y = 1.

``tonemap_ldr(hdr, dt, crf)`` produces the 8-bit LDR frame ``floor(255 * f(H * dt) + 0.5)`` (round half up), clipped
to [0, 255], as uint8.
"""
from __future__ import annotations

import math
from typing import Callable, Dict, Union

import numpy as np
import torch

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


def _log1p(x):
    return torch.log1p(x) if _is_torch(x) else np.log1p(x)


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
        name: registry name.
        forward: f(x) for x >= 0 (already clamped to >= 0 by ``__call__``), numpy or torch in, same kind out.
        inverse: f^-1(y) for y in [0, 1] (already clamped to [0, 1] by ``inverse``).
        description: one-line formula, shown in docs and clip metadata.
    """

    def __init__(self, name: str, forward: Callable, inverse: Callable, description: str = ""):
        self.name = str(name)
        self._forward = forward
        self._inverse = inverse
        self.description = description

    def __call__(self, x: ArrayLike):
        """f(x): exposure-scaled irradiance x = H * dt (>= 0; negatives count as 0) -> LDR value in [0, 1]."""
        x = _as_array(x)
        return _ret(self._forward(_clip(x, 0.0, None) if _is_torch(x) else np.maximum(x, 0.0)))

    def inverse(self, y: ArrayLike):
        """f^-1(y): LDR value in [0, 1] (clamped) -> exposure-scaled irradiance x >= 0."""
        y = _as_array(y)
        return _ret(self._inverse(_clip(y, 0.0, 1.0)))

    @property
    def unit_exposure_value(self) -> float:
        """f(1), the LDR value of unit exposure (C0 of the unit-exposure loss)."""
        return float(self(1.0))

    def __repr__(self) -> str:
        return f"CRF({self.name!r}: {self.description})"


# ----------------------------------------------------------------------------------------------------------------
# The curves
# ----------------------------------------------------------------------------------------------------------------
def _hdrnerf_f(x):
    return (x / (x + 1.0)) ** (1.0 / GAMMA)


def _hdrnerf_inv(y):
    u = y ** GAMMA
    if _is_torch(u):
        return u / (1.0 - u)  # inf at u == 1 (torch division by zero gives inf)
    with np.errstate(divide="ignore"):
        return u / (1.0 - u)


def _gamma_f(x):
    return _clip(x, 0.0, 1.0) ** (1.0 / GAMMA)


def _gamma_inv(y):
    return y ** GAMMA


def _srgb_f(x):
    x = _clip(x, 0.0, 1.0)
    hi = 1.055 * _clip(x, 0.0031308, 1.0) ** (1.0 / 2.4) - 0.055
    return _where(x <= 0.0031308, 12.92 * x, hi)


def _srgb_inv(y):
    hi = ((_clip(y, 0.04045, 1.0) + 0.055) / 1.055) ** 2.4
    return _where(y <= 0.04045, y / 12.92, hi)


MULOG_MU = 5000.0


def _mulog_f(x):
    return _log1p(MULOG_MU * _clip(x, 0.0, 1.0)) / math.log1p(MULOG_MU)


def _mulog_inv(y):
    return _expm1(y * math.log1p(MULOG_MU)) / MULOG_MU


def _linear_f(x):
    return _clip(x, 0.0, 1.0)


def _linear_inv(y):
    return y * 1.0


_REGISTRY: Dict[str, CRF] = {}


def register_crf(crf: CRF, overwrite: bool = False) -> CRF:
    """Add a curve to the registry (so that clip.json may name it)."""
    if crf.name in _REGISTRY and not overwrite:
        raise ValueError(f"CRF {crf.name!r} is already registered")
    _REGISTRY[crf.name] = crf
    return crf


register_crf(CRF("hdrnerf", _hdrnerf_f, _hdrnerf_inv, "(x / (x + 1)) ** (1 / 2.2)"))
register_crf(CRF("gamma", _gamma_f, _gamma_inv, "clip(x, 0, 1) ** (1 / 2.2)"))
register_crf(CRF("srgb", _srgb_f, _srgb_inv, "sRGB OETF of clip(x, 0, 1)"))
register_crf(CRF("mulog", _mulog_f, _mulog_inv, f"log(1 + {MULOG_MU:g} clip(x, 0, 1)) / log(1 + {MULOG_MU:g})"))
register_crf(CRF("linear", _linear_f, _linear_inv, "clip(x, 0, 1)"))

#: name of the default synthetic CRF (HDR-NeRF protocol)
DEFAULT_CRF = "hdrnerf"


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


def quantize_ldr(ldr: ArrayLike):
    """LDR values in [0, 1] -> 8-bit codes floor(255 * v + 0.5) clipped to [0, 255] (uint8; numpy or torch)."""
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
        uint8 array of the same shape (numpy in -> numpy out, torch in -> torch out): floor(255 * f(H * dt) + 0.5).
    """
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"exposure time must be finite and > 0, got {dt!r}")
    f = get_crf(crf)
    h = _as_array(hdr)
    if not _is_torch(h):
        h = h.astype(np.float64, copy=False)
    return quantize_ldr(f(h * float(dt)))
