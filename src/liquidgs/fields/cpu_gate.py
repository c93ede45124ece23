"""The CfC cell's gate from its four heads as one [N, 4H] block [ff1 | ff2 | time_a | time_b]:

    h' = tanh(ff1) * (1 - s) + tanh(ff2) * s,   s = sigmoid(time_a * tau + (time_b + offset)).

`cfc_gate` runs it as one compiled CPU pass each way (cpu_gate.cpp, built on first use by
liquidgs.native) where it can - CPU, float32 with H a multiple of 8 or float64 - and as
`cfc_gate_torch`, the reference, everywhere else; when the library cannot be built, one line on
stderr says so and torch does the work.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import torch
from torch import Tensor

from liquidgs import native
from liquidgs.native import INT, INT64, POINTER, pointer

SOURCES = (Path(__file__).with_name("cpu_gate.cpp"),)
LANES = 8  # float32 columns per vector in the kernel


_FORWARD_ARGS = [POINTER, INT64, INT, POINTER, INT64, POINTER, POINTER, INT]
_BACKWARD_ARGS = [POINTER, INT64, INT, POINTER, INT64] + [POINTER] * 5 + [INT]


def _declare(library: ctypes.CDLL) -> None:
    for suffix in ("f32", "f64"):
        getattr(library, f"liquidgs_cfc_gate_forward_{suffix}").argtypes = _FORWARD_ARGS
        getattr(library, f"liquidgs_cfc_gate_backward_{suffix}").argtypes = _BACKWARD_ARGS


def _library() -> ctypes.CDLL:
    return native.load("cpu_gate", SOURCES, _declare)


def unavailable_reason() -> str | None:
    """None when the library is built and loaded, else why it cannot be."""
    return native.unavailable_reason("cpu_gate", SOURCES, _declare)


def cfc_gate_torch(heads: Tensor, tau: Tensor, offset: Tensor | None = None) -> Tensor:
    ff1, ff2, time_a, time_b = heads.chunk(4, dim=1)
    if offset is not None:
        time_b = time_b + offset
    sigma = torch.sigmoid(time_a * tau + time_b)
    return torch.tanh(ff1) * (1.0 - sigma) + sigma * torch.tanh(ff2)


def _kernel_takes(heads: Tensor, tau: Tensor, offset: Tensor | None) -> bool:
    if heads.device.type != "cpu" or heads.dtype not in (torch.float32, torch.float64) or tau.dtype != heads.dtype:
        return False
    if offset is not None and (offset.dtype != heads.dtype or offset.shape != (heads.shape[0], heads.shape[1] // 4)):
        return False
    hidden = heads.shape[1] // 4
    return heads.dtype == torch.float64 or hidden % LANES == 0


def cfc_gate(heads: Tensor, tau: Tensor, offset: Tensor | None = None) -> Tensor:
    """h' [N, H] from heads [N, 4H], tau [N, 1] or [1, 1] and an offset [N, H] on time_b (or None)."""
    if not _kernel_takes(heads, tau, offset):
        return cfc_gate_torch(heads, tau, offset)
    reason = unavailable_reason()
    if reason is not None:
        native.report_fallback("CfC gate", reason, "torch for the liquid cells")
        return cfc_gate_torch(heads, tau, offset)
    return _CfCGate.apply(heads, tau.expand(heads.shape[0], 1), offset)


class _CfCGate(torch.autograd.Function):
    @staticmethod
    def forward(ctx, heads: Tensor, tau: Tensor, offset: Tensor | None):
        n, hidden = heads.shape[0], heads.shape[1] // 4
        heads_c = heads.detach().contiguous()
        offset_c = None if offset is None else offset.detach().contiguous()
        out = heads.new_empty(n, hidden)
        getattr(_library(), f"liquidgs_cfc_gate_forward_{native.suffix(heads)}")(
            pointer(heads_c), n, hidden, tau.data_ptr(), tau.stride(0), None if offset_c is None else pointer(offset_c),
            pointer(out), torch.get_num_threads(),
        )  # fmt: skip
        ctx.save_for_backward(heads_c, tau, offset_c)
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_out: Tensor):
        heads, tau, offset = ctx.saved_tensors
        n, hidden = heads.shape[0], heads.shape[1] // 4
        grad_out = grad_out.to(heads.dtype).contiguous()  # held: the kernel reads its memory
        grad_heads = torch.empty_like(heads)
        grad_tau = heads.new_empty(n, 1) if ctx.needs_input_grad[1] else None
        grad_offset = torch.empty_like(offset) if offset is not None and ctx.needs_input_grad[2] else None
        getattr(_library(), f"liquidgs_cfc_gate_backward_{native.suffix(heads)}")(
            pointer(heads), n, hidden, tau.data_ptr(), tau.stride(0), None if offset is None else pointer(offset),
            pointer(grad_out), pointer(grad_heads), None if grad_tau is None else pointer(grad_tau),
            None if grad_offset is None else pointer(grad_offset), torch.get_num_threads(),
        )  # fmt: skip
        return grad_heads, grad_tau, grad_offset
