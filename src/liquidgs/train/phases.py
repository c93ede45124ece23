"""Time of each phase of a training step, for `liquidgs bench train`: wall-clock, or the process's
CPU time (steadier than wall time on a CPU shared with other work, which only the wall clock counts).

The trainer marks the end of each phase; the backward pass is split with tensor hooks: the
gradient reaching the rendered image ends the loss's backward, the first gradient reaching
the deformed Gaussians ends the rasteriser's, and the return of backward() ends the field's
(plus the parameter activations', which are elementwise and small). Timing changes nothing
that is computed. On CUDA every mark synchronises, which is why it is off by default.
"""

from __future__ import annotations

import time
from collections.abc import Iterable

import torch

PHASES = (
    "data",
    "field_forward",
    "raster_forward",
    "loss_forward",
    "loss_backward",
    "raster_backward",
    "field_backward",
    "densification",
    "optimizer_step",
    "other",
)


class NoClock:
    """The default: every call does nothing."""

    def start(self) -> None:
        pass

    def mark(self, phase: str) -> None:
        pass

    def watch_backward(self, image: torch.Tensor, gaussians: Iterable[torch.Tensor]) -> None:
        pass

    def end_backward(self) -> None:
        pass


class PhaseClock(NoClock):
    """Seconds per phase of the current step in `times` (reset by start()); `cpu_time`: the process's
    CPU seconds (a CPU device only) instead of the wall clock's."""

    def __init__(self, device: torch.device, cpu_time: bool = False):
        if cpu_time and device.type != "cpu":
            raise ValueError("CPU time measures a CPU device's work only")
        self.device = device
        self.now = time.process_time if cpu_time else time.perf_counter
        """The clock, in seconds: also the benchmark's for whole steps."""
        self.times: dict[str, float] = {}
        self._last = 0.0
        self._handles: list = []
        self._backward: dict[str, float] = {}

    def _now(self) -> float:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        return self.now()

    def start(self) -> None:
        self.times = dict.fromkeys(PHASES, 0.0)
        self._last = self._now()

    def mark(self, phase: str) -> None:
        now = self._now()
        self.times[phase] += now - self._last
        self._last = now

    def watch_backward(self, image: torch.Tensor, gaussians: Iterable[torch.Tensor]) -> None:
        self._backward = {}

        def stamp(name: str):
            def hook(grad: torch.Tensor) -> None:
                self._backward.setdefault(name, self._now())

            return hook

        self._handles = [image.register_hook(stamp("image"))]
        self._handles += [t.register_hook(stamp("gaussians")) for t in gaussians if t.requires_grad]

    def end_backward(self) -> None:
        end = self._now()
        for handle in self._handles:
            handle.remove()
        image_at = self._backward.get("image", self._last)
        gaussians_at = self._backward.get("gaussians", end)
        self.times["loss_backward"] += image_at - self._last
        self.times["raster_backward"] += gaussians_at - image_at
        self.times["field_backward"] += end - gaussians_at
        self._last = end
