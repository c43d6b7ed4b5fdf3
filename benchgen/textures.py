"""Procedural albedo textures in numpy: texture is what the priors (flow, tracks) and the
photometric losses need, so every surface carries some.

Each pattern is a scalar mask m [h, w] in [0, 1] blended between two linear albedos; a
multiplicative multi-octave value-noise overlay combines patterns (checker + noise, stripes +
noise). Everything is deterministic per seed and returned as float32 [h, w, 3] linear albedo clipped
to [ALBEDO_MIN, ALBEDO_MAX]. Row 0 of the array is v = 0 (texture "bottom"); uvs of benchgen.meshes
index it as (u -> column, v -> row).

Band limit (docs/rendering.md "Band-limited textures"): a hard checker edge or a noise octave finer
than a pixel is resampled differently at every sub-pixel camera offset, and HDR-TAE's bilinear warp
cannot follow frequencies near the pixel grid's Nyquist limit, so such detail is a floor under the
metric that no method can go below. ``make_texture(..., band_limit=c)`` evaluates the pattern at
SUPERSAMPLE x the bitmap resolution, low-passes it with a periodic Gaussian whose gain at c cycles
per texture side is CUTOFF_GAIN, and resamples it spectrally to the bitmap resolution (no
aliasing); noise octaves far above c are not computed. The limit may be anisotropic (a 2x2
uv-frequency metric, band_matrix), as the screen footprint of a texture is: benchgen.scene chooses
it per object from where the clip's camera sees the texture
(benchgen.scene.Scene.texture_band_limits)."""

from __future__ import annotations

from typing import Optional, Sequence, Tuple

import numpy as np

ALBEDO_MIN = 0.02
ALBEDO_MAX = 0.95

#: gain of the band-limiting Gaussian at the cutoff frequency (0.47 at half the cutoff)
CUTOFF_GAIN = 0.05
#: the pattern is evaluated at this multiple of the bitmap resolution before the low-pass
SUPERSAMPLE = 4
#: largest evaluation resolution of a supersampled pattern
MAX_EVAL_RESOLUTION = 2048
#: noise octaves with more lattice cells than this multiple of the cutoff are skipped (their
#: energy below the cutoff is below 1/16 of theirs)
OCTAVE_SKIP_FACTOR = 4.0


def band_matrix(band, resolution: Optional[int] = None) -> np.ndarray:
    """The band limit as a 2x2 uv-frequency metric B: the low-pass gain at texture frequency k =
    (k_u, k_v) (cycles per texture side) is CUTOFF_GAIN ** (k^T B k).

    band: a cutoff c > 0 (isotropic: B = I / c^2) or a symmetric positive definite [2, 2] B.
    resolution: when given, the cutoff in every direction is capped at max_cutoff(resolution)
    (B's eigenvalues raised to at least 1 / max_cutoff^2)."""
    b = np.asarray(band, np.float64)
    if b.ndim == 0:
        if not b > 0:
            raise ValueError(f"band limit: the cutoff must be > 0, got {float(b)}")
        B = np.eye(2) / float(b) ** 2
    elif b.shape == (2, 2):
        B = 0.5 * (b + b.T)
    else:
        raise ValueError(f"band limit: a cutoff or a [2, 2] matrix, got shape {b.shape}")
    lam, vec = np.linalg.eigh(B)
    if not np.all(lam > 0):
        raise ValueError(f"band limit: the matrix must be positive definite, got {B.tolist()}")
    if resolution is not None:
        lam = np.maximum(lam, 1.0 / max_cutoff(resolution) ** 2)
    return (vec * lam) @ vec.T


def band_cutoffs(band) -> Tuple[float, float]:
    """(lowest, highest) cutoff in cycles per texture side over directions of a band limit."""
    lam = np.linalg.eigvalsh(band_matrix(band))
    return float(1.0 / np.sqrt(lam[1])), float(1.0 / np.sqrt(lam[0]))


def max_cutoff(resolution: int) -> float:
    """Highest cutoff a bitmap of `resolution` texels keeps (half its Nyquist limit, so Mitsuba's
    bilinear texel interpolation adds no visible structure)."""
    return int(resolution) / 4.0


def lowpass(img: np.ndarray, band, out_res: Optional[int] = None) -> np.ndarray:
    """Periodic Gaussian low-pass of a square image [n, n] or [n, n, c] (texture-side units: the
    image spans one period; rows are v, columns u) with gain CUTOFF_GAIN ** (k^T B k) at frequency k
    = (k_u, k_v) cycles per side (B = band_matrix(band)); resampled in the Fourier domain to out_res
    x out_res texel centres (default n; out_res <= n; the frequencies at and above out_res / 2 are
    dropped, which is exact when the Gaussian has removed them)."""
    a = np.asarray(img, np.float64)
    n = a.shape[0]
    if a.shape[1] != n:
        raise ValueError(f"lowpass: square images only, got {a.shape}")
    m = n if out_res is None else int(out_res)
    if m > n or m < 2:
        raise ValueError(f"lowpass: out_res must be in [2, {n}], got {m}")
    B = band_matrix(band)
    spec = np.fft.rfft2(a, axes=(0, 1))
    fy = np.fft.fftfreq(n, 1.0 / n)[:, None]  # k_v, cycles per side
    fx = np.fft.rfftfreq(n, 1.0 / n)[None, :]  # k_u
    quad = B[0, 0] * fx**2 + 2.0 * B[0, 1] * fx * fy + B[1, 1] * fy**2
    gain = np.exp(-np.log(1.0 / CUTOFF_GAIN) * quad)
    if m != n:
        # texel centres: the n-grid samples (k + 0.5) / n, the m-grid (j + 0.5) / m; shift by the
        # difference so both describe the same continuous texture
        gain = gain * np.exp(2j * np.pi * (0.5 / m - 0.5 / n) * (fy + fx))
    spec = spec * (gain if a.ndim == 2 else gain[..., None])
    if m != n:
        # keep |f| < m / 2 on the m-grid; the Nyquist row and column stay 0
        h = m // 2
        small = np.zeros((m, h + 1) + spec.shape[2:], spec.dtype)
        small[:h, :h] = spec[:h, :h]
        small[m - h + 1 :, :h] = spec[n - h + 1 :, :h]
        spec = small * (m * m) / (n * n)
    return np.fft.irfft2(spec, s=(m, m), axes=(0, 1))


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
    res: int,
    frequency: float = 4.0,
    octaves: int = 4,
    persistence: float = 0.5,
    seed: int = 0,
    max_cells: Optional[float] = None,
) -> np.ndarray:
    """Multi-octave tileable value noise [res, res] rescaled to [0, 1]; octave k has frequency *
    2**k cells. Octaves with more than max_cells cells are skipped (the lower ones keep their
    lattice values: the same seed gives the same coarse pattern)."""
    rng = np.random.default_rng(seed)
    acc = np.zeros((res, res))
    amp, tot = 1.0, 0.0
    for k in range(int(octaves)):
        cells = int(round(frequency * 2**k))
        if k > 0 and max_cells is not None and cells > max_cells:
            break
        acc += amp * _lattice_octave(res, cells, rng)
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
    band_limit=None,
) -> np.ndarray:
    """Procedural albedo texture [resolution, resolution, 3] float32 in [ALBEDO_MIN, ALBEDO_MAX].

    Args:
        type: 'checker' | 'stripes' | 'noise'.
        noise_amount: in [0, 1]; multiplies the pattern by (1 + noise_amount * 1.5 * (n - 0.5)) with
            n a value-noise field at 4x the pattern frequency (the "combination" of patterns).
        band_limit: a cutoff in cycles per texture side or a [2, 2] uv-frequency metric
            (band_matrix), capped at max_cutoff(resolution); None: the raw pattern sampled at texel
            centres (generator version <= 4). The pattern is evaluated at SUPERSAMPLE x the
            resolution, low-passed (lowpass) and resampled to the resolution. A Gaussian is a
            positive kernel, so the result stays within the albedo range.
    """
    res = int(resolution)
    if band_limit is not None:
        B = band_matrix(band_limit, res)
        ev = res * max(1, min(SUPERSAMPLE, MAX_EVAL_RESOLUTION // res))
        max_cells = OCTAVE_SKIP_FACTOR * band_cutoffs(B)[1]
    else:
        ev, max_cells = res, None
    if type == "checker":
        m = checker_mask(ev, frequency)
    elif type == "stripes":
        m = stripes_mask(ev, frequency, angle_deg)
    elif type == "noise":
        m = value_noise(ev, frequency, octaves, persistence, seed, max_cells)
    else:
        raise ValueError(f"unknown texture type {type!r}")
    img = blend(m, colors)
    if noise_amount > 0:
        n = value_noise(ev, max(frequency, 1.0) * 4, octaves, persistence, seed + 7919, max_cells)
        img = img * (1 + noise_amount * 1.5 * (n[..., None] - 0.5))
    img = np.clip(img, ALBEDO_MIN, ALBEDO_MAX)
    if band_limit is not None:
        img = np.clip(lowpass(img, B, res), ALBEDO_MIN, ALBEDO_MAX)
    return img.astype(np.float32)


def texture_from_spec(spec: dict, default_seed: int, band_limit=None) -> np.ndarray:
    """Texture of a validated ``material.texture`` spec; a null seed uses default_seed; band_limit:
    see make_texture (None: none)."""
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
        band_limit,
    )


def solid_color(color: Sequence[float]) -> tuple:
    """A flat albedo clipped to the texture range, as the (r, g, b) tuple Material.color expects."""
    return tuple(float(np.clip(c, ALBEDO_MIN, ALBEDO_MAX)) for c in color)
