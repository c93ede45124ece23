"""Expanding a spec into runs: one resolved `liquidgs train` configuration and run folder each.

Each run's configuration is built exactly as `liquidgs train` builds it (the preset's
defaults, then the flags), so the folder named by its config hash here is the folder the
training command itself would choose under the experiment's output folder.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

from liquidgs.args import parse_args
from liquidgs.atomic import write_json_atomic
from liquidgs.errors import ConfigError, LiquidGSError
from liquidgs.experiments.spec import ExperimentSpec, Grid
from liquidgs.train.config import TrainConfig, config_hash, preset_config, validate
from liquidgs.train.trainer import RESULTS

MANIFEST = "experiment.json"
MANIFEST_FORMAT = "liquidgs-experiment-1"


@dataclass(frozen=True)
class RunEntry:
    """One run of an experiment. run_dir is relative to the experiment folder."""

    dataset: str
    scene: str
    field: str
    lambda_: float
    seed: int
    preset: str
    data: str
    run_dir: str
    train_args: tuple[str, ...]
    """`liquidgs train` arguments, without --out and --resume (the executor adds those)."""

    @property
    def name(self) -> str:
        noise = f"-l{self.lambda_:g}" if self.field == "sde" else ""
        return f"{self.dataset}-{self.scene}-{self.field}{noise}-s{self.seed}"

    def folder(self, experiment_dir: Path) -> Path:
        return Path(experiment_dir) / self.run_dir

    def is_done(self, experiment_dir: Path) -> bool:
        return (self.folder(experiment_dir) / RESULTS).is_file()


@dataclass(frozen=True)
class Experiment:
    """A spec expanded against a data root: what `experiment run` executes and `report` reads."""

    spec: dict
    data_root: str
    directory: Path
    runs: tuple[RunEntry, ...]


def flag(key: str) -> str:
    """An override key ('eval.every', 'field_options.noise') as the `liquidgs train` flag."""
    return "--" + key.replace("_", "-") if key != "lambda" else "--lambda"


def override_args(overrides: dict) -> list[str]:
    args: list[str] = []
    for key, value in overrides.items():
        if isinstance(value, bool):
            args.append(flag(key) if value else _negated(flag(key)))
        elif isinstance(value, (list, tuple)):
            args += [flag(key), *map(str, value)]
        else:
            args += [flag(key), "None" if value is None else str(value)]
    return args


def _negated(name: str) -> str:
    """tyro's negative boolean flag: --eval.no-quantize-8bit for eval.quantize_8bit."""
    head, _, last = name[2:].rpartition(".")
    return f"--{head + '.' if head else ''}no-{last}"


def resolve_train_config(preset: str, args: list[str], source: str) -> TrainConfig:
    """The configuration `liquidgs train --preset PRESET ARGS` would run, or one error line."""
    data = Path(args[args.index("--data") + 1])
    try:
        cfg = parse_args(TrainConfig, args, prog="liquidgs train", default=preset_config(preset, data))
        validate(cfg)
    except ConfigError as err:
        raise ConfigError(f"{source}: not a valid `liquidgs train` setting ({err})") from None
    return cfg


def _scene_folder(data_root: Path, grid: Grid, scene: str, source: str) -> Path:
    for candidate in (data_root / scene, data_root / grid.dataset / scene):
        if candidate.is_dir():
            return candidate.resolve()
    raise ConfigError(
        f"{source}: 'scenes' names '{scene}', which is neither {data_root / scene} "
        f"nor {data_root / grid.dataset / scene}"
    )


def _check_overrides(grid: Grid, data: Path, source: str) -> None:
    """Each override alone, so the error names the key at fault."""
    for key, value in grid.overrides.items():
        args = ["--data", str(data), *override_args({key: value})]
        resolve_train_config(grid.preset, args, f"{source}: overrides.{key}={value!r}")


def expand(spec: ExperimentSpec, data_root: str | Path, directory: str | Path) -> Experiment:
    """Every run of the spec, in a deterministic order, each with its own folder."""
    data_root = Path(data_root)
    if not data_root.is_dir():
        raise ConfigError(f"{data_root}: --data-root is not a folder")
    runs: list[RunEntry] = []
    for g, grid in enumerate(spec.grids):
        source = f"spec '{spec.name}'" + (f" grids[{g}]" if len(spec.grids) > 1 else "")
        folders = {scene: _scene_folder(data_root, grid, scene, source) for scene in grid.scenes}
        _check_overrides(grid, folders[grid.scenes[0]], source)
        for scene in grid.scenes:
            for field in grid.fields:
                for lam in grid.lambdas if field == "sde" else (0.0,):
                    for seed in grid.seeds:
                        args = ["--data", str(folders[scene]), "--field", field, "--preset", grid.preset]
                        if field == "sde":
                            args += ["--lambda", repr(lam)]
                        args += ["--seed", str(seed), *override_args(grid.overrides)]
                        cfg = resolve_train_config(grid.preset, args, f"{source}: {scene}/{field}")
                        run_dir = Path(grid.dataset) / scene / field / config_hash(cfg)
                        runs.append(
                            RunEntry(grid.dataset, scene, field, lam if field == "sde" else 0.0, seed, grid.preset,
                                     str(folders[scene]), run_dir.as_posix(), tuple(args))  # fmt: skip
                        )
    seen: dict[str, RunEntry] = {}
    for run in runs:
        if run.run_dir in seen:
            raise ConfigError(f"spec '{spec.name}': {run.name} and {seen[run.run_dir].name} are the same run")
        seen[run.run_dir] = run
    return Experiment(spec.to_dict(), str(data_root.resolve()), Path(directory), tuple(runs))


def write_manifest(experiment: Experiment) -> Path:
    return write_json_atomic(
        experiment.directory / MANIFEST,
        {
            "format": MANIFEST_FORMAT,
            "spec": experiment.spec,
            "data_root": experiment.data_root,
            "runs": [{**asdict(r), "train_args": list(r.train_args)} for r in experiment.runs],
        },
    )


def read_manifest(directory: str | Path) -> Experiment:
    """The experiment `liquidgs experiment run` wrote to DIR/experiment.json."""
    directory = Path(directory)
    path = directory / MANIFEST
    if not path.is_file():
        raise LiquidGSError(f"{directory}: not an experiment folder (no {MANIFEST}; run `liquidgs experiment run`)")
    try:
        raw = json.loads(path.read_text())
        if raw.get("format") != MANIFEST_FORMAT:
            raise ValueError(f"format is {raw.get('format')!r}, expected {MANIFEST_FORMAT!r}")
        runs = tuple(RunEntry(**{**r, "train_args": tuple(r["train_args"])}) for r in raw["runs"])
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as err:
        raise LiquidGSError(f"{path}: unreadable experiment manifest ({err})") from None
    return Experiment(raw["spec"], raw["data_root"], directory, runs)
