"""Procedural albedo textures in numpy (project issue 3: "texture is what priors and photometric
losses need").

Each pattern is a scalar mask m [h, w] in [0, 1] blended between two linear albedos; a
multiplicative multi-octave value-noise overlay combines patterns (checker + noise, stripes +
noise). Everything is deterministic per seed and returned as float32 [h, w, 3] linear albedo clipped
to [ALBEDO_MIN, ALBEDO_MAX]. Row 0 of the array is v = 0 (texture "bottom"); uvs of benchgen.meshes
index it as (u -> column, v -> row)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

ALBEDO_MIN = 0.02
ALBEDO_MAX = 0.95


def _uv(res: int):
    """Pixel-centre texture coordinates (u, v) [res, res] in (0, 1)."""
    c = (np.arange(res) + 0.5) / res
    u, v = np.meshgrid(c, c, indexing="xy")
    return u, v


def checker_mask(res: int, frequency: float) -> np.ndarray:
    """[res, res] in {0, 1}: frequency x frequency cells."""
    u, v = _uv(res)
    return ((np.floor(u * frequency) + np.floor(v * frequency)) % 2).astype(np.float64)


def stripes_mask(
    res: int, frequency: float, angle_deg: float = 0.0, sharpness: float = 3.0
) -> np.ndarray:
    """[res, res] in [0, 1]: frequency stripe periods across the texture, direction angle_deg in uv
    space.

    A softened square wave (clipped sine) so stripes have crisp but not aliased edges.
    """
    u, v = _uv(res)
    a = np.deg2rad(angle_deg)
    s = u * np.cos(a) + v * np.sin(a)
    return 0.5 + 0.5 * np.clip(sharpness * np.sin(2 * np.pi * frequency * s), -1.0, 1.0)


def _lattice_octave(res: int, cells: int, rng: np.random.Generator) -> np.ndarray:
    """One octave of tileable value noise: random values on a cells x cells lattice, quintic
    interpolation."""
    cells = max(int(cells), 1)
    lat = rng.random((cells, cells))
    c = (np.arange(res) + 0.5) / res * cells
    i0 = np.floor(c).astype(int)
    f = c - i0
    f = f * f * f * (f * (f * 6 - 15) + 10)  # quintic fade: C2 across cells
    i0 %= cells
    i1 = (i0 + 1) % cells
    # rows: v (y), columns: u (x)
    a = lat[np.ix_(i0, i0)]
    b = lat[np.ix_(i0, i1)]
    cc = lat[np.ix_(i1, i0)]
    d = lat[np.ix_(i1, i1)]
    fx = f[None, :]
    fy = f[:, None]
    return (a * (1 - fx) + b * fx) * (1 - fy) + (cc * (1 - fx) + d * fx) * fy


def value_noise(
    res: int, frequency: float = 4.0, octaves: int = 4, persistence: float = 0.5, seed: int = 0
) -> np.ndarray:
    """Multi-octave tileable value noise [res, res] rescaled to [0, 1]; octave k has frequency *
    2**k cells."""
    rng = np.random.default_rng(seed)
    acc = np.zeros((res, res))
    amp, tot = 1.0, 0.0
    for k in range(int(octaves)):
        acc += amp * _lattice_octave(res, int(round(frequency * 2**k)), rng)
        tot += amp
        amp *= persistence
    acc /= tot
    lo, hi = acc.min(), acc.max()
    return (acc - lo) / max(hi - lo, 1e-12)


def blend(mask: np.ndarray, colors: Sequence[Sequence[float]]) -> np.ndarray:
    """[h, w, 3] = colors[0] * (1 - mask) + colors[1] * mask."""
    c0, c1 = (np.asarray(c, dtype=np.float64) for c in colors)
    return c0 * (1 - mask[..., None]) + c1 * mask[..., None]


def make_texture(
    type: str,
    colors: Sequence[Sequence[float]] = ((0.8, 0.8, 0.8), (0.15, 0.15, 0.15)),
    frequency: float = 8.0,
    angle_deg: float = 0.0,
    octaves: int = 4,
    persistence: float = 0.5,
    noise_amount: float = 0.0,
    resolution: int = 256,
    seed: int = 0,
) -> np.ndarray:
    """Procedural albedo texture [resolution, resolution, 3] float32 in [ALBEDO_MIN, ALBEDO_MAX].

    Args:
        type: 'checker' | 'stripes' | 'noise'.
        noise_amount: in [0, 1]; multiplies the pattern by (1 + noise_amount * 1.5 * (n - 0.5)) with
        n a value-noise
            field at 4x the pattern frequency (the "combination" of patterns).
    """
    res = int(resolution)
    if type == "checker":
        m = checker_mask(res, frequency)
    elif type == "stripes":
        m = stripes_mask(res, frequency, angle_deg)
    elif type == "noise":
        m = value_noise(res, frequency, octaves, persistence, seed)
    else:
        raise ValueError(f"unknown texture type {type!r}")
    img = blend(m, colors)
    if noise_amount > 0:
        n = value_noise(res, max(frequency, 1.0) * 4, octaves, persistence, seed + 7919)
        img = img * (1 + noise_amount * 1.5 * (n[..., None] - 0.5))
    return np.clip(img, ALBEDO_MIN, ALBEDO_MAX).astype(np.float32)


def texture_from_spec(spec: dict, default_seed: int) -> np.ndarray:
    """Texture of a validated ``material.texture`` spec; a null seed uses default_seed."""
    seed = spec["seed"] if spec.get("seed") is not None else default_seed
    return make_texture(
        spec["type"],
        spec["colors"],
        spec["frequency"],
        spec["angle_deg"],
        spec["octaves"],
        spec["persistence"],
        spec["noise_amount"],
        spec["resolution"],
        int(seed),
    )


def solid_color(color: Sequence[float]) -> tuple:
    """A flat albedo clipped to the texture range, as the (r, g, b) tuple Material.color expects."""
    return tuple(float(np.clip(c, ALBEDO_MIN, ALBEDO_MAX)) for c in color)
