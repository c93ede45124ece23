"""Screen-tile binning of projected Gaussians and grouping of tiles into evaluation chunks."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass
class TileChunk:
    """Tiles evaluated together; each is padded to the chunk's largest pair count."""

    tile_ids: Tensor  # [T] int64
    max_pairs: int


@dataclass
class TileBins:
    """(tile, Gaussian) pairs sorted by tile, then front to back, as gsplat's isect_tiles produces."""

    tile_size: int
    tiles_x: int
    tiles_y: int
    gaussian_ids: Tensor  # [n_pairs] int64
    tile_starts: Tensor  # [n_tiles] int64, offset of each tile's first pair
    tile_counts: Tensor  # [n_tiles] int64

    @property
    def n_tiles(self) -> int:
        return self.tiles_x * self.tiles_y

    @property
    def n_pairs(self) -> int:
        return int(self.gaussian_ids.numel())


@dataclass
class TileBoxes:
    """Visible Gaussians (radii > 0) front to back, with the tile range their bounding box touches."""

    tiles_x: int
    tiles_y: int
    depth_order: Tensor  # [V] int64 Gaussian ids, nearest first (ties: lower id first)
    tile_min: Tensor  # [V, 2] int64 (x, y), inclusive
    tile_max: Tensor  # [V, 2] int64 (x, y), exclusive


@torch.no_grad()
def tile_boxes(means2d: Tensor, radii_xy: Tensor, depths: Tensor, width: int, height: int, tile_size: int) -> TileBoxes:
    """The tiles each visible Gaussian's bounding box touches, as gsplat's isect_tiles finds them."""
    device = means2d.device
    tiles_x = math.ceil(width / tile_size)
    tiles_y = math.ceil(height / tile_size)
    visible_ids = torch.nonzero(radii_xy[:, 0] > 0).squeeze(1)
    depth_order = visible_ids[torch.argsort(depths.detach()[visible_ids], stable=True)]
    centre = means2d.detach()[depth_order] / tile_size
    tile_radius = radii_xy[depth_order].to(centre.dtype) / tile_size
    upper = torch.tensor([tiles_x, tiles_y], device=device)
    tile_min = torch.minimum(torch.floor(centre - tile_radius).long().clamp_min(0), upper)
    tile_max = torch.minimum(torch.ceil(centre + tile_radius).long().clamp_min(0), upper)
    return TileBoxes(tiles_x, tiles_y, depth_order, tile_min, tile_max)


@torch.no_grad()
def bin_gaussians(
    means2d: Tensor,
    radii_xy: Tensor,
    depths: Tensor,
    width: int,
    height: int,
    tile_size: int,
) -> TileBins:
    """Bin visible Gaussians (radii > 0) to the tiles their bounding box touches, as gsplat does."""
    boxes = tile_boxes(means2d, radii_xy, depths, width, height, tile_size)
    device = means2d.device
    span = boxes.tile_max - boxes.tile_min
    pairs_per_gaussian = span[:, 0] * span[:, 1]
    n_visible = boxes.depth_order.numel()

    # pair_owner is a position in depth order, so sorting pairs by (tile, owner) keeps each tile front to back.
    pair_owner = torch.repeat_interleave(torch.arange(n_visible, device=device), pairs_per_gaussian)
    first_pair = torch.cumsum(pairs_per_gaussian, 0) - pairs_per_gaussian
    local = torch.arange(pair_owner.numel(), device=device) - first_pair[pair_owner]
    owner_span_x = span[pair_owner, 0]
    tile_x = boxes.tile_min[pair_owner, 0] + local % owner_span_x
    tile_y = boxes.tile_min[pair_owner, 1] + local // owner_span_x
    tile_of_pair = tile_y * boxes.tiles_x + tile_x

    order = torch.argsort(tile_of_pair * max(n_visible, 1) + pair_owner)
    gaussian_ids = boxes.depth_order[pair_owner[order]]
    tile_counts = torch.bincount(tile_of_pair, minlength=boxes.tiles_x * boxes.tiles_y)
    tile_starts = torch.cumsum(tile_counts, 0) - tile_counts
    return TileBins(tile_size, boxes.tiles_x, boxes.tiles_y, gaussian_ids, tile_starts, tile_counts)


def plan_chunks(tile_counts: Tensor, pixels_per_tile: int, chunk_elements: int, growth: float = 2.0) -> list[TileChunk]:
    """Group non-empty tiles of similar pair counts so padding stays small and chunks stay bounded.

    A chunk's work is n_tiles * max_pairs * pixels_per_tile fragments. Tiles are taken in order of
    pair count; a chunk closes when it would exceed chunk_elements, or when the next tile has more
    than `growth` times the chunk's smallest count and the chunk is already big enough that the
    per-chunk overhead is amortised. A tile larger than the budget gets a chunk of its own.
    """
    sorted_counts, order = torch.sort(tile_counts)
    first_nonempty = int(torch.searchsorted(sorted_counts, 1))
    counts = sorted_counts[first_nonempty:].tolist()
    order = order[first_nonempty:]
    amortised_elements = chunk_elements // 8
    chunks = []
    start = 0
    while start < len(counts):
        end = start + 1
        while end < len(counts):
            padded = (end + 1 - start) * counts[end] * pixels_per_tile
            current = (end - start) * counts[end - 1] * pixels_per_tile
            too_uneven = counts[end] > growth * counts[start] and current >= amortised_elements
            if padded > chunk_elements or too_uneven:
                break
            end += 1
        chunks.append(TileChunk(tile_ids=order[start:end], max_pairs=counts[end - 1]))
        start = end
    return chunks
