"""`GaussianLayout`: where the densification-relevant quantities live in a dict of per-Gaussian
parameters.

The Gaussian containers (m4dgs.model.gaussians) describe themselves with it (`layout()`,
`static_layout()`, `dynamic_layout()`) and the densification strategy (m4dgs.training.densify) reads
it to grow, split and prune them, so the model layer does not depend on the trainer."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping, Optional

import torch

Tensor = torch.Tensor


def _exp(x: Tensor) -> Tensor:
    return torch.exp(x)


def _log(x: Tensor) -> Tensor:
    return torch.log(x.clamp_min(1e-12))


@dataclass
class GaussianLayout:
    """Where the densification-relevant quantities live in a parameter dict.

    position_keys: keys whose trailing dimension is 3 and that are offset by the split samples (a
        static mean [N, 3] or spline control points [N, K, 3]: every control point moves by the same
        sample).
    scale_key / scale_fn / scale_inv_fn: raw scale parameter [N, 3] and its activation / inverse.
    opacity_key: opacity logits [N] (sigmoid activation).
    rotation_fn: params -> [N, 4] wxyz quaternion (any norm) orienting the split samples; default
        reads `rotation_key` as [N, 4].
    """

    position_keys: tuple = ("means",)
    scale_key: str = "scales"
    opacity_key: str = "opacities"
    rotation_key: str = "quats"
    scale_fn: Callable[[Tensor], Tensor] = _exp
    scale_inv_fn: Callable[[Tensor], Tensor] = _log
    rotation_fn: Optional[Callable[[Mapping[str, Tensor]], Tensor]] = None

    def rotations(self, params: Mapping[str, Tensor]) -> Tensor:
        if self.rotation_fn is not None:
            return self.rotation_fn(params)
        return params[self.rotation_key]
