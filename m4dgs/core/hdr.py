"""The mu-law HDR tone curve (docs/metrics.md "HDR"): T(x) = log(1 + mu x) / log(1 + mu), mu = 5000.

One implementation for every user: the HDR-PSNR/SSIM of eval.metrics.hdr, the flow images of
eval.metrics.temporal, the HDR panel of m4dgs.outputs.videos, the ground-truth noise floor of
benchgen.groundtruth and the `mulog` camera response of m4dgs.core.crf. The curve clips its input
to [0, 1] (the callers divide HDR by a maximum first); the type follows the input: a torch tensor
gives a torch tensor of the same dtype and device, anything else a numpy array (float64 for Python
numbers and integer arrays, the float dtype of a float array)."""

from __future__ import annotations

import math

import numpy as np
import torch

#: mu of the mu-law curve (HDR-NeRF / HDR-GS / Mono4DGS-HDR evaluation convention)
MU = 5000.0


def mu_law(x, mu: float = MU):
    """log(1 + mu clip(x, 0, 1)) / log(1 + mu); torch in -> torch out, else numpy."""
    if isinstance(x, torch.Tensor):
        return torch.log1p(mu * x.clamp(0, 1)) / math.log1p(mu)
    x = np.asarray(x)
    if not np.issubdtype(x.dtype, np.floating):
        x = x.astype(np.float64)
    return np.log1p(mu * np.clip(x, 0.0, 1.0)) / math.log1p(mu)


def mu_law_inverse(y, mu: float = MU):
    """((1 + mu)^y - 1) / mu, the inverse of `mu_law` on [0, 1]; torch in -> torch out, else
    numpy."""
    if isinstance(y, torch.Tensor):
        return torch.expm1(y * math.log1p(mu)) / mu
    return np.expm1(np.asarray(y) * math.log1p(mu)) / mu
