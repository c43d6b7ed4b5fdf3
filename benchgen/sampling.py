"""How the path tracer spends its samples: pure numpy, no Mitsuba (docs/rendering.md).

This module holds the sampling maths that :class:`benchgen.render.Renderer` applies: the
light-selection weights of next-event estimation (:func:`emitter_sampling_weights`, one set per
mode of EMITTER_SAMPLING_MODES, :func:`emitter_weights_for`) and the adaptive sampler's per-pixel
relative variance (:func:`relative_variance`) and allocation of extra sample blocks
(:func:`adaptive_allocation`). Choosing a mode for a clip renders probes, so it lives with the
renderer (benchgen.render.choose_emitter_sampling).
"""

from __future__ import annotations

import math
from typing import Dict

import numpy as np


# --------------------------------------------------------------------------------------------------
# Light selection
# --------------------------------------------------------------------------------------------------
def emitter_sampling_weights(fs, min_weight: float = 1e-3) -> Dict[str, float]:
    """Light-selection weights for next-event estimation, proportional to each emitter's irradiance
    on the scene.

    Mitsuba picks the light of a shadow-ray sample with probability proportional to its
    `sampling_weight` (all 1 by default). In these scenes a small lamp of radiance ~5000 sits next
    to an environment of ~0.005, so uniform selection spends most shadow rays on a light that BSDF
    sampling (MIS) already handles well and leaves the lamp undersampled. Irradiance estimates at
    the scene's typical distance d (the median camera-z of the non-emitter vertices in the frame-0
    camera, >= 0.1):

    - area emitter (one-sided mesh, total area A, mean radiance L): L * (A / 4) / d^2  (projected
      area of a closed convex emitter is A / 4; a flat panel is within a factor of 2 of it);
    - constant environment of radiance L: pi * L;  sun: its irradiance.

    Args:
        fs: benchgen.scene.FrameState of frame 0. min_weight: floor relative to the largest weight,
        so that every light keeps some shadow rays.
    Returns:
        {"env": w, "sun": w (if present), mesh name: w for each emitter mesh}, largest weight 1.
    """
    w2c = np.linalg.inv(np.asarray(fs.c2w, np.float64))
    zs = [
        ((np.asarray(m.vertices, np.float64) @ w2c[:3, :3].T) + w2c[:3, 3])[:, 2]
        for m in fs.meshes
        if m.material.kind != "emitter"
    ]
    z = np.concatenate(zs) if zs else np.zeros(0)
    z = z[z > 0]
    d = max(float(np.median(z)) if z.size else 1.0, 0.1)
    est: Dict[str, float] = {"env": math.pi * float(np.mean(fs.lighting.env_radiance))}
    lt = fs.lighting
    if lt.sun_direction is not None and lt.sun_irradiance is not None:
        est["sun"] = float(np.mean(lt.sun_irradiance))
    for m in fs.meshes:
        if m.material.kind == "emitter" and m.material.radiance is not None:
            V = np.asarray(m.vertices, np.float64)
            F = np.asarray(m.faces, np.int64)
            area = (
                0.5
                * np.linalg.norm(
                    np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1
                ).sum()
            )
            est[m.name] = float(np.mean(m.material.radiance)) * area / 4.0 / d**2
    top = max(est.values())
    if top <= 0:
        return {k: 1.0 for k in est}
    return {k: max(v / top, min_weight) for k, v in est.items()}


#: the light-selection modes of RenderSettings.emitter_sampling ("auto" picks one of them per clip,
#: benchgen.render.choose_emitter_sampling)
EMITTER_SAMPLING_MODES = ("uniform", "power", "power-sqrt")


def emitter_weights_for(mode: str, fs) -> Dict[str, float]:
    """Light-selection weights of an emitter_sampling mode ({} = Mitsuba's uniform default)."""
    if mode == "uniform":
        return {}
    if mode == "power":
        return emitter_sampling_weights(fs)
    if mode == "power-sqrt":
        return {k: math.sqrt(v) for k, v in emitter_sampling_weights(fs).items()}
    raise ValueError(
        f"emitter_sampling must be one of {EMITTER_SAMPLING_MODES + ('auto',)}, got {mode!r}"
    )


# --------------------------------------------------------------------------------------------------
# Adaptive sampling
# --------------------------------------------------------------------------------------------------
#: spp of one block of extra samples of the adaptive sampler (ldsampler sets come in powers of 4)
ADAPTIVE_BLOCK_SPP = 64
#: at most this many extra blocks per pixel
ADAPTIVE_MAX_BLOCKS = 7


def _box3(a: np.ndarray) -> np.ndarray:
    """3x3 box mean of an [H, W] array (edge-replicated)."""
    p = np.pad(a, 1, mode="edge")
    H, W = a.shape
    return sum(p[i : i + H, j : j + W] for i in range(3) for j in range(3)) / 9.0


def relative_variance(mean: np.ndarray, var: np.ndarray) -> np.ndarray:
    """[H, W] per-sample relative variance of each pixel: the 3x3-smoothed channel-sum sample
    variance over the squared 3x3-smoothed channel-sum mean (0 where the neighbourhood is black).

    mean, var [H, W, 3]: per-pixel sample mean and (per-sample) variance. Smoothing makes the
    estimate stable where a pixel's own samples all missed the light (a zero variance there would
    wrongly read as converged)."""
    m = _box3(np.asarray(mean, np.float64).sum(-1))
    v = _box3(np.asarray(var, np.float64).clip(min=0.0).sum(-1))
    return np.where(m > 1e-12, v / np.maximum(m, 1e-12) ** 2, 0.0)


def adaptive_allocation(
    rel_var: np.ndarray,
    base_spp: int,
    extra_spp: float,
    block_spp: int = ADAPTIVE_BLOCK_SPP,
    max_blocks: int = ADAPTIVE_MAX_BLOCKS,
) -> np.ndarray:
    """Extra sample blocks per pixel [H, W] int: greedy minimum of sum_i sqrt(v_i / n_i).

    v_i: per-sample relative variance of pixel i (:func:`relative_variance`); n_i = base_spp +
    block_spp * k_i. The objective is the expected sum of the per-pixel relative errors |X - mu| /
    mu, the quantity HDR-TAE's |a - b| / (a + b) averages, so the blocks go where one more block
    lowers that error most: the increment k -> k + 1 of pixel i gains sqrt(v_i) * (n^-1/2 - (n +
    block)^-1/2); the round(extra_spp * pixels / block_spp) largest gains are taken (the gains of
    one pixel fall with k, so the choice is consistent). Deterministic (ties by pixel order)."""
    v = np.asarray(rel_var, np.float64)
    budget = int(round(float(extra_spp) * v.size / float(block_spp)))
    out = np.zeros(v.shape, np.int64)
    if budget <= 0 or max_blocks <= 0:
        return out
    sv = np.sqrt(np.clip(v.ravel(), 0.0, None))
    n = base_spp + block_spp * np.arange(max_blocks + 1, dtype=np.float64)
    step = 1.0 / np.sqrt(n[:-1]) - 1.0 / np.sqrt(n[1:])  # [max_blocks], falling
    gains = sv[:, None] * step[None, :]  # [P, max_blocks]
    flat = gains.ravel()
    budget = min(budget, int((flat > 0).sum()))
    if budget <= 0:
        return out
    # the `budget` largest gains (stable order: ties go to the lower pixel index, then lower k)
    order = np.argsort(-flat, kind="stable")[:budget]
    np.add.at(out.reshape(-1), order // max_blocks, 1)
    return out
