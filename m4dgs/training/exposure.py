"""Exposure perturbation of the training frames (robustness experiment: unknown / inaccurate
exposure times).

Each training frame's exposure time dt is multiplied by 2^u with u ~ U[-r, r] EV, drawn once per run
from a seeded numpy Generator and fixed for the whole run. Exposures are handled as log2 values
(authors' convention), so the perturbation is additive: log2_dt' = log2_dt + u."""

from __future__ import annotations

from typing import Tuple

import numpy as np
import torch


def exposure_offsets(n_frames: int, r_ev: float, seed: int) -> np.ndarray:
    """[T] float64 offsets u ~ U[-r_ev, r_ev] (in EV = log2 units) from
    numpy.random.default_rng(seed)."""
    if r_ev < 0:
        raise ValueError(f"r_ev must be >= 0, got {r_ev}")
    rng = np.random.default_rng(seed)
    return rng.uniform(-r_ev, r_ev, size=int(n_frames))


def perturb_exposures(log2_dt, r_ev: float, seed: int):
    """Perturb per-frame log2 exposure times.

    Args:
        log2_dt: [T] log2 exposure times (numpy array, list or torch tensor).
        r_ev: half-width of the uniform perturbation in EV (stops); 0 returns an unchanged copy.
        seed: seed of the numpy Generator; the same seed gives the same offsets.
    Returns:
        [T] perturbed log2 exposure times, same type (numpy / torch, dtype and device kept) as the
        input.
    """
    if isinstance(log2_dt, torch.Tensor):
        u = torch.as_tensor(
            exposure_offsets(log2_dt.shape[0], r_ev, seed),
            dtype=log2_dt.dtype,
            device=log2_dt.device,
        )
        return log2_dt + u
    arr = np.asarray(log2_dt)
    out_dtype = arr.dtype if np.issubdtype(arr.dtype, np.floating) else np.float64
    return (arr.astype(np.float64) + exposure_offsets(arr.shape[0], r_ev, seed)).astype(out_dtype)


def training_exposures(exposure_cfg, data, device) -> Tuple[float, torch.Tensor]:
    """The exposure set-up both stages share: (C_0, log2_dt [T] on `device`).

    C_0, the unit-exposure target, is `exposure.unit_exposure_value` or the clip's; log2_dt are the
    training frames' log2 exposure times, perturbed by `exposure.perturb_ev` EV (seeded by
    `exposure.perturb_seed`, so both stages see the same perturbed values) when it is > 0.

    Args:
        exposure_cfg: m4dgs.training.config.ExposureConfig; data: m4dgs.training.data.TrainingData.
    """
    c0 = float(exposure_cfg.unit_exposure_value or data.unit_exposure_value)
    log2_dt = data.log2_dt.to(device)
    if exposure_cfg.perturb_ev > 0:
        log2_dt = perturb_exposures(log2_dt, exposure_cfg.perturb_ev, exposure_cfg.perturb_seed)
    return c0, log2_dt
