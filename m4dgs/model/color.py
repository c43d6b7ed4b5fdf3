"""HDR Gaussian colour from a learned feature (paper appendix "Implementation Details").

Each Gaussian stores a 36-d feature; its HDR irradiance is ``e = 2 ** MLP([feature, view
direction])`` with MLP = Linear(39, 36) - ReLU - Linear(36, 3) (authors' code: base-2 exponential,
no clamp), so e > 0 always. Video-space Gaussians (stage 1) have no meaningful view direction: build
the module with ``view_dependent=False`` (the direction input is then zeros, keeping the 39-d input
so that stage-2 world Gaussians can inherit the same weights)."""

from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F

FEATURE_DIM = 36  # paper appendix: 36-d colour features
HIDDEN_DIM = 36  # paper appendix: colour MLP hidden width 36


class ColorMLP(nn.Module):
    """features [N, F] (+ view directions [N, 3]) -> HDR irradiance [N, 3] = 2 ** MLP(...) > 0."""

    def __init__(
        self,
        feature_dim: int = FEATURE_DIM,
        hidden: int = HIDDEN_DIM,
        view_dependent: bool = True,
        max_log2: float | None = None,
    ):
        """
        Args:
            feature_dim: F, the per-Gaussian feature size (36). hidden: hidden width (36).
            view_dependent: when False the view direction input is replaced by zeros. max_log2:
            optional clamp of the MLP output before 2 ** (None = authors' choice, no clamp).
        """
        super().__init__()
        self.feature_dim = int(feature_dim)
        self.view_dependent = bool(view_dependent)
        self.max_log2 = max_log2
        self.fc1 = nn.Linear(self.feature_dim + 3, hidden)
        self.fc2 = nn.Linear(hidden, 3)

    def log2_irradiance(
        self, features: torch.Tensor, view_dirs: torch.Tensor | None = None
    ) -> torch.Tensor:
        """MLP output before exponentiation: [..., F] (+ [..., 3]) -> [..., 3]."""
        if view_dirs is None or not self.view_dependent:
            view_dirs = features.new_zeros(*features.shape[:-1], 3)
        x = self.fc2(F.relu(self.fc1(torch.cat([features, view_dirs.to(features.dtype)], dim=-1))))
        if self.max_log2 is not None:
            x = x.clamp(max=self.max_log2)
        return x

    def forward(
        self, features: torch.Tensor, view_dirs: torch.Tensor | None = None
    ) -> torch.Tensor:
        """
        Args:
            features: [..., F] per-Gaussian features.
            view_dirs: [..., 3] unit viewing directions (camera centre -> Gaussian), or None.
        Returns:
            [..., 3] HDR irradiance, strictly positive.
        """
        return torch.exp2(self.log2_irradiance(features, view_dirs))


def view_directions(means: torch.Tensor, cam_center: torch.Tensor) -> torch.Tensor:
    """Unit directions from the camera centre to each Gaussian.

    Args:
        means: [N, 3] world positions; cam_center: [3] camera centre (c2w[:3, 3]).
    Returns:
        [N, 3] unit vectors (zero vectors stay zero).
    """
    d = means - cam_center.to(means.dtype)
    return d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)
