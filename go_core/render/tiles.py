"""Tile binning in torch (used by the reference backend).

Each visible Gaussian covers the rectangle of 16x16 tiles
``[floor((u - r)/16), ceil((u + r)/16)) x [floor((v - r)/16), ceil((v + r)/16))`` clamped to the image,
with ``r`` its integer 3-sigma radius. The compiled backend starts from the same rectangles and drops the
tiles no pixel of which the Gaussian can reach with alpha >= 1/255 (same images, fewer pairs).
Within a tile Gaussians are ordered front to back by depth, ties by
index (a stable sort), so results are deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

TILE = 16


@dataclass
class TileBins:
    """Per-tile depth-sorted Gaussian lists of one camera in CSR form."""

    tiles_x: int
    tiles_y: int
    offsets: torch.Tensor  # [tiles+1] int64
    gauss_ids: torch.Tensor  # [n_isect] int64, front to back within each tile


def tile_grid(width: int, height: int) -> tuple[int, int]:
    return math.ceil(width / TILE), math.ceil(height / TILE)


def tile_rects(means2d: torch.Tensor, radii: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """[N,4] int64 (x0, x1, y0, y1) tile rectangles (half-open; empty for culled Gaussians)."""
    tx, ty = tile_grid(width, height)
    m = means2d.detach().to(torch.float32)
    r = radii.to(torch.float32)
    x0 = torch.floor((m[:, 0] - r) / TILE).clamp(0, tx)
    x1 = torch.ceil((m[:, 0] + r) / TILE).clamp(0, tx)
    y0 = torch.floor((m[:, 1] - r) / TILE).clamp(0, ty)
    y1 = torch.ceil((m[:, 1] + r) / TILE).clamp(0, ty)
    rect = torch.stack([x0, x1, y0, y1], dim=-1).to(torch.int64)
    rect[radii <= 0] = 0
    return rect


def bin_gaussians(
    means2d: torch.Tensor, depths: torch.Tensor, radii: torch.Tensor, width: int, height: int
) -> TileBins:
    """Bin one camera's projected Gaussians ([N,2], [N], [N]) into depth-sorted tile lists."""
    tx, ty = tile_grid(width, height)
    n_tiles = tx * ty
    rect = tile_rects(means2d, radii, width, height)
    w = (rect[:, 1] - rect[:, 0]).clamp_min(0)
    h = (rect[:, 3] - rect[:, 2]).clamp_min(0)
    counts = w * h
    order = torch.sort(depths.detach(), stable=True).indices
    counts_o = counts[order]
    keep = counts_o > 0
    order, counts_o = order[keep], counts_o[keep]
    total = int(counts_o.sum())
    if total == 0:
        return TileBins(
            tx, ty, torch.zeros(n_tiles + 1, dtype=torch.int64), torch.zeros(0, dtype=torch.int64)
        )
    gid = torch.repeat_interleave(order, counts_o)
    start = torch.cumsum(counts_o, 0) - counts_o
    k = torch.arange(total, dtype=torch.int64) - torch.repeat_interleave(start, counts_o)
    wg = w[gid]
    tile = (rect[gid, 2] + k // wg) * tx + rect[gid, 0] + k % wg
    tile_sorted, perm = torch.sort(tile, stable=True)
    per_tile = torch.bincount(tile_sorted, minlength=n_tiles)
    offsets = torch.zeros(n_tiles + 1, dtype=torch.int64)
    offsets[1:] = torch.cumsum(per_tile, 0)
    return TileBins(tx, ty, offsets, gid[perm])
