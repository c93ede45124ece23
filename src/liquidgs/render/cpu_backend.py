"""The compiled CPU rasteriser, built on first use by liquidgs.native: cpu_project.cpp (projection
and SH colours per Gaussian) and cpu_composite.cpp (binning and tile compositing). Where it cannot
be built or loaded - no compiler, LIQUIDGS_CPU_KERNEL=0, a tensor on another device - the torch
backend does the same work, and the first time that happens one line on stderr says why.
"""

from __future__ import annotations

import ctypes
import math
from pathlib import Path

import torch
from torch import Tensor

from liquidgs import native
from liquidgs.cameras import view_centre
from liquidgs.native import INT, INT64, POINTER, pointer
from liquidgs.render.composite import MAX_ALPHA, MIN_TRANSMITTANCE
from liquidgs.render.contract import MAX_EXTRA_FEATURES, RasterOptions, RenderOutput
from liquidgs.render.projection import (
    ALPHA_THRESHOLD,
    FRUSTUM_MARGIN,
    MAX_EXTENT_SIGMAS,
    Projection,
    project_gaussians,
)
from liquidgs.render.tiles import FOOTPRINT_MARGIN, TileBins
from liquidgs.render.torch_backend import TiledStages, render_tiled, view_colors
from liquidgs.sh import num_sh_bases

SOURCES = (Path(__file__).with_name("cpu_composite.cpp"), Path(__file__).with_name("cpu_project.cpp"))
# The kernels' constants, from the modules of the torch backend that own them.
DEFINES = (
    ("LIQUIDGS_MAX_ALPHA", MAX_ALPHA),
    ("LIQUIDGS_ALPHA_THRESHOLD", ALPHA_THRESHOLD),
    ("LIQUIDGS_MIN_TRANSMITTANCE", MIN_TRANSMITTANCE),
    ("LIQUIDGS_MAX_EXTENT_SIGMAS", MAX_EXTENT_SIGMAS),
    ("LIQUIDGS_FRUSTUM_MARGIN", FRUSTUM_MARGIN),
    ("LIQUIDGS_MAX_EXTRA_FEATURES", MAX_EXTRA_FEATURES),
    ("LIQUIDGS_FOOTPRINT_MARGIN", FOOTPRINT_MARGIN),
)
# Gradient row per Gaussian: means2d (2), conics (3), opacity (1), |means2d| (2), then the features.
ROW_HEAD = 8
GRADIENT_SLICES = 8
"""The backward's partial gradient sums, one per band of tiles: a fixed count, so the gradients
do not depend on the thread count; up to this many threads share the work. Measured against one
sum per thread (bench raster, 1 thread, 2-core VM under load): +0.6 ms at 64x64/5,000 Gaussians,
+5 ms at 200x200/20,000 (+6%), both within that machine's noise; +7 MB peak at 20,000."""
MIN_FEATURES = 4  # RGB and depth, before any extra channels
MAX_TILE_SIZE = 32

_FORWARD_ARGS = [POINTER] * 8 + [INT64, INT, INT, INT, INT, INT] + [POINTER] * 3 + [INT]
_BACKWARD_ARGS = [POINTER] * 8 + [INT64, INT, INT, INT, INT, INT] + [POINTER] * 4 + [INT64, INT, POINTER, INT]


def _declare(library: ctypes.CDLL) -> None:
    for suffix, real in (("f32", ctypes.c_float), ("f64", ctypes.c_double)):
        binning = getattr(library, f"liquidgs_bin_gaussians_{suffix}")
        binning.argtypes = [POINTER] * 5 + [INT64, INT, INT64, INT64, INT64] + [POINTER] * 3
        binning.restype = INT64
        getattr(library, f"liquidgs_composite_forward_{suffix}").argtypes = _FORWARD_ARGS
        getattr(library, f"liquidgs_composite_backward_{suffix}").argtypes = _BACKWARD_ARGS
        camera = [INT64, POINTER, INT, INT, real, real, real]
        sh = [POINTER, POINTER, INT64, INT, INT, POINTER]
        project = f"liquidgs_project_{{}}_{suffix}"
        getattr(library, project.format("forward")).argtypes = [POINTER] * 4 + camera + [POINTER] * 5 + [INT]
        getattr(library, project.format("backward")).argtypes = [POINTER] * 3 + camera + [POINTER] * 6 + [INT]
        getattr(library, f"liquidgs_sh_forward_{suffix}").argtypes = sh + [POINTER, INT]
        getattr(library, f"liquidgs_sh_backward_{suffix}").argtypes = sh + [POINTER] * 3 + [INT]


def _library() -> ctypes.CDLL:
    return native.load("cpu_render", SOURCES, _declare, DEFINES)


def unavailable_reason(tensor: Tensor | None = None) -> str | None:
    """None when the kernel can run on `tensor` (CPU, float32/float64), else why not."""
    if tensor is not None and tensor.device.type != "cpu":
        return f"tensors are on {tensor.device.type}"
    if tensor is not None and tensor.dtype not in (torch.float32, torch.float64):
        return f"dtype {tensor.dtype} (float32 or float64 only)"
    return native.unavailable_reason("cpu_render", SOURCES, _declare, DEFINES)


def report_fallback(reason: str) -> None:
    """One line on stderr the first time a reason sends rendering to the torch backend."""
    native.report_fallback("CPU rasteriser", reason, "the torch backend")


def _camera_block(viewmat: Tensor, K: Tensor) -> Tensor:
    """The kernels' camera: world-to-camera rotation (row-major), translation, fx, fy, cx, cy."""
    intrinsics = torch.stack([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
    return torch.cat([viewmat[:3, :3].reshape(-1), viewmat[:3, 3], intrinsics]).detach().contiguous()


class _ProjectCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, opacities, camera: Tensor, settings: tuple):
        n = means.shape[0]
        inputs = [t.detach().contiguous() for t in (means, quats, scales, opacities)]
        means2d, conics, depths = means.new_empty(n, 2), means.new_empty(n, 3), means.new_empty(n)
        radii_xy = torch.empty(n, 2, dtype=torch.int32)
        visible = torch.empty(n, dtype=torch.bool)
        getattr(_library(), f"liquidgs_project_forward_{native.suffix(means)}")(
            *(pointer(t) for t in inputs), n, pointer(camera), *settings,
            *(pointer(t) for t in (means2d, conics, depths, radii_xy, visible)), torch.get_num_threads(),
        )  # fmt: skip
        ctx.mark_non_differentiable(radii_xy, visible)
        ctx.save_for_backward(*inputs[:3], camera)
        ctx.settings = settings
        return means2d, conics, depths, radii_xy, visible

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_means2d, grad_conics, grad_depths, _grad_radii, _grad_visible):
        means, quats, scales, camera = ctx.saved_tensors
        n = means.shape[0]
        grads = [torch.empty_like(t) for t in (means, quats, scales)]
        upstream = [
            means.new_zeros(shape) if grad is None else grad.to(means.dtype).contiguous()
            for grad, shape in ((grad_means2d, (n, 2)), (grad_conics, (n, 3)), (grad_depths, (n,)))
        ]
        getattr(_library(), f"liquidgs_project_backward_{native.suffix(means)}")(
            *(pointer(t) for t in (means, quats, scales)), n, pointer(camera), *ctx.settings,
            *(pointer(t) for t in (*upstream, *grads)), torch.get_num_threads(),
        )  # fmt: skip
        return (*grads, None, None, None)


def project_gaussians_cpu(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    near_plane: float,
    far_plane: float,
    eps2d: float,
) -> Projection:
    """projection.project_gaussians in the kernel library: same outputs and gradients (none to the camera,
    so a camera that needs one goes to the torch version)."""
    if viewmat.requires_grad or K.requires_grad:
        camera = (viewmat, K, width, height, near_plane, far_plane, eps2d)
        return project_gaussians(means, quats, scales, opacities, *camera)
    settings = (width, height, near_plane, far_plane, eps2d)
    means2d, conics, depths, radii_xy, visible = _ProjectCPU.apply(
        means, quats, scales, opacities, _camera_block(viewmat, K), settings
    )
    return Projection(means2d=means2d, conics=conics, depths=depths, radii_xy=radii_xy, visible=visible)


class _ViewColorsCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, coeffs, means, centre: Tensor, sh_degree: int):
        inputs = [t.detach().contiguous() for t in (means, coeffs)]
        colors = means.new_empty(means.shape[0], 3)
        getattr(_library(), f"liquidgs_sh_forward_{native.suffix(means)}")(
            pointer(inputs[0]), pointer(inputs[1]), means.shape[0], coeffs.shape[1], sh_degree, pointer(centre),
            pointer(colors), torch.get_num_threads(),
        )  # fmt: skip
        ctx.save_for_backward(*inputs, centre)
        ctx.sh_degree = sh_degree
        return colors

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_colors):
        means, coeffs, centre = ctx.saved_tensors
        grad_means, grad_coeffs = torch.empty_like(means), torch.empty_like(coeffs)
        grad_colors = grad_colors.to(means.dtype).contiguous()  # held: the kernel reads its memory
        getattr(_library(), f"liquidgs_sh_backward_{native.suffix(means)}")(
            pointer(means), pointer(coeffs), means.shape[0], coeffs.shape[1], ctx.sh_degree, pointer(centre),
            pointer(grad_colors), pointer(grad_means), pointer(grad_coeffs),
            torch.get_num_threads(),
        )  # fmt: skip
        return grad_coeffs, grad_means, None, None


def view_colors_cpu(colors: Tensor, sh_degree: int | None, means: Tensor, viewmat: Tensor) -> Tensor | None:
    """torch_backend.view_colors in the kernel library, or None where the torch version must do it
    (plain RGB, or a view matrix that needs a gradient)."""
    if sh_degree is None or viewmat.requires_grad or colors.shape[1] < num_sh_bases(sh_degree):
        return None
    centre = view_centre(viewmat.detach()).contiguous()
    return _ViewColorsCPU.apply(colors, means, centre, sh_degree)


class _CompositeCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, bins: TileBins, width: int, height: int, absgrad):
        tile_order = torch.argsort(bins.tile_counts, descending=True)
        tile_order = tile_order[: int((bins.tile_counts > 0).sum())]  # busiest first balances the threads
        out_features = features.new_zeros(height, width, features.shape[1])
        out_transmittance = features.new_ones(height, width)
        out_last = torch.full((height, width), -1, dtype=torch.int32)
        inputs = [t.detach().contiguous() for t in (means2d, conics, opacities, features)]
        common = _common_arguments(*inputs, bins, tile_order, width, height)
        getattr(_library(), f"liquidgs_composite_forward_{native.suffix(features)}")(
            *common, pointer(out_features), pointer(out_transmittance), pointer(out_last), torch.get_num_threads()
        )
        ctx.bins, ctx.absgrad, ctx.size = bins, absgrad, (width, height)
        ctx.save_for_backward(means2d, conics, opacities, features, tile_order, out_transmittance, out_last)
        return out_features, (1.0 - out_transmittance).unsqueeze(-1)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_features_image, grad_alpha_image):
        means2d, conics, opacities, features, tile_order, transmittance, last = ctx.saved_tensors
        bins: TileBins = ctx.bins
        width, height = ctx.size
        dtype = features.dtype
        grad_features_image = grad_features_image.to(dtype).contiguous()
        grad_alpha_image = grad_alpha_image.to(dtype).reshape(height, width).contiguous()
        slice_grads = features.new_zeros(GRADIENT_SLICES, means2d.shape[0], ROW_HEAD + features.shape[1])
        inputs = [t.detach().contiguous() for t in (means2d, conics, opacities, features)]
        common = _common_arguments(*inputs, bins, tile_order, width, height)
        getattr(_library(), f"liquidgs_composite_backward_{native.suffix(features)}")(
            *common, pointer(transmittance), pointer(last), pointer(grad_features_image),
            pointer(grad_alpha_image), means2d.shape[0], GRADIENT_SLICES, pointer(slice_grads), torch.get_num_threads(),
        )  # fmt: skip
        per_gaussian = slice_grads[0]  # the kernel leaves the slices' total there
        if ctx.absgrad:
            # gsplat's convention: the summed per-pixel |dL/dmeans2d| lands on means2d.absgrad.
            means2d.absgrad = per_gaussian[:, 6:8].clone()
        return (
            per_gaussian[:, 0:2].clone(),
            per_gaussian[:, 2:5].clone(),
            per_gaussian[:, 5].clone(),
            per_gaussian[:, ROW_HEAD:].clone(),
            None, None, None, None,
        )  # fmt: skip


def _common_arguments(means2d, conics, opacities, features, bins: TileBins, tile_order, width, height) -> list:
    return [
        pointer(means2d), pointer(conics), pointer(opacities), pointer(features),
        pointer(bins.gaussian_ids), pointer(bins.tile_starts), pointer(bins.tile_counts), pointer(tile_order),
        int(tile_order.numel()), bins.tile_size, bins.tiles_x, width, height, features.shape[1],
    ]  # fmt: skip


@torch.no_grad()
def bin_gaussians_cpu(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    radii_xy: Tensor,
    depths: Tensor,
    width: int,
    height: int,
    tile_size: int,
) -> TileBins:
    """tiles.bin_gaussians in the kernel library (a radix sort by depth, a counting sort by tile):
    the same bins, without a torch operation per step."""
    tiles_x, tiles_y = math.ceil(width / tile_size), math.ceil(height / tile_size)
    inputs = [t.detach().to(means2d.dtype).contiguous() for t in (means2d, conics, opacities)]
    radii = radii_xy.to(torch.int32).contiguous()
    depths = depths.detach().to(means2d.dtype).contiguous()
    tile_starts = torch.empty(tiles_x * tiles_y, dtype=torch.int64)
    tile_counts = torch.empty(tiles_x * tiles_y, dtype=torch.int64)
    # A box spans at most 2 * radius / tile_size + 2 tiles each way (+1 for the divisions' rounding),
    # and no more than the image has.
    spans = torch.minimum((2 * radii.long()) // tile_size + 3, torch.tensor([tiles_x, tiles_y]))
    capacity = int(spans.prod(dim=1).sum())
    gaussian_ids = torch.empty(capacity, dtype=torch.int64)
    n_pairs = getattr(_library(), f"liquidgs_bin_gaussians_{native.suffix(means2d)}")(
        *(pointer(t) for t in inputs), pointer(radii), pointer(depths), means2d.shape[0], tile_size, tiles_x, tiles_y,
        capacity, pointer(tile_starts), pointer(tile_counts), pointer(gaussian_ids),
    )  # fmt: skip
    if n_pairs > capacity:  # the kernel wrote none of them: a broken bound, not a render
        raise RuntimeError(f"binning found {n_pairs} tile pairs, over their bound {capacity}")
    return TileBins(tile_size, tiles_x, tiles_y, gaussian_ids[:n_pairs], tile_starts, tile_counts)


def composite_tiles_cpu(
    means2d: Tensor,
    conics: Tensor,
    opacities: Tensor,
    features: Tensor,
    bins: TileBins,
    width: int,
    height: int,
    absgrad: bool = False,
) -> tuple[Tensor, Tensor]:
    """composite.composite_tiles on the compiled kernel: same inputs, outputs and gradients."""
    most = MIN_FEATURES + MAX_EXTRA_FEATURES
    if not MIN_FEATURES <= features.shape[1] <= most:
        raise ValueError(
            f"the CPU kernel composites {MIN_FEATURES} to {most} features (RGB, depth, extras), got {features.shape[1]}"
        )
    if not (4 <= bins.tile_size <= MAX_TILE_SIZE and bins.tile_size % 4 == 0):
        # A tile's pixels fill whole 8-float vectors.
        raise ValueError(f"the CPU kernel takes tile sizes 4, 8, ..., {MAX_TILE_SIZE}, got {bins.tile_size}")
    return _CompositeCPU.apply(means2d, conics, opacities, features, bins, width, height, absgrad)


def _view_colors(colors: Tensor, sh_degree: int | None, means: Tensor, viewmat: Tensor) -> Tensor:
    colours = view_colors_cpu(colors, sh_degree, means, viewmat)
    return view_colors(colors, sh_degree, means, viewmat) if colours is None else colours


def _composite(means2d, conics, opacities, features, bins, width, height, absgrad, chunk_elements):
    # The kernel's memory is per tile and thread, so it has no use for the torch backend's chunk bound.
    return composite_tiles_cpu(means2d, conics, opacities, features, bins, width, height, absgrad)


CPU_STAGES = TiledStages(project_gaussians_cpu, _view_colors, bin_gaussians_cpu, _composite)


def render(
    means, quats, scales, opacities, colors, features, viewmat, K, width: int, height: int, options: RasterOptions
) -> RenderOutput:
    return render_tiled(
        CPU_STAGES, "cpu", means, quats, scales, opacities, colors, features, viewmat, K, width, height, options
    )
