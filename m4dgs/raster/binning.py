"""Tile binning: which Gaussians touch which 16x16 tile, front to back (vectorised torch, no
gradients)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .projection import tile_grid

TILE_SIZE = 16


@dataclass
class TileBins:
    """Per-tile depth-sorted Gaussian lists in CSR form.

    offsets: [tiles_y * tiles_x + 1] int32; tile t (row-major) owns ``flat_ids[offsets[t]:offsets[t
    + 1]]``. flat_ids: [M] int32 Gaussian indices, sorted by (tile, depth)."""

    offsets: Tensor
    flat_ids: Tensor
    tiles_x: int
    tiles_y: int
    tile_size: int


@torch.no_grad()
def bin_gaussians(
    means2d: Tensor,
    radii: Tensor,
    depths: Tensor,
    width: int,
    height: int,
    tile_size: int = TILE_SIZE,
) -> TileBins:
    """Bin Gaussians (means2d [N, 2], radii [N, 2] int, depths [N]) into tiles.

    A Gaussian covers tiles ``[floor((m - r) / ts), ceil((m + r) / ts))`` per axis, clipped to the
    grid (gsplat's ``isect_tiles``); Gaussians with a zero radius are skipped."""
    device = means2d.device
    tiles_x, tiles_y = tile_grid(width, height, tile_size)
    n_tiles = tiles_x * tiles_y
    vis = torch.nonzero((radii > 0).all(dim=-1)).squeeze(1)
    # visible Gaussians front to back (stable: equal depths keep index order)
    vis = vis[torch.argsort(depths.detach()[vis], stable=True)]
    m = means2d.detach()[vis].to(torch.float64) / tile_size
    r = radii[vis].to(torch.float64) / tile_size
    x0 = torch.floor(m[:, 0] - r[:, 0]).clamp(0, tiles_x).long()
    x1 = torch.ceil(m[:, 0] + r[:, 0]).clamp(0, tiles_x).long()
    y0 = torch.floor(m[:, 1] - r[:, 1]).clamp(0, tiles_y).long()
    y1 = torch.ceil(m[:, 1] + r[:, 1]).clamp(0, tiles_y).long()
    bw = (x1 - x0).clamp_min(0)
    counts = bw * (y1 - y0).clamp_min(0)
    n_isect = int(counts.sum())
    if n_isect == 0:
        return TileBins(
            torch.zeros(n_tiles + 1, dtype=torch.int32, device=device),
            torch.zeros(0, dtype=torch.int32, device=device),
            tiles_x,
            tiles_y,
            tile_size,
        )
    # one (tile, Gaussian) pair per covered tile, generated in depth order
    start = torch.cumsum(counts, 0) - counts
    per_g = torch.stack([start, bw, x0, y0], dim=-1)  # [Nv, 4]
    g = torch.repeat_interleave(torch.arange(vis.numel(), device=device), counts)  # [M] depth rank
    st, w, gx0, gy0 = per_g[g].unbind(-1)
    local = torch.arange(n_isect, device=device) - st
    tile = ((gy0 + local // w) * tiles_x + gx0 + local % w).to(torch.int32)
    # a stable sort by tile keeps the depth order inside each tile
    tile, perm = torch.sort(tile, stable=True)
    flat_ids = vis[g[perm]].to(torch.int32)
    offsets = torch.zeros(n_tiles + 1, dtype=torch.int64, device=device)
    offsets[1:] = torch.cumsum(torch.bincount(tile.long(), minlength=n_tiles), 0)
    return TileBins(offsets.to(torch.int32), flat_ids.contiguous(), tiles_x, tiles_y, tile_size)
