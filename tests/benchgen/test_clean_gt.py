"""Clean ground truth: band-limited textures, their screen footprint, and the
adaptive sampler, each against an independent answer (numpy FFT spectra, the analytic Jacobian of a
fronto-parallel plane, a brute-force greedy allocation, a plain Mitsuba render)."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from benchgen import textures as T
from benchgen.scene import (
    TEXTURE_MAX_CYCLES_PER_PIXEL,
    band_limit_from_footprint,
    scene_from_dict,
    uv_footprint,
)


# --------------------------------------------------------------------------------------------------
# Band-limited textures
# --------------------------------------------------------------------------------------------------
def _energy_beyond(img: np.ndarray, B: np.ndarray, total: bool = False):
    """Fraction of the AC energy of img [n, n, 3] at uv frequencies k with k^T B k >= 1 (numpy FFT
    per channel; rows are v, columns u; cycles per texture side); total: (that energy, all AC
    energy) instead."""
    n = img.shape[0]
    k_v = np.fft.fftfreq(n, 1.0 / n)[:, None]
    k_u = np.fft.fftfreq(n, 1.0 / n)[None, :]
    quad = B[0, 0] * k_u**2 + 2 * B[0, 1] * k_u * k_v + B[1, 1] * k_v**2
    tot = above = 0.0
    for c in range(3):
        P = np.abs(np.fft.fft2(img[..., c] - img[..., c].mean())) ** 2
        tot += P.sum()
        above += P[quad >= 1.0].sum()
    return (above, tot) if total else above / tot


@pytest.mark.parametrize(
    "kind, kw",
    [
        ("checker", {"frequency": 6, "noise_amount": 0.4}),
        ("stripes", {"frequency": 5, "angle_deg": 30}),
        ("noise", {"frequency": 6, "octaves": 6}),
    ],
)
def test_band_limited_texture_has_no_energy_above_the_cutoff(kind, kw):
    cutoff = 16.0
    raw = T.make_texture(kind, resolution=256, seed=5, **kw)
    bl = T.make_texture(kind, resolution=256, seed=5, band_limit=cutoff, **kw)
    iso = np.eye(2) / cutoff**2
    # the raw pattern has energy there (the test bites), the band-limited one keeps < 0.1 % of it
    assert _energy_beyond(raw, iso) > 0.01
    assert _energy_beyond(bl, iso) < 1e-3
    # within the albedo range, deterministic, the same mean albedo (a positive kernel)
    assert T.ALBEDO_MIN <= bl.min() and bl.max() <= T.ALBEDO_MAX and bl.dtype == np.float32
    np.testing.assert_array_equal(
        bl, T.make_texture(kind, resolution=256, seed=5, band_limit=16, **kw)
    )
    assert abs(bl.mean() - raw.mean()) < 0.02 * raw.mean()
    # and the pattern itself survives: more than half of the energy below half the cutoff is kept
    low = np.eye(2) / (cutoff / 2) ** 2
    kept = (1 - _energy_beyond(bl, low)) * bl.var() / ((1 - _energy_beyond(raw, low)) * raw.var())
    assert kept > 0.5


def test_anisotropic_band_limit_follows_its_metric():
    """A band limit of 4 cycles along u and 32 along v: horizontal stripes (varying along v) keep
    their 12 cycles, vertical ones (varying along u) are removed."""
    B = np.diag([1 / 4.0**2, 1 / 32.0**2])
    for angle in (0, 90):
        raw = T.make_texture("stripes", frequency=12, angle_deg=angle, resolution=256)
        bl = T.make_texture("stripes", frequency=12, angle_deg=angle, band_limit=B, resolution=256)
        assert _energy_beyond(bl, B, True)[0] < 1e-3 * _energy_beyond(raw, B, True)[1]
        assert bl.std() > 0.1 if angle == 90 else bl.std() < 0.005
    assert T.band_cutoffs(B) == pytest.approx((4.0, 32.0))
    # capped at the bitmap's own limit (a quarter of its resolution)
    assert T.band_cutoffs(T.band_matrix(1e6, resolution=64)) == pytest.approx((16.0, 16.0))
    with pytest.raises(ValueError, match="positive definite"):
        T.band_matrix(np.diag([1.0, -1.0]))


def test_lowpass_gain_and_resampling_are_exact():
    n, m = 512, 128
    c = (np.arange(n) + 0.5) / n
    u, v = np.meshgrid(c, c, indexing="xy")
    f = 0.3 + 0.2 * np.sin(2 * np.pi * (3 * u + 2 * v)) + 0.1 * np.cos(2 * np.pi * 5 * v)
    # no attenuation to speak of: the coarser grid samples the same function at its texel centres
    out = T.lowpass(f, 1e9, m)
    c2 = (np.arange(m) + 0.5) / m
    u2, v2 = np.meshgrid(c2, c2, indexing="xy")
    g = 0.3 + 0.2 * np.sin(2 * np.pi * (3 * u2 + 2 * v2)) + 0.1 * np.cos(2 * np.pi * 5 * v2)
    assert np.abs(out - g).max() < 1e-9
    # a sinusoid at the cutoff keeps CUTOFF_GAIN of its amplitude, one at half the cutoff its 4th
    # root
    for k, gain in ((8.0, T.CUTOFF_GAIN), (4.0, T.CUTOFF_GAIN**0.25)):
        s = np.sin(2 * np.pi * k * u)
        np.testing.assert_allclose(T.lowpass(s, 8.0), gain * s, atol=1e-9)


# --------------------------------------------------------------------------------------------------
# Screen footprint -> band limit
# --------------------------------------------------------------------------------------------------
def test_uv_footprint_of_a_fronto_parallel_plane_is_analytic():
    # a 4 m x 3 m quad in the plane y = 0, uv over it; camera at y = -5 looking along +y
    V = np.array([[-2.0, 0, -1.5], [2.0, 0, -1.5], [2.0, 0, 1.5], [-2.0, 0, 1.5]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    UV = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    c2w = np.eye(4)
    # columns: x right (+x), y down (-z), z forward (+y)
    c2w[:3, :3] = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]]).T
    c2w[:3, 3] = [0, -5, 0]
    W, H, fx = 216, 120, 150.0
    K = np.array([[fx, 0, W / 2], [0, fx, H / 2], [0, 0, 1]])
    Q, area = uv_footprint(V, F, UV, c2w, K, W, H)
    # J = d(pixel)/d(uv) = diag(fx * 4 / 5, -fx * 3 / 5): Q = (J^T J)^-1
    Qt = np.diag([(5 / (fx * 4)) ** 2, (5 / (fx * 3)) ** 2])
    assert len(Q) > 100
    np.testing.assert_allclose(Q, np.broadcast_to(Qt, Q.shape), rtol=1e-9)
    # the sample areas add up to the visible screen area of the quad (it fills the image height:
    # 3 m at 5 m is 90 px of 120; 4 m is 120 px of 216)
    assert area.sum() == pytest.approx(120 * 90, rel=0.02)
    # isotropic-by-direction footprint: the band limit is exactly f / sqrt(r(d)) in each axis
    B = band_limit_from_footprint(Q, area, 0.25, 0.5)
    assert T.band_cutoffs(B) == pytest.approx((0.25 * fx * 3 / 5, 0.25 * fx * 4 / 5), rel=1e-6)
    # a mixture: the filter is never weaker than asked for in any direction
    Q2 = np.concatenate([Q, np.broadcast_to(np.diag([1e-4, 4e-6]), Q.shape)])
    B2 = band_limit_from_footprint(Q2, np.r_[area, area], 0.25, 0.5)
    for th in np.linspace(0, np.pi, 17):
        d = np.array([math.cos(th), math.sin(th)])
        r = np.quantile(np.einsum("i,nij,j->n", d, Q2, d), 0.5, method="inverted_cdf")
        assert d @ B2 @ d >= r / 0.25**2 * (1 - 1e-9)
    assert band_limit_from_footprint(np.zeros((0, 2, 2)), np.zeros(0), 0.25, 0.5) is None


def _wall_spec(**texture):
    return {
        "name": "wall",
        "num_frames": 5,
        "camera": {
            "fov_deg": 60,
            "trajectory": {"type": "static", "position": [0, -5, 0], "target": [0, 0, 0]},
        },
        "objects": [
            {
                "name": "wall",
                "mesh": {"type": "plane", "size": [4, 4]},
                "transform": {"rotate_deg": [90, 0, 0]},
                "material": {"kind": "diffuse", "texture": {"type": "checker", **texture}},
            }
        ],
    }


def test_scene_band_limits_textures_for_its_pixel_grid():
    fx = (216 / 2) / math.tan(math.radians(30))
    sc = scene_from_dict(_wall_spec(frequency=48), band_limit=(216, 120))
    # the wall is seen head-on from 5 m: fx * 4 / 5 pixels per texture side in both directions
    want = TEXTURE_MAX_CYCLES_PER_PIXEL * fx * 4 / 5
    assert T.band_cutoffs(sc.texture_band[0]) == pytest.approx((want, want), rel=1e-6)
    alb = sc.objects[0].material.albedo
    assert alb.shape == (256, 256, 3) and not alb.flags.writeable
    assert _energy_beyond(alb, sc.texture_band[0]) < 1e-3
    # a 3x coarser grid gets a 3x lower limit; no band limit keeps the raw pattern
    coarse = scene_from_dict(_wall_spec(frequency=48), band_limit=(72, 40))
    assert T.band_cutoffs(coarse.texture_band[0])[0] == pytest.approx(want / 3, rel=1e-6)
    raw = scene_from_dict(_wall_spec(frequency=48), band_limit=None)
    assert raw.texture_band == {}
    np.testing.assert_array_equal(
        raw.objects[0].material.albedo, T.make_texture("checker", frequency=48, seed=0)
    )


# --------------------------------------------------------------------------------------------------
# Adaptive sampling
# --------------------------------------------------------------------------------------------------
def _greedy(v, base, budget, block, max_blocks):
    """Brute-force greedy: one block at a time to the pixel whose sum of sqrt(v / n) falls most."""
    k = np.zeros(v.size, int)
    for _ in range(budget):
        n = base + block * k
        gain = np.sqrt(v) * (1 / np.sqrt(n) - 1 / np.sqrt(n + block))
        gain[k >= max_blocks] = -1
        if gain.max() <= 0:
            break
        k[int(np.argmax(gain))] += 1
    return k


def test_adaptive_allocation_is_the_greedy_optimum():
    from benchgen.sampling import adaptive_allocation

    rng = np.random.default_rng(3)
    v = rng.lognormal(0, 2, (6, 8))
    v[0, :3] = 0.0  # converged pixels get nothing
    out = adaptive_allocation(v, 64, 16, block_spp=64, max_blocks=5)
    assert out.sum() == round(16 * v.size / 64)
    np.testing.assert_array_equal(out.ravel(), _greedy(v.ravel(), 64, out.sum(), 64, 5))
    assert (out[0, :3] == 0).all() and out.max() <= 5
    # more variance never gets fewer blocks
    o = np.argsort(v.ravel())
    assert (np.diff(out.ravel()[o]) >= 0).all()
    np.testing.assert_array_equal(out, adaptive_allocation(v, 64, 16, block_spp=64, max_blocks=5))
    assert adaptive_allocation(v, 64, 0).sum() == 0


def _shadow_scene(W=48, H=32):
    """A floor lit by a small lamp, a box casting a shadow that only the dim environment lights
    (high relative noise), seen from above at an angle."""
    from benchgen.scene import FrameState, Lighting, Material, MeshState
    from m4dgs.core.camera import K_from_fov

    def quad(c, a, b):
        c, a, b = (np.asarray(x, float) for x in (c, a, b))
        V = np.stack([c - a - b, c + a - b, c + a + b, c - a + b])
        return (
            V,
            np.array([[0, 1, 2], [0, 2, 3]]),
            np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32),
        )

    fV, fF, fUV = quad([0, 0, 0], [3, 0, 0], [0, 3, 0])
    floor = MeshState(
        "floor", 1, fV, fF, fUV, Material("diffuse", None, color=(0.6, 0.6, 0.6)), False
    )
    # a box-shaped occluder as two crossed panels standing on the floor
    bV, bF, bUV = quad([0.3, 0.4, 0.5], [0.6, 0, 0], [0, 0, 0.5])
    wall = MeshState(
        "panel", 2, bV, bF, bUV, Material("diffuse", None, color=(0.4, 0.4, 0.4)), False
    )
    # a small lamp facing down (-z), behind the panel as seen from the camera
    lV, lF, lUV = quad([0.3, 1.2, 0.9], [0.08, 0, 0], [0, -0.08, 0])
    lamp = MeshState(
        "lamp", 3, lV, lF, lUV, Material("emitter", None, radiance=(400.0, 400.0, 400.0)), False
    )
    eye, tgt = np.array([0.0, -3.0, 2.5]), np.array([0.0, 0.0, 0.0])
    z = (tgt - eye) / np.linalg.norm(tgt - eye)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, z, eye
    lt = Lighting(env_radiance=(0.02, 0.02, 0.02), sun_direction=None, sun_irradiance=None)
    return FrameState(0, 0.0, [floor, wall, lamp], c2w, K_from_fov(W, H, 60.0), lt)


def test_adaptive_render_is_unbiased_and_spends_where_the_noise_is():
    from benchgen.groundtruth import render_noise
    from benchgen.render import Renderer
    from benchgen.sampling import ADAPTIVE_BLOCK_SPP, relative_variance

    W, H = 48, 32
    fs = _shadow_scene(W, H)
    settings = {"spp": 64, "max_depth": 2, "emitter_sampling": "uniform", "adaptive_spp": 64}
    r = Renderer(fs, W, H, settings)
    color, blocks = r.render_adaptive(seed=3, spp=64, extra_spp=64)
    assert blocks.sum() == round(64 * W * H / ADAPTIVE_BLOCK_SPP)
    # independent answer: a plain 1024-spp Mitsuba render
    ref = Renderer(fs, W, H, {"spp": 1024, "max_depth": 2}).render_hdr(seed=11).astype(np.float64)
    hit = r.cast_rays().hit & ~r.emitter_pixels()
    assert abs(color[hit].mean() - ref[hit].mean()) < 0.01 * ref[hit].mean()
    rel = (color - ref)[hit] / (color + ref + 1e-12)[hit]
    assert abs(np.median(rel)) < 0.01
    # the blocks went to the pixels with the highest relative variance, measured independently
    # from 16 plain 64-spp renders
    plain = Renderer(fs, W, H, {"spp": 64, "max_depth": 2})
    stack = np.stack([plain.render_hdr(seed=100 + s) for s in range(16)]).astype(np.float64)
    rv = relative_variance(stack.mean(0), stack.var(0, ddof=1) * 64)
    got, none = blocks > 0, (blocks == 0) & hit
    assert got.any() and none.any()
    assert np.median(rv[got]) > 2 * np.median(rv[none])
    # and the frame is less noisy than the plain render with the same base samples
    two = [Renderer(fs, W, H, settings).render_hdr(seed=s) for s in (1, 2)]
    base = [plain.render_hdr(seed=s) for s in (1, 2)]
    assert (
        render_noise(*two, hit)["tae_two_seeds"] < 0.9 * render_noise(*base, hit)["tae_two_seeds"]
    )
    assert r.render_hdr(seed=3).shape == (H, W, 3) and r.last_extra_spp == pytest.approx(
        64, rel=0.02
    )
