"""The gsplat backend: gsplat 1.5.3's CUDA kernels behind `rasterize`'s single-view interface.

It composes gsplat's own pipeline (projection, SH, tile intersection, rasterisation; packed=False,
classic mode, RGB+ED) so that info["means2d"] is an [N,2] tensor the rasteriser consumes directly,
which is what makes its .grad and .absgrad meaningful.

Rows of culled Gaussians: gsplat's projection kernel writes only radii = 0 for a Gaussian it culls
and returns at once, so on a GPU that Gaussian's rows of means2d, depths and conics are uninitialised
memory (`at::empty`), and so is its SH colour (the SH kernel skips masked rows of an `empty_like`).
Nothing here reads them: the tile intersection skips radii <= 0, the rasteriser reads only the ids
it lists, and the backward kernels give culled rows zero gradient (clamp_min's backward is a `where`,
so even a NaN there passes nothing on). info's means2d / depths / conics keep them: read those only
where info["visible"]. tests/test_gsplat_cpu.py runs this module on the CPU with those rows set to
NaN by its kernel stand-ins and checks that images and gradients stay finite and equal.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from liquidgs.cameras import view_centre
from liquidgs.render.contract import RasterOptions, RenderOutput, render_output
from liquidgs.render.projection import Projection

# gsplat's own tile size; rasterize's tile_size tunes the other backends only.
GSPLAT_TILE_SIZE = 16
_availability: dict[str, str | None] = {}


def _probe(device: torch.device) -> str | None:
    try:
        import gsplat
    except Exception as error:  # noqa: BLE001 - any import failure means the backend is unusable
        return f"gsplat does not import ({error})"
    try:
        means = torch.tensor([[0.0, 0.0, 3.0]], device=device)
        quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]], device=device)
        scales = torch.full((1, 3), 0.1, device=device)
        opacities = torch.ones(1, device=device)
        colors = torch.ones(1, 3, device=device)
        viewmats = torch.eye(4, device=device)[None]
        Ks = torch.tensor([[[8.0, 0.0, 4.0], [0.0, 8.0, 4.0], [0.0, 0.0, 1.0]]], device=device)
        gsplat.rasterization(means, quats, scales, opacities, colors, viewmats, Ks, 8, 8)
        torch.cuda.synchronize(device)
    except Exception as error:  # noqa: BLE001 - JIT build or kernel failures surface as many types
        return f"gsplat's CUDA kernels do not build or run ({type(error).__name__}: {error})"
    return None


def unavailable_reason(means: Tensor) -> str | None:
    """None when gsplat's kernels run on `means`' device and dtype, else why not.

    Probed once per device, then cached. float32 only: rasterize_to_pixels' kernels read float
    pointers (a float64 tensor stops them with a dtype error), and the wrapper casts alphas to float.
    """
    device = means.device
    if device.type != "cuda":
        return f"gsplat has no CPU path and the tensors are on {device.type}"
    if means.dtype != torch.float32:
        return f"gsplat's rasteriser kernels take float32 only, the tensors are {means.dtype}"
    key = str(device)
    if key not in _availability:
        _availability[key] = _probe(device)
    return _availability[key]


def render(
    means, quats, scales, opacities, colors, features, viewmat, K, width: int, height: int, options: RasterOptions
) -> RenderOutput:
    """Render with gsplat's kernels (see the contract in render/contract.py). The extra features are
    channels after RGB and depth: gsplat composites any number of them (padded to a count its
    kernels are built for, in its wrapper), with a zero background."""
    from gsplat import (
        fully_fused_projection,
        isect_offset_encode,
        isect_tiles,
        rasterize_to_pixels,
        spherical_harmonics,
    )

    radii_batched, means2d_batched, depths_batched, conics_batched, _ = fully_fused_projection(
        means, None, quats, scales, viewmat[None], K[None], width, height,
        eps2d=options.eps2d, near_plane=options.near_plane, far_plane=options.far_plane, packed=False,
        opacities=opacities,
    )  # fmt: skip
    radii_xy, depths, conics = radii_batched[0], depths_batched[0], conics_batched[0]
    visible = (radii_xy > 0).all(dim=-1)
    means2d = means2d_batched[0]
    if means2d.requires_grad:
        means2d.retain_grad()
    if options.sh_degree is None:
        rgb_colors = colors
    else:
        sh_rgb = spherical_harmonics(options.sh_degree, means - view_centre(viewmat), colors, masks=visible)
        rgb_colors = torch.clamp_min(sh_rgb + 0.5, 0.0)
    channels = [rgb_colors, depths[:, None]] + ([] if features is None else [features])
    n_unlit = 1 if features is None else 1 + features.shape[1]  # depth and the extras: no background
    backgrounds = torch.cat([options.background, options.background.new_zeros(n_unlit)])[None]

    tiles_x = math.ceil(width / GSPLAT_TILE_SIZE)
    tiles_y = math.ceil(height / GSPLAT_TILE_SIZE)
    # The rasteriser must consume this view (not means2d) for gsplat to put .absgrad on it.
    means2d_for_kernel = means2d[None]
    _, isect_ids, flatten_ids = isect_tiles(
        means2d_for_kernel, radii_batched, depths_batched, GSPLAT_TILE_SIZE, tiles_x, tiles_y, n_images=1
    )
    isect_offsets = isect_offset_encode(isect_ids, 1, tiles_x, tiles_y).reshape(1, tiles_y, tiles_x)
    rendered, alphas = rasterize_to_pixels(
        means2d_for_kernel, conics_batched, torch.cat(channels, dim=1)[None], opacities[None], width, height,
        GSPLAT_TILE_SIZE, isect_offsets, flatten_ids, backgrounds=backgrounds, absgrad=options.absgrad,
    )  # fmt: skip
    if options.absgrad and means2d.requires_grad:
        # The hook runs when means2d's gradient is formed, i.e. after the kernel's backward set it.
        def copy_absgrad(grad: Tensor) -> None:
            means2d.absgrad = means2d_for_kernel.absgrad[0]

        means2d.register_hook(copy_absgrad)
    alpha = alphas[0]
    projection = Projection(means2d=means2d, conics=conics, depths=depths, radii_xy=radii_xy, visible=visible)
    return render_output(
        rendered[0, ..., :3], alpha, rendered[0, ..., 3:4], projection,
        width=width, height=height, backend="gsplat", tile_size=GSPLAT_TILE_SIZE, n_pairs=flatten_ids.numel(),
        features=None if features is None else rendered[0, ..., 4:],
    )  # fmt: skip
