"""Experiment specs: grids of scenes x fields x noise levels x seeds, built in or read from YAML.

A spec is one or more grids. The flat YAML form is one grid:

    name: my-grid
    preset: tiny
    scenes: [hook, trex]          # folder names under --data-root (or <data-root>/<dataset>/)
    fields: [mlp, cfc, sde]
    lambdas: [0.05]               # sde only; each lambda is its own row
    seeds: [0, 1, 2]
    overrides: {iterations: 600, downscale: 8}   # any `liquidgs train` setting

A spec spanning datasets with different presets lists `grids:`, each a mapping of the same
keys; keys at the top level are defaults every grid inherits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from liquidgs.errors import ConfigError
from liquidgs.train.config import FIELDS, PRESETS

GRID_KEYS = ("dataset", "preset", "scenes", "fields", "lambdas", "seeds", "overrides")
SPEC_KEYS = ("name", "description", "grids", *GRID_KEYS)

DNERF_SCENES = ("hellwarrior", "mutant", "hook", "bouncingballs", "lego", "trex", "standup", "jumpingjacks")
NERFDS_SCENES = ("sieve", "plate", "bell", "press", "cup", "as", "basin")
# The four D-NeRF scenes every developer and CI machine has (../shared/data/dnerf).
SHARED_DNERF_SCENES = ("bouncingballs", "hellwarrior", "lego", "standup")
PAPER_LAMBDA = 0.05
NOISE_STUDY_LAMBDAS = (0.0, 0.05, 0.1, 0.2)


@dataclass(frozen=True)
class Grid:
    dataset: str
    """Label the report groups by (e.g. dnerf, nerfds); also a sub-folder the scenes may live in."""
    preset: str
    scenes: tuple[str, ...]
    fields: tuple[str, ...]
    lambdas: tuple[float, ...] = (PAPER_LAMBDA,)
    seeds: tuple[int, ...] = (0,)
    overrides: dict = field(default_factory=dict)


@dataclass(frozen=True)
class ExperimentSpec:
    name: str
    grids: tuple[Grid, ...]
    description: str = ""

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "description": self.description,
            "grids": [
                {
                    "dataset": g.dataset,
                    "preset": g.preset,
                    "scenes": list(g.scenes),
                    "fields": list(g.fields),
                    "lambdas": list(g.lambdas),
                    "seeds": list(g.seeds),
                    "overrides": dict(g.overrides),
                }
                for g in self.grids
            ],
        }


def _paper_grid(dataset: str, preset: str, scenes, **kw) -> Grid:
    return Grid(dataset=dataset, preset=preset, scenes=tuple(scenes), fields=("mlp", "cfc", "sde"), **kw)


BUILTIN_SPECS: dict[str, ExperimentSpec] = {
    "paper-dnerf": ExperimentSpec(
        "paper-dnerf",
        (_paper_grid("dnerf", "dnerf", DNERF_SCENES, seeds=(0, 1, 2)),),
        "Table I and the cost table: the 8 D-NeRF scenes at full resolution, MLP / CfC / SDE-LNN "
        "(lambda 0.05), 3 seeds, preset dnerf.",
    ),
    "paper-nerfds": ExperimentSpec(
        "paper-nerfds",
        (_paper_grid("nerfds", "nerfds", NERFDS_SCENES, seeds=(0, 1, 2)),),
        "Table II: the 7 NeRF-DS scenes, MLP / CfC / SDE-LNN (lambda 0.05), 3 seeds, preset nerfds.",
    ),
    "noise-study": ExperimentSpec(
        "noise-study",
        (
            Grid("dnerf", "dnerf", DNERF_SCENES, ("sde",), NOISE_STUDY_LAMBDAS),
            Grid("nerfds", "nerfds", NERFDS_SCENES, ("sde",), NOISE_STUDY_LAMBDAS),
        ),
        "Table IV: SDE-LNN at lambda 0, 0.05, 0.1, 0.2 on both datasets (data root holding dnerf/ and nerfds/).",
    ),
    "seeds": ExperimentSpec(
        "seeds",
        (Grid("dnerf", "dnerf", ("hellwarrior",), ("sde",), (0.0,), (0, 1, 2)),),
        "The paper's statistical calibration: hellwarrior, SDE-LNN at lambda 0, 3 seeds.",
    ),
    "mini": ExperimentSpec(
        "mini",
        (
            _paper_grid(
                "dnerf",
                "tiny",
                SHARED_DNERF_SCENES,
                # The tiny schedule cut to 600 iterations so the 12 runs fit in 30 minutes on a
                # 2-core CPU; decay, densification and opacity reset scaled to match.
                overrides={
                    "downscale": 8,
                    "iterations": 600,
                    "optim.means_lr_steps": 600,
                    "optim.field_lr_steps": 600,
                    "densify.stop": 500,
                    "densify.opacity_reset_interval": 300,
                    "eval.start": 300,
                    "eval.every": 300,
                    "eval.fps_frames": 10,
                },
            ),
        ),
        "The paper's tables at CPU scale: the four shared D-NeRF scenes at 1/8 resolution (100x100), "
        "MLP / CfC / SDE-LNN, one seed, the tiny schedule cut to 600 iterations.",
    ),
}


def _as_tuple(value, key: str, source: str, kind) -> tuple:
    values = value if isinstance(value, (list, tuple)) else [value]
    if not values:
        raise ConfigError(f"{source}: '{key}' is empty")
    out = []
    for v in values:
        if kind is float and isinstance(v, (int, float)) and not isinstance(v, bool):
            v = float(v)
        if kind is int and isinstance(v, bool):
            raise ConfigError(f"{source}: '{key}' must hold integers, got {v!r}")
        if not isinstance(v, kind):
            raise ConfigError(f"{source}: '{key}' must hold {kind.__name__} values, got {v!r}")
        out.append(v)
    return tuple(out)


def _grid(raw: dict, source: str) -> Grid:
    missing = [k for k in ("preset", "scenes", "fields") if k not in raw]
    if missing:
        raise ConfigError(f"{source}: missing key '{missing[0]}'")
    preset = raw["preset"]
    if preset not in PRESETS:
        raise ConfigError(f"{source}: 'preset' is '{preset}' (choose from {', '.join(PRESETS)})")
    fields = _as_tuple(raw["fields"], "fields", source, str)
    for name in fields:
        if name not in FIELDS:
            raise ConfigError(f"{source}: 'fields' names unknown field '{name}' (choose from {', '.join(FIELDS)})")
    lambdas = _as_tuple(raw.get("lambdas", PAPER_LAMBDA), "lambdas", source, float)
    for lam in lambdas:
        if not math.isfinite(lam) or lam < 0:
            raise ConfigError(f"{source}: 'lambdas' must be finite and >= 0, got {lam}")
    seeds = _as_tuple(raw.get("seeds", 0), "seeds", source, int)
    if any(s < 0 for s in seeds):
        raise ConfigError(f"{source}: 'seeds' must be >= 0, got {list(seeds)}")
    overrides = raw.get("overrides") or {}
    if not isinstance(overrides, dict):
        raise ConfigError(f"{source}: 'overrides' must be a mapping of `liquidgs train` settings")
    return Grid(
        dataset=str(raw.get("dataset", preset)),
        preset=preset,
        scenes=_as_tuple(raw["scenes"], "scenes", source, str),
        fields=fields,
        lambdas=tuple(dict.fromkeys(lambdas)),
        seeds=tuple(dict.fromkeys(seeds)),
        overrides=_flatten(overrides),
    )


def _flatten(overrides: dict, prefix: str = "") -> dict:
    """{'eval': {'every': 100}} -> {'eval.every': 100}: one key per `liquidgs train` flag."""
    flat = {}
    for key, value in overrides.items():
        name = f"{prefix}{str(key).replace('-', '_')}"
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat


def spec_from_dict(raw, source: str) -> ExperimentSpec:
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: an experiment spec is a mapping with keys {', '.join(SPEC_KEYS)}")
    unknown = [k for k in raw if k not in SPEC_KEYS]
    if unknown:
        raise ConfigError(f"{source}: unknown key '{unknown[0]}' (known: {', '.join(SPEC_KEYS)})")
    name = raw.get("name")
    if not isinstance(name, str) or not name or "/" in name or name.startswith("."):
        raise ConfigError(f"{source}: 'name' must be a non-empty folder-safe string, got {name!r}")
    defaults = {k: raw[k] for k in GRID_KEYS if k in raw}
    if "grids" in raw:
        if not isinstance(raw["grids"], list) or not raw["grids"]:
            raise ConfigError(f"{source}: 'grids' must be a non-empty list of grid mappings")
        grids = []
        for i, grid_raw in enumerate(raw["grids"]):
            where = f"{source}: grids[{i}]"
            if not isinstance(grid_raw, dict):
                raise ConfigError(f"{where}: a grid is a mapping")
            unknown = [k for k in grid_raw if k not in GRID_KEYS]
            if unknown:
                raise ConfigError(f"{where}: unknown key '{unknown[0]}' (known: {', '.join(GRID_KEYS)})")
            grids.append(_grid({**defaults, **grid_raw}, where))
    else:
        grids = [_grid(defaults, source)]
    return ExperimentSpec(name=name, grids=tuple(grids), description=str(raw.get("description", "")))


def load_spec(name_or_path: str | Path) -> ExperimentSpec:
    """A built-in spec by name, or a YAML file."""
    key = str(name_or_path)
    if key in BUILTIN_SPECS:
        return BUILTIN_SPECS[key]
    path = Path(key)
    if not path.is_file():
        raise ConfigError(
            f"{key}: no such spec file, and not a built-in spec (built-in: {', '.join(BUILTIN_SPECS)})"
        )
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise ConfigError(f"{path}: unreadable spec ({first})") from None
    return spec_from_dict(raw, str(path))
