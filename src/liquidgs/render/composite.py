"""Tile-based front-to-back alpha compositing with an analytic backward, following gsplat's kernels.

Per pixel, fragments are taken front to back. alpha = min(0.999, opacity * exp(-sigma)); fragments
with sigma < 0 or alpha < 1/255 are skipped; a fragment whose transmittance after it would fall to
<= 1e-4 is not composited and ends the pixel. Each chunk of tiles is evaluated as dense
[tiles, pairs, pixels] tensors; the backward recomputes a chunk's fragments instead of storing
them, so memory stays bounded by one chunk in both passes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from liquidgs.render.projection import ALPHA_THRESHOLD
from liquidgs.render.tiles import TileBins, TileChunk, plan_chunks

# gsplat's per-fragment alpha clamp and the transmittance that ends a pixel (cpu_backend.py builds
# the compiled kernel with these values).
MAX_ALPHA = 0.999
MIN_TRANSMITTANCE = 1e-4
DEFAULT_CHUNK_ELEMENTS = 1 << 20
LOG_MIN_TRANSMITTANCE = math.log(MIN_TRANSMITTANCE)


@dataclass
class _Fragments:
    """A chunk's fragments: pairs on dim 1 (front to back), the tile's pixels on dim 2."""

    gaussian_ids: Tensor  # [T, P]
    dx: Tensor  # [T, P, S] mean minus pixel centre
    dy: Tensor
    conics: Tensor  # [T, P, 3]
    falloff: Tensor  # [T, P, S] exp(-sigma)
    gauss_alpha: Tensor  # [T, P, S] opacity * exp(-sigma), before the 0.999 clamp
    weights: Tensor  # [T, P, S] alpha * transmittance, 0 where not composited
    alphas: Tensor  # [T, P, S] clamped alpha, 0 where not composited
    composited: Tensor  # [T, P, S] bool
    transmittance_before: Tensor  # [T, P, S]
    final_transmittance: Tensor  # [T, S]


def _pixel_centres(bins: TileBins, tile_ids: Tensor, dtype: torch.dtype) -> tuple[Tensor, Tensor]:
    size = bins.tile_size
    local = torch.arange(size * size, device=tile_ids.device)
    origin_x = (tile_ids % bins.tiles_x) * size
    origin_y = (tile_ids // bins.tiles_x) * size
    pixel_x = (origin_x[:, None] + local % size).to(dtype) + 0.5
    pixel_y = (origin_y[:, None] + local // size).to(dtype) + 0.5
    return pixel_x, pixel_y


def _evaluate_chunk(bins: TileBins, chunk: TileChunk, means2d: Tensor, conics: Tensor, opacities: Tensor) -> _Fragments:
    slot = torch.arange(chunk.max_pairs, device=means2d.device)
    starts = bins.tile_starts[chunk.tile_ids]
    in_tile = slot < bins.tile_counts[chunk.tile_ids][:, None]
    pair_index = torch.where(in_tile, starts[:, None] + slot, starts[:, None])
    gaussian_ids = bins.gaussian_ids[pair_index]
    # Padding slots get zero opacity, which makes them skipped fragments.
    pair_opacity = torch.where(in_tile, opacities[gaussian_ids], torch.zeros((), dtype=opacities.dtype))
    pair_means = means2d[gaussian_ids]
    pair_conics = conics[gaussian_ids]

    pixel_x, pixel_y = _pixel_centres(bins, chunk.tile_ids, means2d.dtype)
    dx = pair_means[..., 0:1] - pixel_x[:, None, :]
    dy = pair_means[..., 1:2] - pixel_y[:, None, :]
    con_a, con_b, con_c = (pair_conics[..., k : k + 1] for k in range(3))
    sigma = 0.5 * (con_a * dx * dx + con_c * dy * dy) + con_b * dx * dy
    falloff = torch.exp(-sigma)
    gauss_alpha = pair_opacity[..., None] * falloff
    alpha = gauss_alpha.clamp_max(MAX_ALPHA)
    kept = (sigma >= 0) & (alpha >= ALPHA_THRESHOLD)
    alpha = torch.where(kept, alpha, torch.zeros((), dtype=alpha.dtype))
    log_trans = torch.log1p(-alpha)
    log_trans_after = torch.cumsum(log_trans, dim=1)
    # Transmittance only falls, so the composited fragments are a prefix of the kept ones and their
    # running sums over kept fragments equal those over composited ones.
    composited = kept & (log_trans_after > LOG_MIN_TRANSMITTANCE)
    zero = torch.zeros((), dtype=alpha.dtype)
    alpha = torch.where(composited, alpha, zero)
    transmittance_before = torch.exp(log_trans_after - log_trans)
    weights = alpha * transmittance_before
    final_transmittance = torch.exp(torch.where(composited, log_trans, zero).sum(dim=1))
    return _Fragments(
        gaussian_ids=gaussian_ids,
        dx=dx,
        dy=dy,
        conics=pair_conics,
        falloff=falloff,
        gauss_alpha=gauss_alpha,
        weights=weights,
        alphas=alpha,
        composited=composited,
        transmittance_before=transmittance_before,
        final_transmittance=final_transmittance,
    )


def _tiles_to_image(per_tile: Tensor, bins: TileBins, width: int, height: int) -> Tensor:
    size = bins.tile_size
    channels = per_tile.shape[2:]
    grid = per_tile.reshape(bins.tiles_y, bins.tiles_x, size, size, *channels).transpose(1, 2)
    return grid.reshape(bins.tiles_y * size, bins.tiles_x * size, *channels)[:height, :width]


def _image_to_tiles(image: Tensor, bins: TileBins) -> Tensor:
    size = bins.tile_size
    height, width = image.shape[:2]
    channels = image.shape[2:]
    padded = image.new_zeros(bins.tiles_y * size, bins.tiles_x * size, *channels)
    padded[:height, :width] = image
    grid = padded.reshape(bins.tiles_y, size, bins.tiles_x, size, *channels).transpose(1, 2)
    return grid.reshape(bins.n_tiles, size * size, *channels)


class _CompositeTiles(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, bins: TileBins, chunks, width: int, height: int, absgrad):
        pixels = bins.tile_size**2
        out_features = features.new_zeros(bins.n_tiles, pixels, features.shape[1])
        out_transmittance = features.new_ones(bins.n_tiles, pixels)
        for chunk in chunks:
            frags = _evaluate_chunk(bins, chunk, means2d, conics, opacities)
            pair_features = features[frags.gaussian_ids]
            out_features[chunk.tile_ids] = torch.bmm(frags.weights.transpose(1, 2), pair_features)
            out_transmittance[chunk.tile_ids] = frags.final_transmittance
        ctx.bins, ctx.chunks, ctx.absgrad = bins, chunks, absgrad
        ctx.save_for_backward(means2d, conics, opacities, features)
        return (
            _tiles_to_image(out_features, bins, width, height),
            _tiles_to_image(1.0 - out_transmittance, bins, width, height),
        )

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_features_image, grad_alpha_image):
        means2d, conics, opacities, features = ctx.saved_tensors
        bins: TileBins = ctx.bins
        grad_features_tiles = _image_to_tiles(grad_features_image, bins)
        grad_alpha_tiles = _image_to_tiles(grad_alpha_image, bins)
        grad_means2d = torch.zeros_like(means2d)
        abs_grad_means2d = torch.zeros_like(means2d) if ctx.absgrad else None
        grad_conics = torch.zeros_like(conics)
        grad_opacities = torch.zeros_like(opacities)
        grad_features = torch.zeros_like(features)
        for chunk in ctx.chunks:
            frags = _evaluate_chunk(bins, chunk, means2d, conics, opacities)
            ids = frags.gaussian_ids.reshape(-1)
            grad_out = grad_features_tiles[chunk.tile_ids]  # [T, S, F]
            grad_out_alpha = grad_alpha_tiles[chunk.tile_ids]  # [T, S]
            pair_features = features[frags.gaussian_ids]
            grad_pair_features = torch.bmm(frags.weights, grad_out)
            grad_features.index_add_(0, ids, grad_pair_features.reshape(-1, features.shape[1]))

            # dL/dw for each fragment, then the effect of alpha_k on its own weight and, through the
            # transmittance, on every fragment behind it and on the pixel's alpha.
            grad_weight = torch.bmm(pair_features, grad_out.transpose(1, 2))  # [T, P, S]
            weighted = frags.weights * grad_weight
            behind = weighted.sum(dim=1, keepdim=True) - torch.cumsum(weighted, dim=1)
            through_transmittance = behind - (grad_out_alpha * frags.final_transmittance)[:, None, :]
            grad_alpha = frags.transmittance_before * grad_weight - through_transmittance / (1.0 - frags.alphas)
            unclamped = frags.composited & (frags.gauss_alpha <= MAX_ALPHA)
            grad_alpha = torch.where(unclamped, grad_alpha, torch.zeros((), dtype=grad_alpha.dtype))

            grad_opacities.index_add_(0, ids, (grad_alpha * frags.falloff).sum(dim=2).reshape(-1))
            grad_sigma = -grad_alpha * frags.gauss_alpha
            con_a, con_b, con_c = (frags.conics[..., k : k + 1] for k in range(3))
            per_pixel_x = grad_sigma * (con_a * frags.dx + con_b * frags.dy)
            per_pixel_y = grad_sigma * (con_b * frags.dx + con_c * frags.dy)
            grad_pair_means = torch.stack([per_pixel_x.sum(dim=2), per_pixel_y.sum(dim=2)], dim=-1)
            grad_means2d.index_add_(0, ids, grad_pair_means.reshape(-1, 2))
            if abs_grad_means2d is not None:
                abs_pair = torch.stack([per_pixel_x.abs().sum(dim=2), per_pixel_y.abs().sum(dim=2)], dim=-1)
                abs_grad_means2d.index_add_(0, ids, abs_pair.reshape(-1, 2))
            grad_pair_conics = torch.stack(
                [
                    0.5 * (grad_sigma * frags.dx * frags.dx).sum(dim=2),
                    (grad_sigma * frags.dx * frags.dy).sum(dim=2),
                    0.5 * (grad_sigma * frags.dy * frags.dy).sum(dim=2),
                ],
                dim=-1,
            )
            grad_conics.index_add_(0, ids, grad_pair_conics.reshape(-1, 3))
        if abs_grad_means2d is not None:
            # gsplat's convention: the summed per-pixel |dL/dmeans2d| lands on means2d.absgrad.
            means2d.absgrad = abs_grad_means2d
        return grad_means2d, grad_conics, grad_opacities, grad_features, None, None, None, None, None


def composite_tiles(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    features: Tensor,
    bins: TileBins,
    width: int,
    height: int,
    absgrad: bool = False,
    chunk_elements: int = DEFAULT_CHUNK_ELEMENTS,
) -> tuple[Tensor, Tensor]:
    """Composite per-Gaussian features [N, F] front to back into ([H, W, F] sum of w * f, [H, W, 1] alpha).

    With absgrad, backward also sets means2d.absgrad to the per-Gaussian sum over pixels of the
    absolute per-pixel gradient (the AbsGS definition gsplat uses). chunk_elements bounds the
    fragments (tiles x pairs x pixels) evaluated at once, and so peak memory in both passes.
    """
    chunks = plan_chunks(bins.tile_counts, bins.tile_size**2, chunk_elements)
    features_image, alpha_image = _CompositeTiles.apply(
        means2d, conics, opacities, features, bins, chunks, width, height, absgrad
    )
    return features_image, alpha_image.unsqueeze(-1)
