"""The portable PyTorch backend: project, bin into tiles, composite front to back.

Its pipeline is shared with the compiled CPU backend, which swaps in its own stages.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor

from liquidgs.cameras import view_centre
from liquidgs.render.composite import composite_tiles
from liquidgs.render.contract import RasterOptions, RenderOutput, render_output
from liquidgs.render.projection import project_gaussians
from liquidgs.render.tiles import bin_gaussians
from liquidgs.sh import eval_sh


def unavailable_reason(means: Tensor) -> str | None:
    """Always None: the torch backend runs wherever torch does."""
    return None


def view_colors(colors: Tensor, sh_degree: int | None, means: Tensor, viewmat: Tensor) -> Tensor:
    """Per-Gaussian RGB [N,3]: the input itself, or SH at the view direction + 0.5 clamped at 0."""
    if sh_degree is None:
        return colors
    return torch.clamp_min(eval_sh(sh_degree, colors, means - view_centre(viewmat)) + 0.5, 0.0)


@dataclass(frozen=True)
class TiledStages:
    """The four stages of a tiled backend, each with the signature of the torch version here."""

    project: Callable
    view_colors: Callable
    bin: Callable
    composite: Callable  # (means2d, conics, opacities, features, bins, width, height, absgrad, chunk_elements)


TORCH_STAGES = TiledStages(project_gaussians, view_colors, bin_gaussians, composite_tiles)


def render_tiled(
    stages: TiledStages, backend: str, means, quats, scales, opacities, colors, features, viewmat, K, width: int,
    height: int, options: RasterOptions,
) -> RenderOutput:  # fmt: skip
    """The tiled pipeline with `stages`; info["backend"] is `backend`. The extra features, if any,
    are composited as channels after RGB and depth."""
    projection = stages.project(
        means, quats, scales, opacities, viewmat, K, width, height, options.near_plane, options.far_plane, options.eps2d
    )
    means2d = projection.means2d
    if means2d.requires_grad:
        means2d.retain_grad()
    rgb_colors = stages.view_colors(colors, options.sh_degree, means, viewmat)
    channels = [rgb_colors, projection.depths[:, None]] + ([] if features is None else [features])
    bins = stages.bin(
        means2d, projection.conics, opacities, projection.radii_xy, projection.depths, width, height, options.tile_size
    )
    image, alpha = stages.composite(
        means2d, projection.conics, opacities, torch.cat(channels, dim=1), bins, width, height, options.absgrad,
        options.chunk_elements,
    )  # fmt: skip
    rgb = image[..., :3] + (1.0 - alpha) * options.background
    return render_output(
        rgb, alpha, image[..., 3:4], projection,
        width=width, height=height, backend=backend, tile_size=options.tile_size, n_pairs=bins.n_pairs,
        features=None if features is None else image[..., 4:],
    )  # fmt: skip


def render(
    means, quats, scales, opacities, colors, features, viewmat, K, width: int, height: int, options: RasterOptions
) -> RenderOutput:
    return render_tiled(
        TORCH_STAGES, "torch", means, quats, scales, opacities, colors, features, viewmat, K, width, height, options
    )
