"""Dense all-pairs compositing: every pixel against every Gaussian, no tiles and no culling shortcuts.

This is the plain reference the tiled backend is tested against and the baseline the benchmark
times. It follows the same per-pixel rules as gsplat's kernel, written in the product domain with
torch.cumprod so that it shares no arithmetic with the tiled implementation.
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.utils.checkpoint import checkpoint

from liquidgs.render.composite import MAX_ALPHA, MIN_TRANSMITTANCE
from liquidgs.render.projection import ALPHA_THRESHOLD


def _composite_pixels(
    pixels: Tensor, means2d: Tensor, conics: Tensor, opacities: Tensor, features: Tensor
) -> tuple[Tensor, Tensor]:
    """Pixels [P,2] against depth-sorted Gaussians: ([P,F] sum of w * f, [P] final transmittance)."""
    delta = means2d[None, :, :] - pixels[:, None, :]
    dx, dy = delta[..., 0], delta[..., 1]
    sigma = 0.5 * (conics[:, 0] * dx * dx + conics[:, 2] * dy * dy) + conics[:, 1] * dx * dy
    alpha = torch.clamp(opacities * torch.exp(-sigma), max=MAX_ALPHA)
    kept = (sigma >= 0) & (alpha >= ALPHA_THRESHOLD)
    one_minus_alpha = torch.where(kept, 1.0 - alpha, torch.ones_like(alpha))
    transmittance_after = torch.cumprod(one_minus_alpha, dim=1)
    composited = kept & (transmittance_after > MIN_TRANSMITTANCE)
    transmittance_before = torch.cat([torch.ones_like(transmittance_after[:, :1]), transmittance_after[:, :-1]], dim=1)
    weights = torch.where(composited, alpha * transmittance_before, torch.zeros_like(alpha))
    final = torch.where(composited, one_minus_alpha, torch.ones_like(alpha)).prod(dim=1)
    return weights @ features, final


def composite_dense(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    features: Tensor,
    depths: Tensor,
    visible: Tensor,
    width: int,
    height: int,
    pixel_chunk: int = 4096,
    checkpointed: bool = False,
) -> tuple[Tensor, Tensor]:
    """All-pairs compositing of the visible Gaussians: ([H,W,F] sum of w * f, [H,W,1] alpha).

    Pixels are processed in chunks of `pixel_chunk`; with checkpointed=True each chunk is
    recomputed in backward instead of kept, which bounds memory for large scenes.
    """
    ids = torch.nonzero(visible).squeeze(1)
    ids = ids[torch.argsort(depths.detach()[ids], stable=True)]
    rows, cols = torch.meshgrid(
        torch.arange(height, device=means2d.device), torch.arange(width, device=means2d.device), indexing="ij"
    )
    pixels = torch.stack([cols, rows], dim=-1).reshape(-1, 2).to(means2d.dtype) + 0.5
    sorted_inputs = (means2d[ids], conics[ids], opacities[ids], features[ids])
    feature_chunks, transmittance_chunks = [], []
    for start in range(0, pixels.shape[0], pixel_chunk):
        chunk = pixels[start : start + pixel_chunk]
        if checkpointed:
            out, final = checkpoint(_composite_pixels, chunk, *sorted_inputs, use_reentrant=False)
        else:
            out, final = _composite_pixels(chunk, *sorted_inputs)
        feature_chunks.append(out)
        transmittance_chunks.append(final)
    accumulated = torch.cat(feature_chunks).reshape(height, width, -1)
    alpha = 1.0 - torch.cat(transmittance_chunks).reshape(height, width, 1)
    return accumulated, alpha
