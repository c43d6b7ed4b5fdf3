"""Backward warping by optical flow and forward-backward flow consistency.

Conventions (m4dgs.core.camera, docs/clip-format.md): flow F_{a->b} is given per pixel of frame a
as (dx, dy) in pixels, pixel centres at integer + 0.5. Backward warping W(I_b, F_{a->b}) samples I_b
at x + F_{a->b}(x) and so expresses frame b on the pixel grid of frame a. `sample_map` and
`sample_per_frame` sample maps at continuous pixel coordinates with the same convention."""

from __future__ import annotations

import torch
import torch.nn.functional as F


def pixel_grid(height: int, width: int, *, dtype=torch.float32, device=None) -> torch.Tensor:
    """[H, W, 2] integer pixel coordinates (x, y) of each pixel (index space; centres are at +0.5 in
    continuous coordinates, so index space and centre space differ by a constant that cancels in
    displacements)."""
    ys, xs = torch.meshgrid(
        torch.arange(height, dtype=dtype, device=device),
        torch.arange(width, dtype=dtype, device=device),
        indexing="ij",
    )
    return torch.stack([xs, ys], dim=-1)


def backward_warp(
    image: torch.Tensor, flow: torch.Tensor, padding_mode: str = "border"
) -> torch.Tensor:
    """Sample `image` at x + flow(x) with bilinear interpolation.

    Args:
        image: [H, W, C] image of the destination frame b.
        flow:  [H, W, 2] flow F_{a->b} on the grid of frame a (pixels).
        padding_mode: grid_sample padding ("border" as in the authors' HDR-TAE, or "zeros").
    Returns:
        [H, W, C] frame b resampled onto frame a's grid. Uses align_corners=True on pixel indices,
        so an integer flow gives an exact shift.
    """
    h, w = flow.shape[:2]
    hb, wb = image.shape[:2]
    pos = pixel_grid(h, w, dtype=flow.dtype, device=flow.device) + flow
    gx = pos[..., 0] / max(wb - 1, 1) * 2.0 - 1.0
    gy = pos[..., 1] / max(hb - 1, 1) * 2.0 - 1.0
    grid = torch.stack([gx, gy], dim=-1)[None]
    out = F.grid_sample(
        image.permute(2, 0, 1)[None].to(flow.dtype),
        grid,
        mode="bilinear",
        padding_mode=padding_mode,
        align_corners=True,
    )
    return out[0].permute(1, 2, 0)


def sample_map(image: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of ONE map at N points: image [H, W, C], uv [N, 2] continuous pixel
    coordinates (centres at +0.5) -> [N, C].

    Same sampling convention as `backward_warp` (index coordinates uv - 0.5, align_corners=True,
    border padding) and implemented through it, so it is differentiable in `image` and `uv`."""
    n = uv.shape[0]
    idx = uv - 0.5
    grid = pixel_grid(1, n, dtype=uv.dtype, device=uv.device)  # [1, N, 2]: (i, 0)
    flow = idx[None] - grid
    return backward_warp(image, flow)[0]


def sample_per_frame(maps: torch.Tensor, uv: torch.Tensor, mode: str = "bilinear") -> torch.Tensor:
    """Samples of T single-channel maps along N tracks: maps [T, H, W], uv [N, T, 2] continuous
    pixel coordinates (centres at +0.5; uv[:, t] samples maps[t]) -> [N, T].

    Border clamp; mode "bilinear" (explicit four-tap gather in the maps' dtype, exact on pixel
    centres; no gradient through uv) or "nearest". Used on CPU float64 prior maps by the camera
    initialisation (m4dgs.priors.camera_init)."""
    T, H, W = maps.shape
    x = (uv[..., 0] - 0.5).clamp(0, W - 1)
    y = (uv[..., 1] - 0.5).clamp(0, H - 1)
    if mode == "nearest":
        xi = x.round().long()
        yi = y.round().long()
        return maps[torch.arange(T, device=maps.device)[None].expand_as(xi), yi, xi]
    x0 = x.floor().long().clamp(0, W - 1)
    y0 = y.floor().long().clamp(0, H - 1)
    x1 = (x0 + 1).clamp(max=W - 1)
    y1 = (y0 + 1).clamp(max=H - 1)
    fx = (x - x0).to(maps.dtype)
    fy = (y - y0).to(maps.dtype)
    ti = torch.arange(T, device=maps.device)[None].expand_as(x0)
    v00, v01 = maps[ti, y0, x0], maps[ti, y0, x1]
    v10, v11 = maps[ti, y1, x0], maps[ti, y1, x1]
    return (v00 * (1 - fx) + v01 * fx) * (1 - fy) + (v10 * (1 - fx) + v11 * fx) * fy


def fb_consistency(
    flow_fwd: torch.Tensor, flow_bwd: torch.Tensor, alpha: float = 0.5, beta: float = 0.5
) -> torch.Tensor:
    """Visibility of frame a's pixels in frame b from forward-backward consistency.

    A pixel is visible when |f + b(x + f)| < alpha * (|f| + |b(x + f)|) + beta (norms over the 2
    flow components).

    Args:
        flow_fwd: [H, W, 2] F_{a->b}; flow_bwd: [H, W, 2] F_{b->a}.
    Returns:
        [H, W] bool mask.
    """
    b_at = backward_warp(flow_bwd, flow_fwd)
    lhs = torch.linalg.norm(flow_fwd + b_at, dim=-1)
    rhs = alpha * (torch.linalg.norm(flow_fwd, dim=-1) + torch.linalg.norm(b_at, dim=-1)) + beta
    return lhs < rhs
