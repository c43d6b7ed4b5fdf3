"""The constant HDR background behind the Gaussians (paper silent; `tonemap.learn_background`)."""

from __future__ import annotations

import torch


class Background(torch.nn.Module):
    """Constant HDR background colour 2^b behind the Gaussians (b learnable when enabled)."""

    def __init__(self, learn: bool = True, init_log2: float = -4.0):
        super().__init__()
        self.log2 = torch.nn.Parameter(torch.full((3,), float(init_log2)), requires_grad=learn)

    def forward(self) -> torch.Tensor:
        return torch.exp2(self.log2)
