"""The interface every deformation field implements, and the static (zero) field."""

from __future__ import annotations

import abc
import contextlib
import math
from collections import Counter
from collections.abc import Iterator

import torch
from torch import nn
from torch.nn import functional as F

from liquidgs.errors import LiquidGSError
from liquidgs.fields.encoding import time_column

Deltas = tuple[torch.Tensor, torch.Tensor, torch.Tensor]
ParamGroup = tuple[str, list[nn.Parameter], float]
"""(name, parameters, learning-rate scale): one group of a field's parameters (param_groups)."""
DELTA_WIDTHS = {"d_xyz": 3, "d_rotation": 4, "d_scaling": 3}
"""Columns of each delta, in the order a field returns them."""
PROBE_POINTS = 8
"""Initial means a field is first run on by begin_training, to check its outputs' shapes."""


class FieldContractError(LiquidGSError):
    """A field's output breaks the contract (fields/registry.py)."""


def linear_flops(module: nn.Module) -> int:
    """2 x multiply-adds of every nn.Linear in module, for one input row."""
    return sum(2 * m.in_features * m.out_features for m in module.modules() if isinstance(m, nn.Linear))


def stacked_product(x: torch.Tensor, layers: list[nn.Linear]) -> torch.Tensor:
    """Linear layers on the same input as one product, their weights side by side: the outputs'
    columns in the layers' order. Narrow heads run several times faster this way on a CPU than
    one product each; the parameters stay the separate layers."""
    weight = torch.cat([layer.weight for layer in layers])
    bias = torch.cat([layer.bias for layer in layers])
    return F.linear(x, weight, bias)


def stacked_linear(x: torch.Tensor, layers: list[nn.Linear]) -> tuple[torch.Tensor, ...]:
    """stacked_product split back into one output per layer."""
    return stacked_product(x, layers).split([layer.out_features for layer in layers], dim=1)


class DeformationField(nn.Module, abc.ABC):
    """Maps canonical Gaussian means and a time to (d_xyz [N,3], d_rotation [N,4], d_scaling [N,3]).

    The field applies the stop-gradient on xyz itself, so it never passes gradients to the
    Gaussians' means. Noise (stochastic fields only) is active in training mode, and inside
    `monte_carlo` whatever the mode. The full contract, hooks included: fields/registry.py.
    """

    def __init__(self, config):
        super().__init__()
        self.config = config.resolved()
        self.name = type(self).__name__
        """The registered name (build_field sets it), for error messages."""
        self.progress_step = 0
        self._noise_forced = False

    def forward(self, xyz: torch.Tensor, t: torch.Tensor | float) -> Deltas:
        if xyz.dim() != 2 or xyz.shape[1] != 3:
            raise ValueError(f"xyz must have shape [N, 3], got {tuple(xyz.shape)}")
        xyz = xyz.detach()
        deltas = self.deltas(xyz, time_column(t, xyz.shape[0], xyz))
        self._check_deltas(deltas, xyz.shape[0])
        return deltas

    def _check_deltas(self, deltas, n: int) -> None:
        if isinstance(deltas, tuple | list):
            got = [tuple(d.shape) if isinstance(d, torch.Tensor) else type(d).__name__ for d in deltas]
        else:
            got = type(deltas).__name__
        if got != [(n, width) for width in DELTA_WIDTHS.values()]:
            contract = ", ".join(f"{key} [N, {width}]" for key, width in DELTA_WIDTHS.items())
            raise FieldContractError(
                f"field '{self.name}' returned {got} for N = {n} points; a field returns ({contract})"
            )

    @abc.abstractmethod
    def deltas(self, xyz: torch.Tensor, t: torch.Tensor) -> Deltas:
        """The deltas for detached xyz [N, 3] and t of shape [1, 1] or [N, 1]."""

    @abc.abstractmethod
    def flops_per_gaussian(self) -> int:
        """Forward FLOPs per Gaussian: 2 x multiply-adds of the Linear layers only.

        Not counted: bias additions, activations, positional encodings, the gate and
        state-update arithmetic, noise draws and solver steps (all elementwise, O(width)).
        Layers applied to the time alone (the time network) are counted once per Gaussian,
        as in the reference code, even though a time shared by all Gaussians is encoded once.
        """

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())

    def setup(self, xyz: torch.Tensor) -> None:
        """Optional hook: set the field up from the initial means [N, 3] before training (hexplane:
        its grid box). State it sets must be a parameter or a persistent buffer (checkpointed)."""

    def regulariser_loss(self) -> torch.Tensor | None:
        """Optional hook: a scalar loss term the trainer adds at every step after the warm-up."""
        return None

    def param_groups(self) -> list[ParamGroup]:
        """Optional hook: the parameters in groups (name, parameters, scale), each trained at the
        run's field learning rate times its scale (hexplane: the grid faster than the decoder).
        Every parameter in exactly one group; by default one group, "field", at scale 1."""
        return [("field", list(self.parameters()), 1.0)]

    def checked_param_groups(self) -> list[ParamGroup]:
        """param_groups, refused in one line naming the field unless it holds every parameter
        exactly once, each scale a finite number > 0 (the trainer builds its optimizer from it)."""
        groups = [(name, list(params), scale) for name, params, scale in self.param_groups()]
        names = {id(p): name for name, p in self.named_parameters()}
        counts = Counter(id(p) for _, params, _ in groups for p in params)
        missing = [name for key, name in names.items() if key not in counts]
        repeated = [names[key] for key, n in counts.items() if n > 1 and key in names]
        foreign = sum(key not in names for key in counts)
        problems = [f"missing {', '.join(missing)}"] if missing else []
        problems += [f"repeated {', '.join(repeated)}"] if repeated else []
        problems += [f"{foreign} parameter(s) that are not the field's"] if foreign else []
        if problems:
            raise FieldContractError(
                f"field '{self.name}': param_groups() must hold each of its parameters exactly once "
                f"({'; '.join(problems)})"
            )
        for name, _, scale in groups:
            if isinstance(scale, bool) or not (isinstance(scale, int | float) and math.isfinite(scale) and scale > 0):
                raise FieldContractError(
                    f"field '{self.name}': param group '{name}' has learning-rate scale {scale!r}, "
                    "not a finite number > 0"
                )
        return groups

    @torch.no_grad()
    def begin_training(self, xyz: torch.Tensor) -> None:
        """What the trainer calls before the first step: `setup`, then one eval-mode pass on a few
        of the means, so a field that breaks the output contract fails now with its name (eval
        mode draws no noise: the run's random numbers are untouched)."""
        self.setup(xyz)
        training = self.training
        self.eval()
        try:
            self(xyz[:PROBE_POINTS], 0.0)
        finally:
            self.train(training)

    def set_progress(self, step: int) -> None:
        """Record the training step (drives annealed noise schedules; otherwise unused)."""
        self.progress_step = int(step)

    @property
    def noise_active(self) -> bool:
        return self.training or self._noise_forced

    @contextlib.contextmanager
    def noise_on(self) -> Iterator[None]:
        """Noise on even in eval mode (Monte-Carlo sampling); the previous state is restored."""
        forced, self._noise_forced = self._noise_forced, True
        try:
            yield
        finally:
            self._noise_forced = forced

    @torch.no_grad()
    def monte_carlo(self, xyz: torch.Tensor, t: torch.Tensor | float, samples: int) -> tuple[Deltas, Deltas]:
        """K = samples noisy passes (noise on even in eval mode): per-Gaussian mean and variance.

        The variance is the unbiased sample variance (K - 1 in the denominator), accumulated
        with Welford's update so memory does not grow with K. Deterministic fields, and
        stochastic ones whose noise level is currently 0, give zero variance.
        """
        if samples < 2:
            raise ValueError(f"monte_carlo needs samples >= 2, got {samples}")
        with self.noise_on():
            mean = [value.clone() for value in self(xyz, t)]
            m2 = [torch.zeros_like(value) for value in mean]
            for k in range(2, samples + 1):
                for value, mu, acc in zip(self(xyz, t), mean, m2):
                    delta = value - mu
                    mu += delta / k
                    acc += delta * (value - mu)
        return tuple(mean), tuple(m / (samples - 1) for m in m2)


class StaticField(DeformationField):
    """No deformation: zero deltas and no parameters, the floor every field must beat."""

    def deltas(self, xyz: torch.Tensor, t: torch.Tensor) -> Deltas:
        n = xyz.shape[0]
        return xyz.new_zeros(n, 3), xyz.new_zeros(n, 4), xyz.new_zeros(n, 3)

    def flops_per_gaussian(self) -> int:
        return 0
