"""FieldConfig: every size and noise setting of a deformation field, with per-dataset presets.

A setting left at None takes its value from the preset of the field's family ("mlp" for the
D-3DGS MLP, "liquid" for the CfC / SDE fields: the family a field registers with, fields/registry.py);
`resolved()` fills them in. A field registered without a family (hexplane, plugins) takes its sizes
from its own preset, and a config that sets any of these options for it is refused, but for the
options that one field alone reads (FIELD_ONLY_OPTIONS). Every value is checked when the config is
built, so a bad setting fails early with a ConfigError.
"""

from __future__ import annotations

import dataclasses
import functools
import typing
from dataclasses import dataclass
from typing import Any, Literal

from liquidgs.errors import ConfigError, check_integer, check_number
from liquidgs.fields.presets import FAMILY_SIZES, PRESET_NAMES, PRESETS
from liquidgs.fields.registry import field_names, field_type, install_options_check

PresetName = Literal[PRESET_NAMES]  # type: ignore[valid-type]
ACTIVATIONS = ("silu", "relu", "tanh", "gelu", "lecun_tanh")
NOISE_SITES = ("gate", "ou", "solver")
SCHEDULES = ("constant", "linear", "cosine")

SIZE_BOUNDS = {
    "xyz_freqs": (0, 100),
    "time_freqs": (0, 100),
    "timenet_width": (0, 4096),
    "timenet_out": (0, 1024),
    "mlp_depth": (1, 80),
    "mlp_width": (1, 4096),
    "cells": (1, 64),
    "hidden": (1, 4096),
    "backbone_units": (1, 4096),
    "backbone_layers": (1, 32),
}
"""(lowest, highest) of each size of the built-in fields: a field's cost grows with each, and the
highest is 10-32x the largest preset's (fields/presets.py), room for any study on one GPU."""

FIELD_ONLY_OPTIONS = {"grid_lr_scale": "hexplane", "level_time_resolutions": "hexplane"}
"""FieldOptions that one field alone reads (by its name): refused for every other field, and left
out of the other fields' config identities (so theirs stay those of the runs made before)."""

SDE_OPTIONS = ("noise", "lambda_schedule", "lambda_decay_steps", "adaptive_lambda", "lambda_floor", "solver_dt",
               "ltc_leak")  # fmt: skip
"""FieldOptions of the 'sde' field's noise variants, read by it alone."""


def options_read(name: str) -> tuple[str, ...]:
    """The FieldOptions field `name` reads (beside the options it registered): its family's sizes,
    the liquid stack's dropout, the 'sde' field's noise variants, the options it alone owns."""
    family = field_type(name).family
    read = FAMILY_SIZES[family] if family is not None else ()
    read += ("backbone_dropout",) if family == "liquid" else ()
    read += SDE_OPTIONS if name == "sde" else ()
    return read + tuple(key for key, owner in FIELD_ONLY_OPTIONS.items() if owner == name)


PAPER_LAMBDA = 0.05
"""The paper's calibrated gate-noise level, used when an 'sde' config leaves lambda unset."""


def default_lambda(name: str) -> float:
    """The noise level of a field whose lambda is not given: the one a stochastic field registered
    (the paper's for 'sde'), else 0."""
    return field_type(name).default_lambda or 0.0


def check_choice(kind: str, value: str, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ConfigError(f"unknown {kind} '{value}' (choose from {', '.join(choices)})")


@dataclass
class FieldOptions:
    """Sizes, noise variants and HexPlane's grid learning rate: everything but which field it is
    (name, preset, lambda).

    Not validated on its own: most rules depend on the field's name, so they are checked once,
    when a FieldConfig is built from these options and a name (train's --field-options.*).
    None means "from the preset".
    """

    # Encodings, shared by the MLP and liquid fields.
    xyz_freqs: int | None = None
    """Positional-encoding frequencies 2^0..2^(L-1) of the canonical position (at most 100)."""
    time_freqs: int | None = None
    """Positional-encoding frequencies of the time (at most 100)."""
    timenet_width: int | None = None
    """Hidden width of the time network Linear-ReLU-Linear on gamma(t); 0 = no time network (at most 4,096)."""
    timenet_out: int | None = None
    """Output width of the time network (0 when there is none; at most 1,024)."""

    # D-3DGS MLP.
    mlp_depth: int | None = None
    """Hidden layers of the MLP (at most 80)."""
    mlp_width: int | None = None
    """Width of each hidden layer of the MLP (at most 4,096)."""

    # Liquid (CfC) stack.
    cells: int | None = None
    """CfC cells in the stack (at most 64)."""
    hidden: int | None = None
    """Hidden units of each cell (at most 4,096)."""
    backbone_units: int | None = None
    """Width of each cell's backbone layers (at most 4,096)."""
    backbone_layers: int | None = None
    """Backbone layers of each cell (at most 32)."""
    activation: Literal[ACTIVATIONS] | None = None  # type: ignore[valid-type]
    """Backbone activation of each CfC cell (None: the preset's)."""
    backbone_dropout: float = 0.0
    """Dropout between each cell's backbone layers while training."""

    # Noise variants of the 'sde' field (beyond the paper).
    noise: Literal[NOISE_SITES] = "gate"  # type: ignore[valid-type]
    """Where the noise enters: the time gate (paper), an exact Ornstein-Uhlenbeck hidden-state
    transition, or the same hidden-state SDE integrated by torchsde (Euler-Maruyama)."""
    lambda_schedule: Literal[SCHEDULES] = "constant"  # type: ignore[valid-type]
    """How lambda changes over training: constant (paper), or annealed to 0 by lambda_decay_steps
    (linear or cosine)."""
    lambda_decay_steps: int = 0
    """Training step at which a linear / cosine schedule has brought lambda to 0."""
    adaptive_lambda: bool = False
    """Input-dependent lambda_i = lambda * (floor + (1 - floor) * sigmoid(w . z + b)) per cell."""
    lambda_floor: float = 0.25
    """Lower bound of the adaptive noise scale, as a fraction of lambda (0 < floor <= 1)."""
    solver_dt: float = 0.05
    """Euler step of the solver variant, in units of the elapsed time normalised to [0, 1]."""
    ltc_leak: float = 0.0
    """1 / tau_c of the hidden-state drift -(1/tau_c + f) h + f A (0: the pure OU form)."""

    # HexPlane (fields/hexplane.py), whose sizes come from its preset.
    grid_lr_scale: float | None = None
    """The 'hexplane' grid's learning rate as a multiple of the field learning rate, which its
    decoder trains at (None: the preset's, 10, 4DGaussians' ratio)."""
    level_time_resolutions: tuple[int, ...] = ()
    """The 'hexplane' grid's nodes along time, one value per level (none: the preset's time resolution at
    every level, as 4DGaussians)."""


@dataclass
class FieldConfig(FieldOptions):
    """Settings of one deformation field, validated when built."""

    name: str = "cfc"
    """A registered field (fields/registry.py)."""
    preset: PresetName = "dnerf"
    lambda_: float | None = None
    """Noise level of a stochastic field (None: the one it registered, 0.05 for 'sde'); must be 0
    for the others."""
    options: Any = None
    """The field's own settings, an instance of the options dataclass it registered (None: its
    defaults); None for a field that registered none."""

    @classmethod
    def of(cls, options: FieldOptions, name: str, preset: str, lambda_: float | None) -> FieldConfig:
        """The config of field `name` from a run's field_options (field_options_class(name))."""
        shared = {f.name: getattr(options, f.name) for f in dataclasses.fields(FieldOptions)}
        own_class = field_type(name).options
        own = None
        if own_class is not None:
            own = {f.name: getattr(options, f.name) for f in dataclasses.fields(own_class) if hasattr(options, f.name)}
        return cls(**shared, name=name, preset=preset, lambda_=lambda_, options=own)

    def __post_init__(self) -> None:
        self._validate(self._resolved_values())
        own_class = field_type(self.name).options
        if own_class is None:
            if self.options is not None:
                raise ConfigError(f"field '{self.name}' has no options of its own, got {self.options!r}")
        elif not isinstance(self.options, own_class):
            self.options = _own_options(self.name, own_class, self.options or {})

    @property
    def base_lambda(self) -> float:
        """The base noise level lambda after defaulting."""
        return default_lambda(self.name) if self.lambda_ is None else float(self.lambda_)

    def resolved(self) -> FieldConfig:
        """A copy with every size of this field's family, and lambda_, filled in."""
        return dataclasses.replace(self, **self._resolved_values(), lambda_=self.base_lambda)

    def _resolved_values(self) -> dict:
        kind = field_type(self.name)
        check_choice("preset", self.preset, PRESET_NAMES)
        if self.preset not in kind.presets:
            raise ConfigError(f"field '{self.name}' has no preset '{self.preset}' (it has {', '.join(kind.presets)})")
        if kind.family is None:
            # A field outside the built-in families is sized by its preset alone.
            changed = [
                f.name
                for f in dataclasses.fields(FieldOptions)
                if getattr(self, f.name) != f.default and f.name not in FIELD_ONLY_OPTIONS
            ]
            if changed:
                raise ConfigError(
                    f"field '{self.name}' takes its sizes from its preset; --field-options "
                    f"({', '.join(changed)}) apply to the built-in fields only"
                )
            return {}
        defaults = PRESETS[self.preset].get(kind.family, {})
        return {
            key: defaults[key] if getattr(self, key) is None else getattr(self, key)
            for key in FAMILY_SIZES[kind.family]
        }

    def _validate(self, values: dict) -> None:
        check_number("field: lambda", self.base_lambda)
        if self.base_lambda != 0 and field_type(self.name).default_lambda is None:
            raise ConfigError(f"field '{self.name}' is deterministic: lambda must be 0 (use 'sde')")
        if self.name != "sde" and (self.noise, self.lambda_schedule, self.adaptive_lambda) != (
            "gate",
            "constant",
            False,
        ):
            raise ConfigError(
                f"noise, lambda_schedule and adaptive_lambda apply to the 'sde' field only, not to '{self.name}'"
            )
        for key, owner in FIELD_ONLY_OPTIONS.items():
            if getattr(self, key) not in (None, ()) and self.name != owner:
                raise ConfigError(f"{key} applies to the '{owner}' field only, not to '{self.name}'")
        if self.grid_lr_scale is not None:
            check_number("field: grid_lr_scale", self.grid_lr_scale, positive=True)
        for key, (lowest, highest) in SIZE_BOUNDS.items():
            if key in values:
                check_integer(f"field: {key}", values[key], lowest, highest)
        if "timenet_width" in values and (values["timenet_width"] > 0) != (values["timenet_out"] > 0):
            raise ConfigError("field: timenet_width and timenet_out must be both > 0 or both 0")
        check_choice("activation", values.get("activation", "gelu"), ACTIVATIONS)
        check_choice("noise site", self.noise, NOISE_SITES)
        check_choice("lambda schedule", self.lambda_schedule, SCHEDULES)
        if not 0.0 <= self.backbone_dropout < 1.0:
            raise ConfigError(f"field: backbone_dropout must be in [0, 1), got {self.backbone_dropout}")
        if self.lambda_schedule != "constant" and self.lambda_decay_steps < 1:
            raise ConfigError(
                f"lambda schedule '{self.lambda_schedule}' needs lambda_decay_steps >= 1, got {self.lambda_decay_steps}"
            )
        if not 0.0 < self.lambda_floor <= 1.0:
            raise ConfigError(f"field: lambda_floor must be in (0, 1], got {self.lambda_floor}")
        if not 0.0 < self.solver_dt <= 1.0:
            raise ConfigError(f"field: solver_dt must be in (0, 1], got {self.solver_dt}")
        check_number("field: ltc_leak", self.ltc_leak)
        if self.ltc_leak > 0 and self.noise == "gate":
            raise ConfigError("field: ltc_leak applies to the hidden-state noise sites ('ou', 'solver') only")


def _own_options(name: str, own_class: type, values: dict):
    """A field's own options from their values, checked by the field's own rules (its __post_init__)."""
    kind = field_type(name)
    try:
        return own_class(**values)
    except ConfigError:
        raise
    except Exception as error:  # a plugin's rules: any exception is a bad setting, named
        raise ConfigError(
            f"field '{name}' (package {kind.origin}): bad --field-options: {type(error).__name__}: {error}"
        ) from None


SETTING_TYPES = "int, float, bool, str, a Literal, a tuple or list of those, or one of those or None"


def check_options_class(name: str, options: type) -> None:
    """The options a field registers: a dataclass whose settings all have defaults of a type
    settings reads, named apart from the shared FieldOptions (their flags are one namespace)."""
    from liquidgs import settings  # settings reads the field registry through train's config

    if not (isinstance(options, type) and dataclasses.is_dataclass(options)):
        raise ConfigError(f"field '{name}': options must be a dataclass, got {options!r}")
    try:
        hints = typing.get_type_hints(options)
    except Exception as error:
        raise ConfigError(f"field '{name}': options {options.__name__}: {type(error).__name__}: {error}") from None
    shared = {f.name for f in dataclasses.fields(FieldConfig)}
    for f in dataclasses.fields(options):
        where = f"field '{name}': option '{f.name}'"
        if f.name in shared:
            raise ConfigError(f"{where} is a setting of every field (FieldOptions): choose another name")
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise ConfigError(f"{where} needs a default")
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        try:
            fits = settings.matches(settings.to_dict_value(default), hints[f.name])
        except TypeError:
            raise ConfigError(f"{where}: type {hints[f.name]} is not one settings read ({SETTING_TYPES})") from None
        if not fits:
            raise ConfigError(f"{where}: default {default!r} is not {settings.describe(hints[f.name])}")


install_options_check(check_options_class)


@functools.cache
def _options_subclass(name: str, own_class: type) -> type:
    hints = typing.get_type_hints(own_class)
    own = [(f.name, hints[f.name], dataclasses.field(default=f.default, default_factory=f.default_factory))
           for f in dataclasses.fields(own_class)]  # fmt: skip
    return dataclasses.make_dataclass(
        f"{own_class.__name__}FieldOptions", own, bases=(FieldOptions,), namespace={"__doc__": own_class.__doc__}
    )


def field_options_class(name: str) -> type[FieldOptions]:
    """The class of a run's field_options for field `name`: FieldOptions, with the settings of the
    field's own options dataclass where it registered one (so they are --field-options.* too)."""
    try:
        own_class = field_type(name).options
    except ConfigError:  # an unknown field: the run's config names it in its own error
        return FieldOptions
    return FieldOptions if own_class is None else _options_subclass(name, own_class)


def own_option_flags() -> dict[str, list]:
    """Every registered field's own options: {setting name: [(field, type hint), ...]}."""
    found: dict[str, list] = {}
    for name in field_names():
        own_class = field_type(name).options
        if own_class is not None:
            hints = typing.get_type_hints(own_class)
            for f in dataclasses.fields(own_class):
                found.setdefault(f.name, []).append((name, hints[f.name]))
    return found
