"""Rendering the Gaussians of either stage: HDR colour, depth, alpha and, as extra feature channels,
the Gaussians' positions at destination times (from which the rendered flow / track maps follow).

`render_gaussians` works for any Gaussian set with positions(t), quats(t), scales(), opacities() and
features(): stage 1 draws its video Gaussians with it through the orthographic video camera J_ortho
(identity view, camera_model "ortho", paper sec. 3.3.1); `render_world` draws world Gaussians (stage
2 and the trained model) from a pinhole camera. The HDR colour of each Gaussian is the colour MLP's,
times its brightness gain at the render time when the Gaussians carry one (beyond the paper;
`gaussian_colors`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, List, Optional, Sequence

import torch

from m4dgs.core import camera as cam
from m4dgs.model.background import Background
from m4dgs.model.color import ColorMLP, color_directions
from m4dgs.raster import render


def gaussian_colors(
    gauss, color: ColorMLP, t: float, dirs: Optional[torch.Tensor] = None
) -> torch.Tensor:
    """HDR colour [N, 3] of each Gaussian at time t: color(features, dirs), times 2 ** g(t) when
    the Gaussians carry a log2 gain over time (`log2_gain(t)`, beyond the paper:
    ModelConfig.appearance_knots); without one exactly the colour MLP's output."""
    hdr = color(gauss.features(), dirs)
    gain_at = getattr(gauss, "log2_gain", None)
    gain = gain_at(t) if gain_at is not None else None
    return hdr if gain is None else hdr * torch.exp2(gain.to(hdr.dtype))


@dataclass
class RenderResult:
    hdr: torch.Tensor  # [H, W, 3]
    depth: torch.Tensor  # [H, W]
    alpha: torch.Tensor  # [H, W]
    # destination-position maps [H, W, 3] (alpha-blended), one per requested destination time
    dest: List[torch.Tensor]
    meta: Any  # m4dgs.raster.RenderMeta (means2d / radii for densification)


def render_gaussians(
    gauss,
    color: ColorMLP,
    bg: Background,
    t: float,
    view: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    camera_model: str,
    backend: str = "auto",
    dest_times: Sequence[float] = (),
) -> RenderResult:
    """Render `gauss` at time t with intrinsics K [3, 3]: camera_model "ortho" (`view` is the
    world-to-camera matrix [4, 4]) or "pinhole" (`view` is the camera-to-world pose c2w [4, 4]).

    Features: HDR colour (3, background 2^b; with a view-dependent colour MLP and a pinhole camera,
    of the feature and the direction from the camera centre c2w[:3, 3] to each Gaussian, or that
    direction mirrored about the Gaussian's normal (`color_directions`); times the
    Gaussian's gain at t when it has one, `gaussian_colors`) + the Gaussians' positions at each
    destination time (3 each, background 0), alpha-blended."""
    if dest_times:
        # one spline evaluation for the render time and every destination time: [N, 1 + D, 3]
        times = torch.tensor([float(t)] + [float(d) for d in dest_times], device=K.device)
        pos = gauss.positions(times)
        means, dest_pos = pos[:, 0], pos[:, 1:].reshape(pos.shape[0], -1)
    else:
        means, dest_pos = gauss.positions(t), None
    quats, scales = gauss.quats(t), gauss.scales()
    # directions for a view-dependent colour MLP (view or reflected, `color_directions`): pinhole
    # renders only (the orthographic video camera has none; the MLP then sees zeros)
    dirs = (
        color_directions(color, means, quats, scales, view[:3, 3])
        if camera_model == "pinhole"
        else None
    )
    hdr = gaussian_colors(gauss, color, t, dirs)
    feats = hdr if dest_pos is None else torch.cat([hdr, dest_pos], -1)
    background = torch.cat([bg(), means.new_zeros(feats.shape[1] - 3)])
    out = render(
        means,
        quats,
        scales,
        gauss.opacities(),
        feats,
        cam.invert_rigid(view) if camera_model == "pinhole" else view,
        K,
        width,
        height,
        camera_model=camera_model,
        backend=backend,
        background=background,
    )
    f = out.features
    dest = [f[..., 3 + 3 * i : 6 + 3 * i] for i in range(len(dest_times))]
    return RenderResult(f[..., :3], out.depth[..., 0], out.alpha[..., 0], dest, out.meta)


def render_world(
    gauss,
    color: ColorMLP,
    bg: Background,
    t: float,
    c2w: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    backend: str = "auto",
    dest_times: Sequence[float] = (),
) -> RenderResult:
    """Render world Gaussians at time t from a pinhole camera c2w [4, 4] (OpenCV) with intrinsics
    K [3, 3]; destination maps hold world positions."""
    return render_gaussians(
        gauss, color, bg, t, c2w, K, width, height, "pinhole", backend, dest_times
    )
