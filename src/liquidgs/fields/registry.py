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

Spatially local deformation: a field whose deformation has parameters per region of space (a
grid: hexplane) registers `local_deformation=True`. Neighbouring Gaussians can then move apart
freely, so captures train it with the neighbour motion regularisers by default (train/motion_reg.py);
a field that is one network over all of space (mlp, cfc, sde) is smooth in space already and trains
without them unless asked. Where a capture with flow trains it with the static/dynamic split by
default, the split takes the neighbour terms' place (train/motion_reg.py's
split_in_place_of_neighbour_terms).

Own settings: a field may register `options`, a dataclass whose every setting has a default
(int, float, bool, str, a Literal, a tuple, or one of those or None). Its settings are the field's
--field-options.* (train, experiment spec overrides), stored in config.yml with the others and part
of its runs' identity; the factory reads them as config.options, an instance of that dataclass
(built, so validated by its __post_init__, when the config is). A stochastic field registers
`default_lambda`, its noise level when --lambda is not given; it reads the run's as
config.base_lambda (eval mode must stay deterministic).

Bad input: a plugin whose import or registration fails (or exits) is reported in one line naming
its package and the error, and every other field still works; a plugin cannot take a built-in
field's name (one line naming it, the built-in is kept); two packages registering one name make
that name unusable, with one line naming both. A plugin's factory that fails is one line naming
the field and its package (build_field).
"""

from __future__ import annotations

import importlib
import importlib.metadata
import sys
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

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
    version: str | None = None
    """That distribution's version (None where it is not installed metadata, e.g. a test's)."""
    options: type | None = None
    """The dataclass of the field's own settings (--field-options.*), or None."""
    default_lambda: float | None = None
    """A stochastic field's noise level when none is given; None: the field is deterministic."""
    local_deformation: bool = False
    """Its deformation has parameters per region of space (a grid), not one network over all of it."""

    @property
    def plugin(self) -> bool:
        return self.package != BUILTIN_PACKAGE

    @property
    def origin(self) -> str:
        """The package as messages name it: 'my-fields 0.2'."""
        return f"{self.package} {self.version}" if self.version else self.package


class Plugin(NamedTuple):
    """One "liquidgs.fields" entry point and the distribution that declares it."""

    package: str
    version: str | None
    entry_point: importlib.metadata.EntryPoint | None
    """None for liquidgs' built-in registrations."""


def installed_plugins() -> list[Plugin]:
    """Every installed 'liquidgs.fields' entry point, by name."""
    found = importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)
    return [
        Plugin(ep.dist.name, ep.dist.version, ep) if ep.dist else Plugin(ep.module.split(".")[0], None, ep)
        for ep in sorted(found, key=lambda e: e.name)
    ]


def _options_unchecked(name: str, options: type) -> None:
    raise ConfigError(f"field '{name}': options cannot be checked before liquidgs.fields.config is imported")


_options_check: Callable[[str, type], None] = _options_unchecked


def install_options_check(check: Callable[[str, type], None]) -> None:
    """How a field's options class is checked at registration (raises ConfigError): installed by
    fields/config.py, which owns the settings the options must fit, so that this registry imports
    nothing above it."""
    global _options_check
    _options_check = check


class FieldRegistry:
    """The registered fields, filled on first read from the built-ins and `list_plugins()`."""

    def __init__(self, list_plugins: Callable[[], Iterable[Plugin]]):
        self._list_plugins = list_plugins
        self._fields: dict[str, FieldType] = {}
        self._conflicts: dict[str, str] = {}
        """Names registered twice: the one-line error that using them gives."""
        self.problems: list[str] = []
        """One line per plugin that failed to load or registered a taken name (printed as warnings)."""
        self._failed_packages: list[str] = []
        self._loaded = False
        self._loading: Plugin | None = None
        """The plugin whose registrations are running (None: the built-ins or a direct call)."""

    def register(
        self,
        name: str,
        factory: Callable[[FieldConfig], DeformationField],
        *,
        presets: Collection[str],
        label: str | None = None,
        family: str | None = None,
        options: type | None = None,
        default_lambda: float | None = None,
        local_deformation: bool = False,
    ) -> None:
        if self._loading is not None:
            package, version = self._loading.package, self._loading.version
        else:
            package, version = getattr(factory, "__module__", "?").split(".")[0], None
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
        if default_lambda is not None and not (
            isinstance(default_lambda, (int, float)) and 0 <= default_lambda < float("inf")
        ):
            raise ConfigError(f"field '{name}': default_lambda must be a finite number >= 0, got {default_lambda!r}")
        if not isinstance(local_deformation, bool):
            raise ConfigError(f"field '{name}': local_deformation must be True or False, got {local_deformation!r}")
        if options is not None:
            _options_check(name, options)
        new = FieldType(name, factory, label or name, presets, family, package, version, options, default_lambda,
                        local_deformation)  # fmt: skip
        if name in self._conflicts:
            return
        first = self._fields.get(name)
        if first is None:
            self._fields[name] = new
        elif first.package == package and first.factory is factory:
            return  # one package's two entry points for the same registration
        elif not first.plugin:
            self._refuse(
                f"field plugin package '{package}' cannot register '{name}': "
                "it is a built-in field (the built-in is kept)"
            )
        else:
            del self._fields[name]
            if first.package == package:
                self._conflicts[name] = f"field '{name}' is registered twice by package '{package}': fix the package"
            else:
                self._conflicts[name] = (
                    f"field '{name}' is registered by two packages, '{first.package}' and '{package}': uninstall one"
                )
            self._refuse(self._conflicts[name])

    def _refuse(self, line: str) -> None:
        """A taken name: while plugins load, a warning (the plugin's other fields still register);
        from a direct call, an error."""
        if self._loading is None:
            raise NameTaken(line)
        self._problem(line)

    def _load(self) -> None:
        if self._loaded:
            return
        self._loaded = True  # first: a plugin's own reads of the registry must not load it again
        self._loading = Plugin(BUILTIN_PACKAGE, None, None)
        try:
            # Loaded by name, as a plugin's entry point is: the registry depends on no field.
            importlib.import_module(BUILTIN_REGISTRATIONS).register_builtin_fields()
        finally:
            self._loading = None
        try:
            plugins = list(self._list_plugins())
        except Exception as error:  # broken installed metadata: the built-in fields still work
            plugins = []
            self._problem(f"the '{ENTRY_POINT_GROUP}' entry points could not be read: {type(error).__name__}: {error}")
        loaded = set()
        for plugin in plugins:
            entry_point = plugin.entry_point
            if (plugin.package, entry_point.value) in loaded:
                continue  # the same function under two entry-point names
            loaded.add((plugin.package, entry_point.value))
            self._loading = plugin
            try:
                entry_point.load()()
            except KeyboardInterrupt:
                raise
            except BaseException as error:  # a plugin's sys.exit() must not end liquidgs
                self._failed_packages.append(plugin.package)
                what = "exited" if isinstance(error, SystemExit) else "failed to load"
                self._problem(
                    f"field plugin package '{plugin.package}' {what} ({entry_point.name} = {entry_point.value}): "
                    f"{type(error).__name__}: {error}"
                )
            finally:
                self._loading = None

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
    options: type | None = None,
    default_lambda: float | None = None,
    local_deformation: bool = False,
) -> None:
    """Make a field available under `name` (see the module docstring for the contract).

    presets: the preset names the field has sizes for (a dict of sizes by preset name works: its
    keys are used). label: what tables show (default: the name). family: for fields that read
    the built-in FieldOptions sizes ('mlp', 'liquid'); leave it None to size the field by its
    preset alone. options: the dataclass of the field's own settings (--field-options.*), read by
    the factory as config.options. default_lambda: makes the field stochastic, with this noise
    level when --lambda is not given. local_deformation: the deformation has parameters per region
    of space (a grid), so captures train the field with the motion regularisers by default. Raises
    ConfigError for a bad name, preset, family or options, or (outside a plugin's entry point) a
    name already taken.
    """
    REGISTRY.register(name, factory, presets=presets, label=label, family=family, options=options,
                      default_lambda=default_lambda, local_deformation=local_deformation)  # fmt: skip


def field_names() -> tuple[str, ...]:
    """Every usable registered field, in the order tables list them: the built-ins, then plugins."""
    return REGISTRY.names()


def field_type(name: str) -> FieldType:
    """The registered field `name`; ConfigError (one line, the choices) when there is none."""
    return REGISTRY.get(name)


def field_label(name: str) -> str:
    return field_type(name).label


def field_record(name: str) -> dict:
    """What a run folder records of its field's origin: {'name': package, 'version': ...}."""
    kind = field_type(name)
    version = kind.version
    if not kind.plugin:
        from liquidgs import __version__

        version = __version__
    return {"name": kind.package, "version": version}


def check_recorded_field(name: str, record, source) -> None:
    """A stored run's field, with the record of its origin (field_record): when it is not
    registered, one line naming the package it came from."""
    if not isinstance(name, str) or name in field_names() or name in REGISTRY._conflicts:
        return
    if isinstance(record, dict) and isinstance(record.get("name"), str):
        version = record.get("version")
        origin = f"{record['name']} {version}" if version else record["name"]
        raise ConfigError(f"{source}: field '{name}' comes from package {origin}, which is not installed")
