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
    chunks: list[TileChunk]

    @property
    def n_tiles(self) -> int:
        return self.tiles_x * self.tiles_y

    @property
    def n_pairs(self) -> int:
        return int(self.gaussian_ids.numel())


@torch.no_grad()
def bin_gaussians(
    means2d: Tensor,
    radii_xy: Tensor,
    depths: Tensor,
    width: int,
    height: int,
    tile_size: int,
    chunk_elements: int,
) -> TileBins:
    """Bin visible Gaussians (radii > 0) to the tiles their bounding box touches, as gsplat does."""
    device = means2d.device
    tiles_x = math.ceil(width / tile_size)
    tiles_y = math.ceil(height / tile_size)
    visible_ids = torch.nonzero(radii_xy[:, 0] > 0).squeeze(1)
    centre = means2d.detach()[visible_ids] / tile_size
    tile_radius = radii_xy[visible_ids].to(centre.dtype) / tile_size
    upper = torch.tensor([tiles_x, tiles_y], device=device)
    tile_min = torch.minimum(torch.floor(centre - tile_radius).long().clamp_min(0), upper)
    tile_max = torch.minimum(torch.ceil(centre + tile_radius).long().clamp_min(0), upper)
    span = tile_max - tile_min
    pairs_per_gaussian = span[:, 0] * span[:, 1]

    pair_owner = torch.repeat_interleave(torch.arange(visible_ids.numel(), device=device), pairs_per_gaussian)
    first_pair = torch.cumsum(pairs_per_gaussian, 0) - pairs_per_gaussian
    local = torch.arange(pair_owner.numel(), device=device) - first_pair[pair_owner]
    owner_span_x = span[pair_owner, 0]
    tile_x = tile_min[pair_owner, 0] + local % owner_span_x
    tile_y = tile_min[pair_owner, 1] + local // owner_span_x
    tile_of_pair = tile_y * tiles_x + tile_x

    depth_rank = torch.empty_like(visible_ids)
    depth_rank[torch.argsort(depths.detach()[visible_ids], stable=True)] = torch.arange(
        visible_ids.numel(), device=device
    )
    sort_key = tile_of_pair * max(visible_ids.numel(), 1) + depth_rank[pair_owner]
    order = torch.argsort(sort_key)
    gaussian_ids = visible_ids[pair_owner[order]]

    tile_counts = torch.bincount(tile_of_pair, minlength=tiles_x * tiles_y)
    tile_starts = torch.cumsum(tile_counts, 0) - tile_counts
    chunks = plan_chunks(tile_counts, tile_size * tile_size, chunk_elements)
    return TileBins(tile_size, tiles_x, tiles_y, gaussian_ids, tile_starts, tile_counts, chunks)


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
