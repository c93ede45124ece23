"""`rasterize`: one pure function over two backends (portable PyTorch, gsplat's CUDA kernels)."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor

from liquidgs.render import cpu_backend, gsplat_backend
from liquidgs.render.cameras import view_centre
from liquidgs.render.composite import DEFAULT_CHUNK_ELEMENTS, composite_tiles
from liquidgs.render.projection import project_gaussians
from liquidgs.render.sh import MAX_SH_DEGREE, eval_sh, num_sh_bases
from liquidgs.render.tiles import bin_gaussians

logger = logging.getLogger(__name__)

BACKENDS = ("auto", "torch", "cpu", "gsplat")
# Fastest per backend for small trained-scene Gaussians (a few pixels across); see benchmarks/raster_cpu.jsonl.
DEFAULT_TILE_SIZES = {"torch": 4, "cpu": 4}
# gsplat's "ED" depth divides by alpha clamped at this value.
DEPTH_ALPHA_FLOOR = 1e-10

_logged_backends: set[str] = set()


@dataclass
class RenderOutput:
    """One rendered view. info holds gsplat-style per-Gaussian metadata (see `rasterize`)."""

    rgb: Tensor  # [H, W, 3]
    alpha: Tensor  # [H, W, 1]
    depth: Tensor  # [H, W, 1]
    info: dict[str, Any] = field(default_factory=dict)


def _check_tensor(name: str, tensor: Any, shape: tuple[int | None, ...], shape_text: str) -> None:
    if not isinstance(tensor, Tensor):
        raise ValueError(f"{name} must be a torch.Tensor with shape {shape_text}, got {type(tensor).__name__}")
    if tensor.dim() != len(shape) or any(want is not None and got != want for got, want in zip(tensor.shape, shape)):
        raise ValueError(f"{name} must have shape {shape_text}, got {list(tensor.shape)}")
    if not tensor.is_floating_point():
        raise ValueError(f"{name} must be a floating-point tensor, got {tensor.dtype}")
    if not bool(torch.isfinite(tensor).all()):
        raise ValueError(f"{name} contains NaN or inf")


def _validate(
    means, quats, scales, opacities, colors, viewmat, K, width, height, sh_degree, background, backend
) -> None:
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    for name, size in (("width", width), ("height", height)):
        if isinstance(size, bool) or not isinstance(size, int) or size < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {size!r}")
    _check_tensor("means", means, (None, 3), "[N,3]")
    n = means.shape[0]
    _check_tensor("quats", quats, (n, 4), f"[N,4] with N={n}")
    _check_tensor("scales", scales, (n, 3), f"[N,3] with N={n}")
    _check_tensor("opacities", opacities, (n,), f"[N] with N={n}")
    _check_tensor("viewmat", viewmat, (4, 4), "[4,4]")
    _check_tensor("K", K, (3, 3), "[3,3]")
    if background is not None:
        _check_tensor("background", background, (3,), "[3]")
    if sh_degree is None:
        _check_tensor("colors", colors, (n, 3), f"[N,3] with N={n} (RGB, as sh_degree is None)")
        return
    if isinstance(sh_degree, bool) or not isinstance(sh_degree, int) or not 0 <= sh_degree <= MAX_SH_DEGREE:
        raise ValueError(f"sh_degree must be None or an integer in 0..{MAX_SH_DEGREE}, got {sh_degree!r}")
    n_bases = num_sh_bases(sh_degree)
    _check_tensor("colors", colors, (n, None, 3), f"[N,K,3] with N={n} (SH coefficients, as sh_degree is set)")
    if colors.shape[1] < n_bases:
        raise ValueError(
            f"colors must have at least {n_bases} SH coefficients for sh_degree={sh_degree}, "
            f"got shape {list(colors.shape)}"
        )


def _resolve_backend(backend: str, means: Tensor) -> str:
    device = means.device
    if backend in ("gsplat", "cpu"):
        reason = (gsplat_backend.unavailable_reason(means) if backend == "gsplat"
                  else cpu_backend.unavailable_reason(means))  # fmt: skip
        if reason is not None:
            raise ValueError(f"backend={backend!r} is unavailable: {reason}; use backend='torch' or 'auto'")
        chosen = backend
    elif backend == "auto":
        if gsplat_backend.unavailable_reason(means) is None:
            chosen = "gsplat"
        elif device.type == "cpu" and (reason := cpu_backend.unavailable_reason(means)) is not None:
            cpu_backend.report_fallback(reason)
            chosen = "torch"
        else:
            chosen = "cpu" if device.type == "cpu" else "torch"
    else:
        chosen = "torch"
    if backend == "auto" and chosen not in _logged_backends:
        _logged_backends.add(chosen)
        logger.info("rasterize: backend='auto' uses %s on %s", chosen, device.type)
    return chosen


def view_colors(colors: Tensor, sh_degree: int | None, means: Tensor, viewmat: Tensor) -> Tensor:
    """Per-Gaussian RGB [N,3]: the input itself, or SH at the view direction + 0.5 clamped at 0."""
    if sh_degree is None:
        return colors
    return torch.clamp_min(eval_sh(sh_degree, colors, means - view_centre(viewmat)) + 0.5, 0.0)


def rasterize(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    *,
    sh_degree: int | None = None,
    background: Tensor | None = None,
    backend: str = "auto",
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
    absgrad: bool = False,
    tile_size: int | None = None,
    chunk_elements: int = DEFAULT_CHUNK_ELEMENTS,
) -> RenderOutput:
    """Render N 3D Gaussians into one pinhole view, following gsplat 1.5.3's conventions.

    Args:
        means [N,3], quats [N,4] (wxyz, any norm), scales [N,3] (std-devs), opacities [N] in [0,1].
        colors: RGB [N,3] when sh_degree is None, else SH coefficients [N,K,3], K >= (sh_degree+1)^2.
        viewmat [4,4]: world-to-camera, OpenCV axes (x right, y down, z forward). K [3,3]: intrinsics.
        background [3] or None (black). backend: "auto" (gsplat on CUDA for float32 when its kernels
        run; on the CPU the compiled kernel where it builds, else torch), "torch" (the portable reference),
        "cpu" or "gsplat". tile_size (default per backend, DEFAULT_TILE_SIZES) tunes torch and cpu;
        chunk_elements bounds the torch backend's memory.

    Returns RenderOutput with rgb [H,W,3], alpha [H,W,1], depth [H,W,1] (expected depth, divided by
    alpha clamped at 1e-10) and info: means2d [N,2] (its .grad is dL/dmeans2d after backward, and
    .absgrad too when absgrad=True), radii [N] int32 (largest per-axis radius, 0 = culled),
    radii_xy [N,2] int32 (gsplat 1.5.3's per-axis radii), visible [N] bool, depths [N], conics
    [N,3], width, height, n_cameras (1), backend. The rows of culled Gaussians in means2d, depths and
    conics are meaningless (with the gsplat backend on a GPU, uninitialised memory, possibly NaN):
    read them only where visible. Their .grad / .absgrad rows are zero.
    """
    _validate(means, quats, scales, opacities, colors, viewmat, K, width, height, sh_degree, background, backend)
    if tile_size is not None and (isinstance(tile_size, bool) or not isinstance(tile_size, int) or tile_size < 1):
        raise ValueError(f"tile_size must be an integer >= 1, got {tile_size!r}")
    chosen = _resolve_backend(backend, means)
    viewmat = viewmat.to(dtype=means.dtype, device=means.device)
    K = K.to(dtype=means.dtype, device=means.device)
    if background is None:
        background = means.new_zeros(3)
    if chosen == "gsplat":
        return gsplat_backend.rasterize_gsplat(
            means, quats, scales, opacities, colors, viewmat, K, width, height,
            sh_degree=sh_degree, background=background, near_plane=near_plane, far_plane=far_plane,
            eps2d=eps2d, absgrad=absgrad,
        )  # fmt: skip

    project = cpu_backend.project_gaussians_cpu if chosen == "cpu" else project_gaussians
    projection = project(means, quats, scales, opacities, viewmat, K, width, height, near_plane, far_plane, eps2d)
    means2d = projection.means2d
    if means2d.requires_grad:
        means2d.retain_grad()
    rgb_colors = cpu_backend.view_colors_cpu(colors, sh_degree, means, viewmat) if chosen == "cpu" else None
    if rgb_colors is None:
        rgb_colors = view_colors(colors, sh_degree, means, viewmat)
    features = torch.cat([rgb_colors, projection.depths[:, None]], dim=1)
    if tile_size is None:
        tile_size = DEFAULT_TILE_SIZES[chosen]
    if chosen == "cpu":
        bins = cpu_backend.bin_gaussians_cpu(means2d, projection.radii_xy, projection.depths, width, height, tile_size)
        features_image, alpha = cpu_backend.composite_tiles_cpu(
            means2d, projection.conics, opacities, features, bins, width, height, absgrad
        )
    else:
        bins = bin_gaussians(means2d, projection.radii_xy, projection.depths, width, height, tile_size)
        features_image, alpha = composite_tiles(
            means2d, projection.conics, opacities, features, bins, width, height, absgrad, chunk_elements
        )
    rgb = features_image[..., :3] + (1.0 - alpha) * background
    depth = features_image[..., 3:] / alpha.clamp_min(DEPTH_ALPHA_FLOOR)
    radii_xy = projection.radii_xy
    info = {
        "means2d": means2d,
        "radii": radii_xy.amax(dim=1) if radii_xy.numel() else radii_xy.new_zeros(0),
        "radii_xy": radii_xy,
        "visible": projection.visible,
        "depths": projection.depths,
        "conics": projection.conics,
        "width": width,
        "height": height,
        "n_cameras": 1,
        "backend": chosen,
        "tile_size": tile_size,
        "n_pairs": bins.n_pairs,
    }
    return RenderOutput(rgb=rgb, alpha=alpha, depth=depth, info=info)


def focal_from_fov(fov: float, size: int) -> float:
    """Pinhole focal length in pixels for a full field of view (radians) across `size` pixels."""
    return 0.5 * size / math.tan(0.5 * fov)
