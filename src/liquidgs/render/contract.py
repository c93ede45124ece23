"""The backends' contract: what `rasterize` hands each backend and the one RenderOutput every
backend returns, its `info` built here for all of them.

A backend is a module with `unavailable_reason(means) -> str | None` (None: it runs on means'
device and dtype) and `render(means, quats, scales, opacities, colors, features, viewmat, K, width,
height, options) -> RenderOutput`, features being None or the extra channels [N, C] it composites
in the same pass as colour; `rasterize` has validated and moved the inputs to means' device and dtype.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from torch import Tensor

from liquidgs.render.projection import Projection


@dataclass(frozen=True)
class RasterOptions:
    """The settings of one `rasterize` call, with the defaults resolved (see `rasterize`)."""

    sh_degree: int | None
    background: Tensor  # [3]
    near_plane: float
    far_plane: float
    eps2d: float
    absgrad: bool
    tile_size: int
    chunk_elements: int  # bounds the torch backend's memory; the others ignore it


MAX_EXTRA_FEATURES = 4
"""The most extra feature channels one `rasterize` call composites (the compiled CPU kernel is built
for each count up to this; a screen motion takes 2)."""

# gsplat's "ED" depth divides by alpha clamped at this value.
DEPTH_ALPHA_FLOOR = 1e-10


@dataclass
class RenderOutput:
    """One rendered view. info holds gsplat-style per-Gaussian metadata (see `rasterize`)."""

    rgb: Tensor  # [H, W, 3]
    alpha: Tensor  # [H, W, 1]
    depth: Tensor  # [H, W, 1]
    info: dict[str, Any] = field(default_factory=dict)
    features: Tensor | None = None  # [H, W, C]: the extra channels' sum of w * f (no background), if asked for


def render_output(
    rgb: Tensor,
    alpha: Tensor,
    depth_sum: Tensor,
    projection: Projection,
    *,
    width: int,
    height: int,
    backend: str,
    tile_size: int,
    n_pairs: int,
    features: Tensor | None = None,
) -> RenderOutput:
    """A backend's result: rgb on the background [H,W,3], alpha [H,W,1], the alpha-weighted depth
    sum [H,W,1] (made the expected depth here), the projection it composited and its tiling
    (tile_size in pixels, n_pairs Gaussian-tile intersections), and the extra channels' sums [H,W,C]
    where it composited some."""
    radii_xy = projection.radii_xy
    info = {
        "means2d": projection.means2d,
        "radii": radii_xy.amax(dim=1) if radii_xy.numel() else radii_xy.new_zeros(0),
        "radii_xy": radii_xy,
        "visible": projection.visible,
        "depths": projection.depths,
        "conics": projection.conics,
        "width": width,
        "height": height,
        "n_cameras": 1,
        "backend": backend,
        "tile_size": tile_size,
        "n_pairs": n_pairs,
    }
    depth = depth_sum / alpha.clamp_min(DEPTH_ALPHA_FLOOR)
    return RenderOutput(rgb=rgb, alpha=alpha, depth=depth, info=info, features=features)
