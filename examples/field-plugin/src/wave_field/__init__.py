"""The 'wave' deformation field: an example of a liquidgs field plugin.

An MLP of the canonical position and of sin / cos of the time at a few frequencies gives the
three deltas. Its own settings (WaveOptions) are --field-options.* of `liquidgs train --field
wave`; it is stochastic: in training it adds Gaussian noise of std lambda (--lambda, default
0.01) to its hidden layer, and eval mode is deterministic, as the contract asks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from liquidgs.fields import DeformationField, linear_flops
from liquidgs.fields import register as register_field

WIDTHS = {"tiny": 32, "dnerf": 64, "nerfds": 64}
"""Hidden width by preset, when --field-options.width is not given."""


@dataclass
class WaveOptions:
    """The field's own settings: --field-options.width, --field-options.frequencies."""

    width: int | None = None
    """Hidden width (None: the preset's, WIDTHS)."""
    frequencies: int = 3
    """Time frequencies 1..F of the sin / cos time features."""

    def __post_init__(self) -> None:
        if self.width is not None and self.width < 1:
            raise ValueError(f"width must be >= 1, got {self.width}")
        if not 1 <= self.frequencies <= 16:
            raise ValueError(f"frequencies must be between 1 and 16, got {self.frequencies}")


class WaveField(DeformationField):
    def __init__(self, config):
        super().__init__(config)
        options: WaveOptions = self.config.options
        width = options.width or WIDTHS[self.config.preset]
        self.frequencies = options.frequencies
        self.noise_std = self.config.base_lambda
        self.hidden = nn.Linear(3 + 2 * self.frequencies, width)
        self.head = nn.Linear(width, 10)
        nn.init.zeros_(self.head.weight)  # no deformation at the start
        nn.init.zeros_(self.head.bias)

    def deltas(self, xyz: torch.Tensor, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        k = torch.arange(1, self.frequencies + 1, device=xyz.device, dtype=xyz.dtype)
        phase = 2 * math.pi * t * k  # [1 or N, F]
        time = torch.cat([phase.sin(), phase.cos()], dim=1).expand(xyz.shape[0], -1)
        h = torch.tanh(self.hidden(torch.cat([xyz, time], dim=1)))
        if self.noise_active and self.noise_std > 0:
            h = h + self.noise_std * torch.randn_like(h)
        d = self.head(h)
        return d[:, :3], d[:, 3:7], d[:, 7:]

    def flops_per_gaussian(self) -> int:
        return linear_flops(self)


def register() -> None:
    """The "liquidgs.fields" entry point (pyproject.toml)."""
    register_field("wave", WaveField, presets=WIDTHS, label="Wave MLP", options=WaveOptions, default_lambda=0.01)
