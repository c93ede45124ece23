"""The field contract as a check a plugin's own tests call (installed with liquidgs).

    from liquidgs.fields.testing import check_field, plugin_registry
    from my_package.field import register

    def test_my_field_keeps_the_contract():
        with plugin_registry(register, package="my-fields"):  # not needed once the package is installed
            check_field("wave")

check_field builds the field for every preset it registered (and for each given options) and
checks what liquidgs relies on (fields/registry.py describes the contract): a DeformationField;
deltas of the right shapes for one time and for a time per point; no gradient into the means;
eval mode deterministic, whatever lambda; gradients reaching every parameter in training; its
parameter groups, regulariser, parameter and FLOP counts; its state (set by setup) carried by
its state_dict, so a checkpoint rebuilds the same field. A broken promise is an AssertionError
naming the field and what broke.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable, Iterator
from importlib.metadata import EntryPoint

import torch

from liquidgs.fields import registry
from liquidgs.fields.base import DeformationField
from liquidgs.fields.build import build_field
from liquidgs.fields.config import FieldConfig


@contextlib.contextmanager
def plugin_registry(register: Callable[[], None], package: str, version: str | None = None) -> Iterator[None]:
    """Inside: a registry that also loads `register` as package `package`'s entry point would
    (for a plugin's tests run from its checkout, before it is installed). An installed package of
    that name listing the same function is loaded once."""
    entry_point = EntryPoint(
        register.__name__, f"{register.__module__}:{register.__qualname__}", registry.ENTRY_POINT_GROUP
    )
    listed = registry.REGISTRY._list_plugins
    previous = registry.REGISTRY
    registry.REGISTRY = registry.FieldRegistry(lambda: [*listed(), registry.Plugin(package, version, entry_point)])
    try:
        yield
    finally:
        registry.REGISTRY = previous


def check_field(name: str, options: list[dict] | None = None, lambda_: float | None = None, points: int = 64) -> None:
    """The contract check of the registered field `name` at each of its presets, with its default
    options and with each settings dict in `options` (e.g. [{"width": 8}])."""
    kind = registry.field_type(name)
    for preset in kind.presets:
        for own in [None, *(options or [])]:
            config = FieldConfig(name=name, preset=preset, lambda_=lambda_, options=own)
            _check_one(config, f"field '{name}' (preset {preset}{'' if own is None else f', options {own}'})", points)


def _check_one(config: FieldConfig, what: str, n: int) -> None:
    torch.manual_seed(0)
    field = build_field(config)
    assert isinstance(field, DeformationField), f"{what}: the factory returned {type(field).__name__}"
    xyz = torch.rand(n, 3) * 2 - 1
    field.begin_training(xyz)  # setup, then the shapes of the deltas
    field.checked_param_groups()
    for p in field.parameters():
        p.data.add_(0.01 * torch.randn_like(p))  # away from an initialisation where some gradients vanish
    field.set_progress(1)
    field.train()
    means = xyz.clone().requires_grad_(True)
    loss = sum(d.square().sum() + d.sum() for d in field(means, torch.full((n, 1), 0.3)))
    regulariser = field.regulariser_loss()
    if regulariser is not None:
        assert isinstance(regulariser, torch.Tensor) and regulariser.dim() == 0, (
            f"{what}: regulariser_loss() must return a scalar tensor or None, got {regulariser!r}"
        )
        loss = loss + regulariser
    if loss.requires_grad:  # a field without parameters (static) has no gradient at all
        loss.backward()
    assert means.grad is None or not means.grad.any(), f"{what}: the deltas move the means through their input"
    without = [n for n, p in field.named_parameters() if p.requires_grad and (p.grad is None or not p.grad.any())]
    assert not without, f"{what}: no gradient reaches {', '.join(without)} in training"
    field.eval()
    t = torch.full((1, 1), 0.7)
    first, again = field(xyz, t), field(xyz, t)
    assert all(torch.equal(a, b) for a, b in zip(first, again)), f"{what}: eval mode is not deterministic"
    assert all(torch.isfinite(d).all() for d in first), f"{what}: non-finite deltas in eval mode"
    count, flops = field.num_parameters(), field.flops_per_gaussian()
    assert isinstance(count, int) and count >= 0, f"{what}: num_parameters() must be an int >= 0, got {count!r}"
    assert isinstance(flops, int) and flops >= 0, f"{what}: flops_per_gaussian() must be an int >= 0, got {flops!r}"
    rebuilt = build_field(dataclasses.replace(config))
    rebuilt.load_state_dict(field.state_dict())
    rebuilt.eval()
    same = all(torch.equal(a, b) for a, b in zip(first, rebuilt(xyz, t)))
    assert same, (
        f"{what}: a field rebuilt from its state_dict differs (state setup() sets must be a parameter or buffer)"
    )
