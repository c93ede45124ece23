"""The field registry in tests: a mocked entry-point table (no package is installed).

Tests read liquidgs' own "liquidgs.fields" entry points from pyproject.toml rather than from the
installed metadata (an editable install made before an entry point was added lacks it), plus
whatever plugins a test writes: a plugin is a module written into a folder on sys.path, listed
under a made-up package name and version.
"""

from __future__ import annotations

import sys
import textwrap
from importlib.metadata import EntryPoint
from pathlib import Path

import tomllib

from liquidgs.fields import registry
from liquidgs.fields.registry import Plugin

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"


def own_entry_points() -> list[Plugin]:
    """liquidgs' own entry points as pyproject.toml declares them (hexplane)."""
    declared = tomllib.loads(PYPROJECT.read_text())["project"]["entry-points"][registry.ENTRY_POINT_GROUP]
    return [
        Plugin("liquidgs", None, EntryPoint(name, value, registry.ENTRY_POINT_GROUP))
        for name, value in sorted(declared.items())
    ]


def use_registry(monkeypatch, plugins: list[Plugin] = ()) -> registry.FieldRegistry:
    """A fresh registry for one test: liquidgs' own entry points, then `plugins`."""
    fresh = registry.FieldRegistry(lambda: own_entry_points() + list(plugins))
    monkeypatch.setattr(registry, "REGISTRY", fresh)
    return fresh


def write_plugin(folder: Path, module: str, source: str, monkeypatch) -> EntryPoint:
    """A plugin module `module` in `folder` (put on sys.path), its entry point `module:register`."""
    (folder / f"{module}.py").write_text(textwrap.dedent(source))
    monkeypatch.syspath_prepend(str(folder))
    monkeypatch.delitem(sys.modules, module, raising=False)
    return EntryPoint(module, f"{module}:register", registry.ENTRY_POINT_GROUP)


def plugin(package: str, entry_point: EntryPoint, version: str | None = "0.2") -> Plugin:
    """An installed package's entry point, as the registry lists it."""
    return Plugin(package, version, entry_point)
