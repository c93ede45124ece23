"""The compiled CPU SSIM (cpu_ssim.cpp: the score of one [H, W, C] image pair and its gradient
with respect to the first image), built on first use by liquidgs.native.

`metrics.ssim` owns SSIM and decides when this runs: CPU float32/float64 images whose
reference needs no gradient. The window and constants come from there, so both paths compute
the same thing; this module only moves tensors in and out of the library.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import torch
from torch import Tensor

from liquidgs import native
from liquidgs.native import INT, INT64, POINTER, pointer

SOURCES = (Path(__file__).with_name("cpu_ssim.cpp"),)
WINDOW = 11  # the kernel's window size (kTaps)
PARTIALS = 3  # dS/dmu_x, dS/dE[x^2], dS/dE[xy], filtered horizontally, kept for the backward

DOUBLE = ctypes.c_double
_FORWARD_ARGS = [POINTER, POINTER, POINTER, DOUBLE, DOUBLE, INT64, INT64, INT, POINTER, INT]
_BACKWARD_ARGS = [POINTER, POINTER, POINTER, INT64, INT64, INT, POINTER, DOUBLE, POINTER, INT]


def _declare(library: ctypes.CDLL) -> None:
    for suffix in ("f32", "f64"):
        forward = getattr(library, f"liquidgs_ssim_forward_{suffix}")
        forward.argtypes, forward.restype = _FORWARD_ARGS, DOUBLE
        backward = getattr(library, f"liquidgs_ssim_backward_{suffix}")
        backward.argtypes, backward.restype = _BACKWARD_ARGS, None


def _library() -> ctypes.CDLL:
    return native.load("cpu_ssim", SOURCES, _declare)


def unavailable_reason() -> str | None:
    """None when the library is built and loaded, else why it cannot be."""
    return native.unavailable_reason("cpu_ssim", SOURCES, _declare)


def applies(img: Tensor, ref: Tensor) -> bool:
    """Whether the kernel takes this pair of images: CPU, one float dtype, no gradient for ref."""
    return (
        img.device.type == "cpu"
        and ref.device.type == "cpu"
        and img.dtype in (torch.float32, torch.float64)
        and ref.dtype == img.dtype
        and not ref.requires_grad
        and img.numel() > 0
    )


def _forward(img: Tensor, ref: Tensor, window: Tensor, c1: float, c2: float, partials: Tensor | None) -> Tensor:
    height, width, channels = img.shape
    total = getattr(_library(), f"liquidgs_ssim_forward_{native.suffix(img)}")(
        pointer(img), pointer(ref), pointer(window), c1, c2, height, width, channels,
        None if partials is None else pointer(partials), torch.get_num_threads(),
    )  # fmt: skip
    return torch.tensor(total / img.numel(), dtype=img.dtype)


class _SSIMCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, img, ref, window, c1, c2):
        x, y = img.detach().contiguous(), ref.contiguous()
        partials = x.new_empty(PARTIALS, *x.shape)
        score = _forward(x, y, window, c1, c2, partials)
        ctx.save_for_backward(x, y, window, partials)
        return score

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_score):
        x, y, window, partials = ctx.saved_tensors
        height, width, channels = x.shape
        grad = torch.empty_like(x)
        getattr(_library(), f"liquidgs_ssim_backward_{native.suffix(x)}")(
            pointer(x), pointer(y), pointer(window), height, width, channels, pointer(partials),
            float(grad_score) / x.numel(), pointer(grad), torch.get_num_threads(),
        )  # fmt: skip
        return grad, None, None, None, None


def ssim_cpu(img: Tensor, ref: Tensor, window: Tensor, c1: float, c2: float) -> Tensor:
    """The 0-d score of one [H, W, C] pair (the library loaded, `applies` true), differentiable in `img`.

    `window` is the 1-D Gaussian of WINDOW taps in the images' dtype.
    """
    if window.numel() != WINDOW:
        raise ValueError(f"the compiled SSIM takes a {WINDOW}-tap window, got {window.numel()}")
    if torch.is_grad_enabled() and img.requires_grad:
        return _SSIMCPU.apply(img, ref, window, c1, c2)
    return _forward(img.detach().contiguous(), ref.contiguous(), window, c1, c2, None)
