"""`rasterize`: one pure function over three backends (portable PyTorch, compiled CPU kernels,
gsplat's CUDA kernels). This module owns the backend names and picks the backend, once per call."""

from __future__ import annotations

import logging
import math
from typing import Any

import torch
from torch import Tensor

from liquidgs.render import cpu_backend, gsplat_backend, torch_backend
from liquidgs.render.composite import DEFAULT_CHUNK_ELEMENTS
from liquidgs.render.contract import MAX_EXTRA_FEATURES, RasterOptions, RenderOutput
from liquidgs.sh import MAX_SH_DEGREE, num_sh_bases

logger = logging.getLogger(__name__)

# Each backend module renders through the contract of render/contract.py.
_BACKEND_MODULES = {"torch": torch_backend, "cpu": cpu_backend, "gsplat": gsplat_backend}
BACKENDS = ("auto", *_BACKEND_MODULES)
"""The backend names `rasterize` takes, and every setting that names a backend with it."""
# Fastest per backend for small trained-scene Gaussians (a few pixels across); see benchmarks/raster_cpu.jsonl.
DEFAULT_TILE_SIZES = {"torch": 4, "cpu": 4, "gsplat": gsplat_backend.GSPLAT_TILE_SIZE}

_logged_backends: set[str] = set()


def _check_tensor(name: str, tensor: Any, shape: tuple[int | None, ...], shape_text: str) -> None:
    if not isinstance(tensor, Tensor):
        raise ValueError(f"{name} must be a torch.Tensor with shape {shape_text}, got {type(tensor).__name__}")
    if tensor.dim() != len(shape) or any(want is not None and got != want for got, want in zip(tensor.shape, shape)):
        raise ValueError(f"{name} must have shape {shape_text}, got {list(tensor.shape)}")
    if not tensor.is_floating_point():
        raise ValueError(f"{name} must be a floating-point tensor, got {tensor.dtype}")
    if not _all_finite(tensor):
        raise ValueError(f"{name} contains NaN or inf")


def _all_finite(tensor: Tensor) -> bool:
    """Whether every entry is finite. A NaN or inf makes the sum NaN or inf, so a finite sum settles
    it in one reduction (for 5,122 Gaussians' SH coefficients 17 us, where isfinite(...).all() took
    660 us); only a sum that overflows asks entry by entry. A camera's few numbers are read in
    Python, cheaper than any tensor operation."""
    if tensor.numel() <= 16 and tensor.device.type == "cpu":
        return all(map(math.isfinite, tensor.detach().flatten().tolist()))
    total = tensor.detach().sum()
    return bool(torch.isfinite(total)) or bool(torch.isfinite(tensor).all())


def _validate(
    means, quats, scales, opacities, colors, viewmat, K, width, height, sh_degree, background, backend, features
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
    if features is not None:
        _check_tensor("features", features, (n, None), f"[N,C] with N={n}, 1 <= C <= {MAX_EXTRA_FEATURES}")
        if not 1 <= features.shape[1] <= MAX_EXTRA_FEATURES:
            raise ValueError(f"features must have 1 to {MAX_EXTRA_FEATURES} channels, got shape {list(features.shape)}")
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


def choose_backend(backend: str, means: Tensor) -> str:
    """The backend that renders `means`: the one named, if it runs on their device and dtype (else a
    ValueError saying why), or for 'auto' gsplat where its kernels run, else the compiled CPU
    kernels on the CPU (one line on stderr when they cannot), else torch."""
    if backend != "auto":
        reason = _BACKEND_MODULES[backend].unavailable_reason(means)
        if reason is not None:
            raise ValueError(f"backend={backend!r} is unavailable: {reason}; use backend='torch' or 'auto'")
        return backend
    device = means.device
    if gsplat_backend.unavailable_reason(means) is None:
        chosen = "gsplat"
    elif device.type == "cpu" and (reason := cpu_backend.unavailable_reason(means)) is not None:
        cpu_backend.report_fallback(reason)
        chosen = "torch"
    else:
        chosen = "cpu" if device.type == "cpu" else "torch"
    if chosen not in _logged_backends:
        _logged_backends.add(chosen)
        logger.info("rasterize: backend='auto' uses %s on %s", chosen, device.type)
    return chosen


NEAR_PLANE = 0.01
"""Gaussians nearer the camera than this (in scene units) are not drawn (gsplat's default)."""


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
    features: Tensor | None = None,
    sh_degree: int | None = None,
    background: Tensor | None = None,
    backend: str = "auto",
    near_plane: float = NEAR_PLANE,
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
        features: None, or extra per-Gaussian channels [N,C] (1 <= C <= MAX_EXTRA_FEATURES) composited
        in the same pass with colour's weights, into RenderOutput.features [H,W,C] (sum of w * f, no
        background, not divided by alpha); gradients flow to them and, through the weights, to the Gaussians.
        viewmat [4,4]: world-to-camera, OpenCV axes (x right, y down, z forward). K [3,3]: intrinsics.
        background [3] or None (black). backend: "auto" (gsplat on CUDA for float32 when its kernels
        run; on the CPU the compiled kernel where it builds, else torch), "torch" (the portable reference),
        "cpu" or "gsplat". tile_size (default per backend, DEFAULT_TILE_SIZES) tunes torch and cpu;
        chunk_elements bounds the torch backend's memory.

    Returns RenderOutput with rgb [H,W,3], alpha [H,W,1], depth [H,W,1] (expected depth, divided by
    alpha clamped at 1e-10) and info: means2d [N,2] (its .grad is dL/dmeans2d after backward, and
    .absgrad too when absgrad=True), radii [N] int32 (largest per-axis radius, 0 = culled),
    radii_xy [N,2] int32 (gsplat 1.5.3's per-axis radii), visible [N] bool, depths [N], conics
    [N,3], width, height, n_cameras (1), backend, tile_size and n_pairs (Gaussian-tile intersections;
    the same keys from every backend, render/contract.py). The rows of culled Gaussians in means2d,
    depths and conics are meaningless (with the gsplat backend on a GPU, uninitialised memory, possibly NaN):
    read them only where visible. Their .grad / .absgrad rows are zero.
    """
    _validate(
        means, quats, scales, opacities, colors, viewmat, K, width, height, sh_degree, background, backend, features
    )
    if tile_size is not None and (isinstance(tile_size, bool) or not isinstance(tile_size, int) or tile_size < 1):
        raise ValueError(f"tile_size must be an integer >= 1, got {tile_size!r}")
    chosen = choose_backend(backend, means)
    options = RasterOptions(
        sh_degree=sh_degree,
        background=means.new_zeros(3) if background is None else background,
        near_plane=near_plane,
        far_plane=far_plane,
        eps2d=eps2d,
        absgrad=absgrad,
        tile_size=DEFAULT_TILE_SIZES[chosen] if tile_size is None else tile_size,
        chunk_elements=chunk_elements,
    )
    viewmat = viewmat.to(dtype=means.dtype, device=means.device)
    K = K.to(dtype=means.dtype, device=means.device)
    if features is not None:
        features = features.to(dtype=means.dtype, device=means.device)
    return _BACKEND_MODULES[chosen].render(
        means, quats, scales, opacities, colors, features, viewmat, K, width, height, options
    )
