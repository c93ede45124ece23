"""Screen-tile binning of projected Gaussians and grouping of tiles into evaluation chunks."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from liquidgs.render.projection import ALPHA_THRESHOLD

FOOTPRINT_MARGIN = 1e-3
"""Added to each Gaussian's cut-off ln(opacity / ALPHA_THRESHOLD) before tiles are tested against
its ellipse, so no rounding in the float32 composite meets a fragment whose tile the test dropped."""


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


def footprint_columns(
    means2d: Tensor, conics: Tensor, opacities: Tensor, rows: Tensor, tile_size: int
) -> tuple[Tensor, Tensor]:
    """The tile columns [first, last] (float64) of tile row `rows` [P] holding a pixel centre where
    each Gaussian (means2d [P,2], conics [P,3], opacities [P]) can reach ALPHA_THRESHOLD: the ellipse
    0.5 a u^2 + b u v + 0.5 c v^2 <= ln(opacity / threshold) + FOOTPRINT_MARGIN (u, v: offsets
    from the mean) over the band of the row's pixel centres - Speedy-Splat's exact tile test, a row
    at a time. A conic that is not positive definite gets every column (-inf, inf). Only tiles in
    which no fragment is drawn are left out, so the image is the one the whole box gives; the
    compiled binning (cpu_composite.cpp) computes the same in the same order."""
    mx, my = means2d[:, 0].double(), means2d[:, 1].double()
    a, b, c = conics.double().unbind(1)
    cut = torch.log(opacities.double() / ALPHA_THRESHOLD).clamp_min(0.0) + FOOTPRINT_MARGIN
    inverse_a, reach_sq, det = 1.0 / a, 2.0 * cut * a, a * c - b * b
    reach_v = torch.sqrt(reach_sq / det)  # the ellipse's half height
    extreme_v = -b * torch.sqrt(2.0 * cut / (det * c))  # where it reaches furthest right
    band_low = rows.double() * tile_size + 0.5 - my
    band_high = band_low + (tile_size - 1)
    low, high = torch.maximum(band_low, -reach_v), torch.minimum(band_high, reach_v)

    def half_width(v: Tensor) -> Tensor:
        return torch.sqrt((reach_sq - det * v * v).clamp_min(0.0))

    right_v = torch.minimum(torch.maximum(extreme_v, low), high)
    left_v = torch.minimum(torch.maximum(-extreme_v, low), high)
    right = mx + (-b * right_v + half_width(right_v)) * inverse_a
    left = mx + (-b * left_v - half_width(left_v)) * inverse_a
    inverse_tile = 1.0 / tile_size
    first = torch.ceil((left + 0.5) * inverse_tile - 1.0)
    last = torch.where(low <= high, torch.floor((right - 0.5) * inverse_tile), first - 1)  # no band: no column
    exact = (a > 0) & (c > 0) & (det > 0) & torch.isfinite(first) & torch.isfinite(last)
    return torch.where(exact, first, -math.inf), torch.where(exact, last, math.inf)


@torch.no_grad()
def bin_gaussians(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    radii_xy: Tensor,
    depths: Tensor,
    width: int,
    height: int,
    tile_size: int,
) -> TileBins:
    """Bin visible Gaussians (radii > 0) to the tiles of their bounding box (as gsplat does) that
    hold a pixel their alpha can reach (footprint_columns)."""
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
    ids = boxes.depth_order[pair_owner]
    first, last = footprint_columns(means2d[ids], conics[ids], opacities[ids], tile_y, tile_size)
    kept = (tile_x >= first) & (tile_x <= last)
    pair_owner, tile_of_pair = pair_owner[kept], (tile_y * boxes.tiles_x + tile_x)[kept]

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
