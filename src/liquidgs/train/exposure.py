"""Exposure compensation: a learned colour correction per training frame, for captures whose camera
changed its exposure and white balance from frame to frame (a phone's automatic exposure).

A frame's correction is a per-channel gain and offset on the rendered image,
rgb' = rgb * (1 + gain) + offset, zero at the start (the frame as rendered). Without it a
time-dependent field can absorb a frame's brightness by reshaping Gaussians at that frame's time,
and score above the static model on a scene where nothing moves; with it every model, the static
one included, is given the same per-frame freedom. Test frames have no learned correction: the
aligned evaluation fits one per test view beside its pose (camera_opt.align_camera).

Learned from gsplat's simple_trainer (app_opt: a per-image appearance embedding in its own Adam)
and the affine colour correction of Mip-NeRF 360's evaluation; this one is per channel and per frame,
no network.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch

from liquidgs.data.loading import check_capture_switch, for_captures
from liquidgs.errors import LiquidGSError, check_number
from liquidgs.train.frame_corrections import FrameCorrections
from liquidgs.train.schedules import log_linear_lr


@dataclass
class ExposureConfig:
    """A per-channel gain and offset per training frame, and fitted per test view when aligned."""

    apply: Literal["auto", "on", "off"] = "auto"
    """auto: on for captures (the Nerfies layout: Nerfies, HyperNeRF, NeRF-DS, `data video`, `data
    images`), off for D-NeRF's rendered frames. A config.yml made before exposure compensation
    existed has none, and trains without it (off)."""
    lr: float = 1e-3
    """Adam learning rate of the gains and offsets, decaying log-linearly to lr_final over the run."""
    lr_final: float = 1e-5
    """The exposure gain and offset's learning rate at the end of training."""
    max_change: float = 0.5
    """A gain or offset past this (in units of full brightness) ran away: training stops naming the frame."""

    def __post_init__(self) -> None:
        check_capture_switch("exposure.apply", self.apply)
        for name in ("lr", "lr_final", "max_change"):
            check_number(f"exposure.{name.replace('_', '-')}", getattr(self, name), positive=True)


def compensates(cfg: ExposureConfig, data_format: str | None) -> bool:
    """Whether a run on data of this format learns a per-frame exposure (None: the format is unknown)."""
    return for_captures(cfg.apply, data_format)


def expose(rgb: torch.Tensor, gain: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
    """The image [H, W, 3] with a frame's correction: rgb * (1 + gain) + offset, per channel."""
    return rgb * (1.0 + gain) + offset


class ExposureCompensation(FrameCorrections):
    """The corrections of a run's training frames, their Adam and their schedule."""

    KEYS = ("gains", "offsets")
    WHAT, VERB, OFF_FLAG = "exposure compensation", "compensates", "--exposure.apply off"

    def __init__(self, cfg: ExposureConfig, frames: list, iterations: int, device, adam_eps: float):
        super().__init__(frames, device)
        self.cfg = cfg
        self.iterations = iterations
        self.optimizer = torch.optim.Adam([self.gains, self.offsets], lr=cfg.lr, eps=adam_eps)
        self._updated = False

    def correct(self, rgb: torch.Tensor, index: int) -> torch.Tensor:
        """Training frame `index`'s render as its exposure shows it."""
        self._updated = True
        return expose(rgb, self.gains[index], self.offsets[index])

    def step(self, step: int) -> None:
        """Adam on the corrections used this step, then the run-away check."""
        if not self._updated:
            return
        self._updated = False
        self.optimizer.param_groups[0]["lr"] = log_linear_lr(step, self.cfg.lr, self.cfg.lr_final, self.iterations)
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        with torch.no_grad():
            largest = torch.maximum(self.gains.abs(), self.offsets.abs()).amax(dim=1)
        for i in torch.nonzero(~(largest <= self.cfg.max_change)).flatten().tolist()[:1]:
            raise LiquidGSError(
                f"exposure compensation ran away at iteration {step}: train frame '{self.names[i]}' has gain "
                f"{self._triple(self.gains[i])} and offset {self._triple(self.offsets[i])} (bound "
                f"{self.cfg.max_change:g}); the frame may not show the scene: drop it, or train with "
                "--exposure.apply off"
            )

    @staticmethod
    def _triple(values: torch.Tensor) -> str:
        return "(" + ", ".join(f"{float(v):+.3f}" for v in values.detach()) + ")"

    def report(self, iteration: int) -> dict:
        """exposure.json: how each training frame's brightness was corrected, readable by a user."""
        gains, offsets = self.gains.detach().cpu(), self.offsets.detach().cpu()
        frames = [
            {"name": name, "gain": [round(float(v), 5) for v in gains[i]],
             "offset": [round(float(v), 5) for v in offsets[i]]}
            for i, name in enumerate(self.names)
        ]  # fmt: skip
        return {
            "iteration": iteration,
            "about": "per training frame, the colour correction learned for its exposure: the frame's render is "
            "rgb * (1 + gain) + offset, per channel (R, G, B; brightness in [0, 1])",
            "largest_gain": round(float(gains.abs().max()), 5) if len(frames) else 0.0,
            "largest_offset": round(float(offsets.abs().max()), 5) if len(frames) else 0.0,
            "frames": frames,
        }
