"""The field registry: the one owner of which deformation fields exist, their names and labels.

Every field - the built-in static, mlp, cfc and sde, and any field from another installed
package - is registered through `register`. The registry is filled once, lazily, when it is first
read: the built-in fields, then every entry point of the group "liquidgs.fields" (in the order of
their names). An entry point names a function that takes no argument and calls `register`; in a
plugin's pyproject.toml:

    [project.entry-points."liquidgs.fields"]
    myfield = "my_package.field:register"

A registered name is accepted wherever a field is named: `liquidgs train --field NAME`, experiment
specs, `bench fields`; render, export, eval and the viewer rebuild a run's field from its config
through `build_field`, and reports label its rows with the registered label.

The contract a field satisfies (fields/base.py's DeformationField; subclass it):
- factory(config) -> DeformationField, with config the FieldConfig of a run (name, preset,
  lambda_ and, for the built-in families, the FieldOptions sizes). A field registered without a
  family takes its sizes from its own preset: config.preset is one of the `presets` it registered
  (dnerf / nerfds / tiny, the names the training schedules share), and --field-options.* do not
  apply to it (a config that sets any is refused; hexplane reads one, grid_lr_scale, named in
  fields/config.py's FIELD_ONLY_OPTIONS). lambda_ is the 'sde' field's noise level and
  is 0 for every other field.
- deltas(xyz, t) -> (d_xyz [N, 3], d_rotation [N, 4], d_scaling [N, 3]) for canonical means
  xyz [N, 3] and times t [1, 1] (one time for every Gaussian) or [N, 1]. forward() detaches xyz
  before calling deltas (stop-gradient: a field never moves the means through its input) and
  checks the shapes of what deltas returns: a field that breaks the contract fails with one line
  naming it, before the first training step (Trainer runs DeformationField.begin_training).
- train / eval: a stochastic field draws noise only while `noise_active` (training mode, or inside
  `noise_on` for Monte-Carlo sampling); eval mode is deterministic.
- num_parameters() (all parameters by default) and flops_per_gaussian(): 2 x multiply-adds of the
  Linear layers per Gaussian (linear_flops), encodings and grid lookups not counted; `bench
  fields` reports both.
- Optional hooks, no-ops by default: setup(xyz) with the initial means before training
  (hexplane fits its grid box to them), regulariser_loss() -> a scalar tensor or None, which
  the trainer adds to the loss at every step after the warm-up (hexplane's grid regularisers),
  and param_groups() -> [(name, parameters, scale)], every parameter in exactly one group, each
  trained at the run's field learning rate times its scale (default: one group at 1; hexplane's
  grid at 10). A field's state that setup sets must be a parameter or a persistent buffer, so
  checkpoints carry it.

Bad input: a plugin whose import or registration fails is reported in one line naming its package
and the error, and every other field still works; two packages registering one name make that name
unusable, with one line naming both.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import sys
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from liquidgs.errors import ConfigError, one_line
from liquidgs.fields.presets import FAMILY_SIZES, PRESET_NAMES

if TYPE_CHECKING:
    from liquidgs.fields.base import DeformationField
    from liquidgs.fields.config import FieldConfig

ENTRY_POINT_GROUP = "liquidgs.fields"
BUILTIN_PACKAGE = "liquidgs"
BUILTIN_REGISTRATIONS = "liquidgs.fields.builtin"
"""The module whose register_builtin_fields() registers the built-in fields."""


class NameTaken(ConfigError):
    """A field name registered a second time."""


@dataclass(frozen=True)
class FieldType:
    """One registered field."""

    name: str
    factory: Callable[[FieldConfig], DeformationField]
    label: str
    """The name tables, reports and figures show."""
    presets: tuple[str, ...]
    """The presets the field has sizes for."""
    family: str | None
    """The built-in size family whose FieldOptions the field reads ('static', 'mlp', 'liquid'),
    or None: its sizes come from its preset alone."""
    package: str
    """The distribution that registered it ('liquidgs' for the built-in fields)."""


def installed_plugins() -> list[tuple[str, importlib.metadata.EntryPoint]]:
    """(package, entry point) of every installed 'liquidgs.fields' entry point, by name."""
    found = importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)
    return [(ep.dist.name if ep.dist else ep.module.split(".")[0], ep) for ep in sorted(found, key=lambda e: e.name)]


class FieldRegistry:
    """The registered fields, filled on first read from the built-ins and `list_plugins()`."""

    def __init__(self, list_plugins: Callable[[], Iterable[tuple[str, importlib.metadata.EntryPoint]]]):
        self._list_plugins = list_plugins
        self._fields: dict[str, FieldType] = {}
        self._conflicts: dict[str, str] = {}
        """Names registered twice: the one-line error that using them gives."""
        self.problems: list[str] = []
        """One line per plugin that failed to load or registered a taken name (printed as warnings)."""
        self._failed_packages: list[str] = []
        self._loaded = False
        self._package: str | None = None
        """The package whose registrations are running (None: a direct call)."""

    def register(
        self,
        name: str,
        factory: Callable[[FieldConfig], DeformationField],
        *,
        presets: Collection[str],
        label: str | None = None,
        family: str | None = None,
    ) -> None:
        package = self._package or getattr(factory, "__module__", "?").split(".")[0]
        if not (isinstance(name, str) and name.isidentifier() and name.islower()):
            raise ConfigError(f"a field name must be a lowercase identifier, got {name!r}")
        if not callable(factory):
            raise ConfigError(f"field '{name}': the factory must be callable, got {factory!r}")
        presets = tuple(presets)
        unknown = [p for p in presets if p not in PRESET_NAMES]
        if not presets or unknown:
            raise ConfigError(f"field '{name}' must register presets among {', '.join(PRESET_NAMES)}, got {presets}")
        if family is not None and family not in FAMILY_SIZES:
            raise ConfigError(f"field '{name}': unknown family '{family}' (choose from {', '.join(FAMILY_SIZES)})")
        if name in self._conflicts:
            return
        if name in self._fields:
            first = self._fields.pop(name).package
            self._conflicts[name] = (
                f"field '{name}' is registered by two packages, '{first}' and '{package}': uninstall one"
            )
            raise NameTaken(self._conflicts[name])
        self._fields[name] = FieldType(name, factory, label or name, presets, family, package)

    def _load(self) -> None:
        if self._loaded:
            return
        self._loaded = True  # first: a plugin's own reads of the registry must not load it again
        self._package = BUILTIN_PACKAGE
        try:
            # Loaded by name, as a plugin's entry point is: the registry depends on no field.
            importlib.import_module(BUILTIN_REGISTRATIONS).register_builtin_fields()
        finally:
            self._package = None
        try:
            plugins = list(self._list_plugins())
        except Exception as error:  # broken installed metadata: the built-in fields still work
            plugins = []
            self._problem(f"the '{ENTRY_POINT_GROUP}' entry points could not be read: {type(error).__name__}: {error}")
        for package, entry_point in plugins:
            self._package = package
            try:
                entry_point.load()()
            except NameTaken as error:
                self._problem(str(error))
            except Exception as error:
                self._failed_packages.append(package)
                self._problem(
                    f"field plugin package '{package}' failed to load ({entry_point.name} = {entry_point.value}): "
                    f"{type(error).__name__}: {error}"
                )
            finally:
                self._package = None

    def _problem(self, line: str) -> None:
        self.problems.append(one_line(line))
        print(f"liquidgs: warning: {self.problems[-1]}", file=sys.stderr)

    def names(self) -> tuple[str, ...]:
        self._load()
        return tuple(self._fields)

    def get(self, name: str) -> FieldType:
        self._load()
        if name in self._conflicts:
            raise ConfigError(self._conflicts[name])
        if name not in self._fields:
            failed = self._failed_packages
            note = f"; field plugin packages that failed to load: {', '.join(failed)}" if failed else ""
            raise ConfigError(f"unknown field '{name}' (choose from {', '.join(self._fields)}){note}")
        return self._fields[name]


REGISTRY = FieldRegistry(installed_plugins)
"""The process's registry (tests replace it to list their own plugins)."""


def register(
    name: str,
    factory: Callable[[FieldConfig], DeformationField],
    *,
    presets: Collection[str],
    label: str | None = None,
    family: str | None = None,
) -> None:
    """Make a field available under `name` (see the module docstring for the contract).

    presets: the preset names the field has sizes for (a dict of sizes by preset name works: its
    keys are used). label: what tables show (default: the name). family: for fields that read
    the built-in FieldOptions sizes ('mlp', 'liquid'); leave it None to size the field by its
    preset alone. Raises ConfigError for a bad name, preset or family, or a name already taken.
    """
    REGISTRY.register(name, factory, presets=presets, label=label, family=family)


def field_names() -> tuple[str, ...]:
    """Every usable registered field, in the order tables list them: the built-ins, then plugins."""
    return REGISTRY.names()


def field_type(name: str) -> FieldType:
    """The registered field `name`; ConfigError (one line, the choices) when there is none."""
    return REGISTRY.get(name)


def field_label(name: str) -> str:
    return field_type(name).label
