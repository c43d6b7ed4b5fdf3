"""HDR Gaussian colour from a learned feature (paper appendix "Implementation Details").

Each Gaussian stores a 36-d feature; its HDR irradiance is ``e = 2 ** MLP([feature, view
direction])`` with MLP = Linear(39, 36) - ReLU - Linear(36, 3) (authors' code: base-2 exponential,
no clamp), so e > 0 always. Video-space Gaussians (stage 1) have no meaningful view direction: build
the module with ``view_dependent=False`` (the direction input is then zeros, keeping the 39-d input
so that stage-2 world Gaussians can inherit the same weights).

Beyond the paper, the direction fed to the MLP can be the view direction mirrored about each
Gaussian's normal (``direction="reflected"``, the reflected direction of Ref-NeRF): a mirror-like
surface shows a fixed light where that direction meets it, so the MLP can tie a highlight to it
(`color_directions`). A Gaussian's normal is the axis of its smallest scale. With ``specular=True``
(beyond the paper) each Gaussian also has a lobe over that direction, read from its feature by a
linear head: ``e += a * exp(kappa * (d . mu - 1))`` (a spherical Gaussian: RGB amplitude
a = 2 ** (...), unit axis mu, sharpness kappa = exp(...)), which can flare as the direction sweeps
past mu; the lobe is absent where there is no direction (stage 1's orthographic camera)."""

from __future__ import annotations

import math
from typing import Optional

import torch
import torch.nn as nn
import torch.nn.functional as F

from m4dgs.core.camera import quat_to_rotmat

FEATURE_DIM = 36  # paper appendix: 36-d colour features
HIDDEN_DIM = 36  # paper appendix: colour MLP hidden width 36
DIRECTIONS = ("view", "reflected")  # what `direction` may name (ToneMapConfig.color_direction)
# the specular lobe's start (beyond the paper; no source), for a feature of zeros: amplitude 2^-4
# (dim against the scene's HDR values of order 1, yet within the stops a feature's learning rate
# can add in one stage: at 2^-8 the lobes of a glint probe never left it) and sharpness 2 (broad: a
# half-width of about 50 degrees, so that every Gaussian's axis gets a gradient from the start)
SPEC_LOG2_AMPLITUDE0 = -4.0
SPEC_SHARPNESS0 = 2.0


class ColorMLP(nn.Module):
    """features [N, F] (+ view directions [N, 3]) -> HDR irradiance [N, 3] = 2 ** MLP(...) > 0
    (+ each Gaussian's lobe over the direction with `specular`)."""

    def __init__(
        self,
        feature_dim: int = FEATURE_DIM,
        hidden: int = HIDDEN_DIM,
        view_dependent: bool = True,
        max_log2: float | None = None,
        direction: str = "view",
        specular: bool = False,
    ):
        """
        Args:
            feature_dim: F, the per-Gaussian feature size (36). hidden: hidden width (36).
            view_dependent: when False the view direction input is replaced by zeros. max_log2:
            optional clamp of the MLP output before 2 ** (None = authors' choice, no clamp).
            direction: which direction the renders feed when view dependent (`color_directions`):
            "view" (camera centre -> Gaussian, the authors') or "reflected" (that direction
            mirrored about the Gaussian's normal; beyond the paper). specular: add each
            Gaussian's lobe over the direction (beyond the paper; module docstring).
        """
        super().__init__()
        if direction not in DIRECTIONS:
            raise ValueError(f"colour direction must be one of {DIRECTIONS}; got {direction!r}")
        self.feature_dim = int(feature_dim)
        self.view_dependent = bool(view_dependent)
        self.direction = direction
        self.max_log2 = max_log2
        self.fc1 = nn.Linear(self.feature_dim + 3, hidden)
        self.fc2 = nn.Linear(hidden, 3)
        self.specular = bool(specular)
        if self.specular:
            # feature -> log2 RGB amplitude (3), lobe axis (3, normalised), ln sharpness (1). Every
            # row keeps its random start, so that each Gaussian's feature moves its own lobe from
            # the first step (a row of zeros passes no gradient to the features); the biases start
            # at the constants above
            self.spec = nn.Linear(self.feature_dim, 7)
            with torch.no_grad():
                self.spec.bias[:3].fill_(SPEC_LOG2_AMPLITUDE0)
                self.spec.bias[3:6].zero_()
                self.spec.bias[6:].fill_(math.log(SPEC_SHARPNESS0))

    def log2_irradiance(
        self, features: torch.Tensor, view_dirs: torch.Tensor | None = None
    ) -> torch.Tensor:
        """MLP output before exponentiation (without the specular lobe): [..., F] (+ [..., 3]) ->
        [..., 3]."""
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
        e = torch.exp2(self.log2_irradiance(features, view_dirs))
        if self.specular and self.view_dependent and view_dirs is not None:
            e = e + self.specular_lobe(features, view_dirs)
        return e

    def specular_lobe(self, features: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        """Each Gaussian's lobe (module docstring): [..., F], [..., 3] unit -> [..., 3] >= 0."""
        out = self.spec(features)
        amp = torch.exp2(out[..., :3])
        axis = F.normalize(out[..., 3:6], dim=-1)
        sharp = torch.exp(out[..., 6:])
        cos = (dirs.to(axis.dtype) * axis).sum(-1, keepdim=True)
        return amp * torch.exp(sharp * (cos - 1.0))


def view_directions(means: torch.Tensor, cam_center: torch.Tensor) -> torch.Tensor:
    """Unit directions from the camera centre to each Gaussian.

    Args:
        means: [N, 3] world positions; cam_center: [3] camera centre (c2w[:3, 3]).
    Returns:
        [N, 3] unit vectors (zero vectors stay zero).
    """
    d = means - cam_center.to(means.dtype)
    return d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)


def gaussian_normals(quats: torch.Tensor, scales: torch.Tensor) -> torch.Tensor:
    """Each Gaussian's normal: the unit axis of its smallest scale, in world space.

    Args:
        quats: [N, 4] rotations (w, x, y, z; need not be unit). scales: [N, 3] activated scales.
    Returns:
        [N, 3] unit normals; their sign is arbitrary (`reflect` does not depend on it).
    """
    R = quat_to_rotmat(quats)  # [N, 3, 3], columns = the local axes in world space
    idx = scales.argmin(dim=-1)  # [N]
    return R.gather(-1, idx[:, None, None].expand(-1, 3, 1))[..., 0]


def reflect(dirs: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """Directions mirrored about planes with the given unit normals: d - 2 (d . n) n.

    Args:
        dirs: [N, 3]; normals: [N, 3] unit (either sign gives the same result).
    Returns:
        [N, 3], as long as `dirs`.
    """
    return dirs - 2.0 * (dirs * normals).sum(-1, keepdim=True) * normals


def color_directions(
    color: ColorMLP,
    means: torch.Tensor,
    quats: torch.Tensor,
    scales: torch.Tensor,
    cam_center: torch.Tensor,
) -> Optional[torch.Tensor]:
    """The direction input of a pinhole render's colour MLP, or None when it has none.

    Args:
        color: the colour MLP (its `view_dependent` and `direction`). means: [N, 3] world
        positions at the render time; quats: [N, 4] and scales: [N, 3] (activated) at that time;
        cam_center: [3] camera centre (c2w[:3, 3]).
    Returns:
        [N, 3] unit directions: camera centre -> Gaussian ("view"), or that mirrored about each
        Gaussian's normal (`gaussian_normals`, "reflected"); None when not view dependent.
    """
    if not color.view_dependent:
        return None
    d = view_directions(means, cam_center)
    if color.direction == "reflected":
        d = reflect(d, gaussian_normals(quats, scales))
    return d
