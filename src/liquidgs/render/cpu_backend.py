"""The compiled CPU compositing kernel (cpu_composite.cpp): built on first use, loaded with ctypes.

The kernel takes plain pointers, so it needs only a C++17 compiler (no torch headers, no
ninja); it is compiled once per source, compiler and CPU into a cache folder
($LIQUIDGS_CACHE_DIR, else ~/.cache/liquidgs) and shared by every process. Where it cannot be
built or loaded - no compiler, LIQUIDGS_CPU_KERNEL=0, a tensor on another device - the torch
backend does the same work, and the first time that happens one line on stderr says why.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import torch
from torch import Tensor

from liquidgs.render.tiles import TileBins, tile_boxes

SOURCE = Path(__file__).with_name("cpu_composite.cpp")
FLAGS = ("-O3", "-march=native", "-std=c++17", "-shared", "-fPIC", "-fopenmp")
DISABLE_VARIABLE = "LIQUIDGS_CPU_KERNEL"
# Gradient row per Gaussian: means2d (2), conics (3), opacity (1), RGB + depth (4), |means2d| (2).
ROW = 12
FEATURES = 4
MAX_TILE_SIZE = 32

_POINTER = ctypes.c_void_p
_INT = ctypes.c_int
_INT64 = ctypes.c_int64
_FORWARD_ARGS = [_POINTER] * 8 + [_INT64, _INT, _INT, _INT, _INT] + [_POINTER] * 3 + [_INT]
_BACKWARD_ARGS = [_POINTER] * 8 + [_INT64, _INT, _INT, _INT, _INT] + [_POINTER] * 4 + [_INT64, _POINTER, _INT]


class KernelUnavailable(RuntimeError):
    pass


def _cache_dir() -> Path:
    root = os.environ.get("LIQUIDGS_CACHE_DIR")
    return Path(root) if root else Path.home() / ".cache" / "liquidgs"


def _cpu_signature() -> str:
    """What -march=native depends on, so a cache shared across machines never runs foreign code."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
        wanted = [line for line in lines if line.startswith(("model name", "flags"))][:2]
        return "\n".join(wanted) or platform.processor()
    except OSError:
        return platform.processor() or platform.machine()


def _compile(compiler: str, target: Path) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as scratch:
        built = Path(scratch) / target.name
        result = subprocess.run(
            [compiler, *FLAGS, str(SOURCE), "-o", str(built)], capture_output=True, text=True, check=False
        )
        if result.returncode != 0:
            first = (result.stderr.strip().splitlines() or ["no output"])[0]
            raise KernelUnavailable(f"{compiler} failed on {SOURCE.name}: {first}")
        os.replace(built, target)  # atomic: concurrent first uses each build, one file wins


@functools.lru_cache(maxsize=1)
def _library() -> ctypes.CDLL:
    if os.environ.get(DISABLE_VARIABLE, "1") == "0":
        raise KernelUnavailable(f"{DISABLE_VARIABLE}=0")
    compiler = os.environ.get("CXX") or shutil.which("c++") or shutil.which("g++")
    if compiler is None:
        raise KernelUnavailable("no C++ compiler found (set CXX or install g++)")
    try:
        version = subprocess.run([compiler, "--version"], capture_output=True, text=True, check=False).stdout
    except OSError as err:
        raise KernelUnavailable(f"cannot run {compiler}: {err.strerror}") from None
    key = hashlib.sha256(
        b"\0".join(s.encode() for s in (SOURCE.read_text(), " ".join(FLAGS), version, _cpu_signature()))
    ).hexdigest()[:16]
    target = _cache_dir() / f"cpu_composite-{key}.so"
    if not target.is_file():
        try:
            _compile(compiler, target)
        except OSError as err:
            raise KernelUnavailable(f"cannot build in {target.parent}: {err.strerror or err}") from None
    try:
        library = ctypes.CDLL(str(target))
    except OSError as err:
        raise KernelUnavailable(f"cannot load {target}: {err}") from None
    library.liquidgs_bin_tiles.argtypes = [_POINTER, _POINTER, _INT64, _INT, _INT64, _POINTER, _POINTER, _POINTER]
    for suffix in ("f32", "f64"):
        getattr(library, f"liquidgs_composite_forward_{suffix}").argtypes = _FORWARD_ARGS
        getattr(library, f"liquidgs_composite_backward_{suffix}").argtypes = _BACKWARD_ARGS
    return library


_reported: set[str] = set()


def unavailable_reason(tensor: Tensor | None = None) -> str | None:
    """None when the kernel can run on `tensor` (CPU, float32/float64), else why not."""
    if tensor is not None and tensor.device.type != "cpu":
        return f"tensors are on {tensor.device.type}"
    if tensor is not None and tensor.dtype not in (torch.float32, torch.float64):
        return f"dtype {tensor.dtype} (float32 or float64 only)"
    try:
        _library()
    except KernelUnavailable as err:
        return str(err)
    return None


def report_fallback(reason: str) -> None:
    """One line on stderr the first time a reason sends rendering to the torch backend."""
    if reason not in _reported:
        _reported.add(reason)
        print(f"liquidgs: compiled CPU rasteriser unavailable ({reason}); using the torch backend", file=sys.stderr)


def _pointer(tensor: Tensor) -> int:
    if not tensor.is_contiguous():
        raise ValueError("the CPU kernel needs contiguous tensors")
    return tensor.data_ptr()


def _suffix(dtype: torch.dtype) -> str:
    return "f64" if dtype == torch.float64 else "f32"


class _CompositeCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, features, bins: TileBins, width: int, height: int, absgrad):
        tile_order = torch.argsort(bins.tile_counts, descending=True)
        tile_order = tile_order[: int((bins.tile_counts > 0).sum())]  # busiest first balances the threads
        out_features = features.new_zeros(height, width, FEATURES)
        out_transmittance = features.new_ones(height, width)
        out_last = torch.full((height, width), -1, dtype=torch.int32)
        inputs = [t.detach().contiguous() for t in (means2d, conics, opacities, features)]
        common = _common_arguments(*inputs, bins, tile_order, width, height)
        getattr(_library(), f"liquidgs_composite_forward_{_suffix(features.dtype)}")(
            *common, _pointer(out_features), _pointer(out_transmittance), _pointer(out_last), torch.get_num_threads()
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
        threads = torch.get_num_threads()
        thread_grads = features.new_zeros(threads, means2d.shape[0], ROW)
        inputs = [t.detach().contiguous() for t in (means2d, conics, opacities, features)]
        common = _common_arguments(*inputs, bins, tile_order, width, height)
        getattr(_library(), f"liquidgs_composite_backward_{_suffix(dtype)}")(
            *common, _pointer(transmittance), _pointer(last), _pointer(grad_features_image),
            _pointer(grad_alpha_image), means2d.shape[0], _pointer(thread_grads), threads,
        )  # fmt: skip
        per_gaussian = thread_grads.sum(dim=0)
        if ctx.absgrad:
            # gsplat's convention: the summed per-pixel |dL/dmeans2d| lands on means2d.absgrad.
            means2d.absgrad = per_gaussian[:, 10:12].clone()
        return (
            per_gaussian[:, 0:2].clone(),
            per_gaussian[:, 2:5].clone(),
            per_gaussian[:, 5].clone(),
            per_gaussian[:, 6:10].clone(),
            None, None, None, None,
        )  # fmt: skip


def _common_arguments(means2d, conics, opacities, features, bins: TileBins, tile_order, width, height) -> list:
    return [
        _pointer(means2d), _pointer(conics), _pointer(opacities), _pointer(features),
        _pointer(bins.gaussian_ids), _pointer(bins.tile_starts), _pointer(bins.tile_counts), _pointer(tile_order),
        int(tile_order.numel()), bins.tile_size, bins.tiles_x, width, height,
    ]  # fmt: skip


@torch.no_grad()
def bin_gaussians_cpu(
    means2d: Tensor, radii_xy: Tensor, depths: Tensor, width: int, height: int, tile_size: int
) -> TileBins:
    """tiles.bin_gaussians with a counting sort in the kernel library: the same bins, without sorting pairs."""
    boxes = tile_boxes(means2d, radii_xy, depths, width, height, tile_size)
    box = torch.cat([boxes.tile_min, boxes.tile_max], dim=1).contiguous()
    span = boxes.tile_max - boxes.tile_min
    n_pairs = int((span[:, 0] * span[:, 1]).sum())
    n_tiles = boxes.tiles_x * boxes.tiles_y
    tile_starts = torch.empty(n_tiles, dtype=torch.int64)
    tile_counts = torch.empty(n_tiles, dtype=torch.int64)
    gaussian_ids = torch.empty(n_pairs, dtype=torch.int64)
    _library().liquidgs_bin_tiles(
        _pointer(boxes.depth_order), _pointer(box), int(boxes.depth_order.numel()), boxes.tiles_x, n_tiles,
        _pointer(tile_starts), _pointer(tile_counts), _pointer(gaussian_ids),
    )  # fmt: skip
    return TileBins(tile_size, boxes.tiles_x, boxes.tiles_y, gaussian_ids, tile_starts, tile_counts)


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
    if features.shape[1] != FEATURES:
        raise ValueError(f"the CPU kernel composites {FEATURES} features (RGB + depth), got {features.shape[1]}")
    if not (4 <= bins.tile_size <= MAX_TILE_SIZE and bins.tile_size % 4 == 0):
        # A tile's pixels fill whole 8-float vectors.
        raise ValueError(f"the CPU kernel takes tile sizes 4, 8, ..., {MAX_TILE_SIZE}, got {bins.tile_size}")
    return _CompositeCPU.apply(means2d, conics, opacities, features, bins, width, height, absgrad)
