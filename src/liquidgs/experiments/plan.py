"""Expanding a spec into runs: one resolved training configuration and run folder each.

Each run's configuration is built as `liquidgs train` builds it (the preset's defaults, then
the settings on top), as a TrainConfig; the executor hands it to the run as a file
(`liquidgs train --config FILE`), so the folder named by its config hash here is the folder
the training command itself would choose under the experiment's output folder.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

from liquidgs import settings
from liquidgs.atomic import write_json_atomic
from liquidgs.data import DataConfig, generate_synthetic
from liquidgs.errors import ConfigError, LiquidGSError
from liquidgs.experiments.spec import ExperimentSpec, Grid, SyntheticScene, Variant
from liquidgs.train.config import TrainConfig, differing_settings, from_dict, preset_config, run_folder
from liquidgs.train.run_folder import RESULTS

MANIFEST = "experiment.json"
MANIFEST_FORMAT = "liquidgs-experiment-2"
MANIFEST_FORMATS = ("liquidgs-experiment-1", MANIFEST_FORMAT)
"""Format 1 listed each run's `liquidgs train` arguments; it is read for reports (its runs have
no config: `experiment run` expands the spec again and writes format 2)."""
SCENES = "scenes"
"""Sub-folder of an experiment holding the built-in scenes it generated."""


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
    config: dict | None
    """The run's resolved TrainConfig as plain values (no out / resume: the executor adds those);
    None in a manifest of format 1."""
    variant: str = ""
    """The spec's name for this field configuration ('' when fields x lambdas made it)."""
    perturb: str = ""
    """The perturbation ('time_jitter', ...) this run trains under; '' for the clean run."""
    strength: float = 0.0

    @property
    def label(self) -> str:
        """The field configuration, as the report names it."""
        return Variant(self.variant, self.field, self.lambda_).label

    @property
    def name(self) -> str:
        condition = f"-{self.perturb.replace('_', '-')}{self.strength:g}" if self.perturb else ""
        return f"{self.dataset}-{self.scene}-{self.label}{condition}-s{self.seed}"

    def folder(self, experiment_dir: Path) -> Path:
        return Path(experiment_dir) / self.run_dir

    def is_done(self, experiment_dir: Path) -> bool:
        return (self.folder(experiment_dir) / RESULTS).is_file()

    @property
    def trained_as_cfc(self) -> bool:
        """An SDE row at lambda 0 that the plan trains as the CfC run (plan.cfc_twin)."""
        return self.field == "sde" and self.config is not None and self.config.get("field") == "cfc"

    @property
    def trained_field(self) -> str:
        """The field the run folder's configuration trains."""
        return "cfc" if self.trained_as_cfc else self.field

    def train_config(self) -> TrainConfig:
        if self.config is None:
            raise LiquidGSError(
                f"{self.name}: listed by an older experiment manifest; run `liquidgs experiment run` again"
            )
        return from_dict(self.config, f"run {self.name}")


@dataclass(frozen=True)
class Experiment:
    """A spec expanded against a data root: what `experiment run` executes and `report` reads."""

    spec: dict
    data_root: str
    directory: Path
    runs: tuple[RunEntry, ...]
    synthetic_scenes: tuple[tuple[SyntheticScene, Path], ...] = ()
    """Built-in scenes the spec names and the folders `experiment run` generates them in."""


def run_config(preset: str, data: Path, run_settings: dict, source: str) -> TrainConfig:
    """The configuration `liquidgs train --preset PRESET --data DATA` with these settings would
    run (settings by dotted key or flag name: 'eval.every', 'downscale'), or one error line."""
    try:
        keyed = settings.setting_keys(TrainConfig, run_settings, source)
        return settings.with_settings(preset_config(preset, DataConfig(path=data)), keyed, source)
    except ConfigError as err:
        raise ConfigError(f"{source}: not a valid `liquidgs train` setting ({err})") from None


def synthetic_folder(directory: Path, scene: SyntheticScene) -> Path:
    """Where an experiment keeps a generated scene (its D-NeRF layout is what runs train on)."""
    return Path(directory).resolve() / SCENES / scene.label


def generate_scenes(experiment: Experiment) -> list[Path]:
    """Render the built-in scenes the experiment trains on, once; returns those made now.

    Each is rendered into a temporary folder renamed into place, so an interrupted generation
    never leaves a half-written scene that a later run would train on.
    """
    made = []
    for scene, folder in experiment.synthetic_scenes:
        if folder.is_dir():
            continue
        tmp = folder.with_name(f".{folder.name}.tmp-{os.getpid()}")
        shutil.rmtree(tmp, ignore_errors=True)
        generate_synthetic(scene.name, tmp, size=scene.size)
        os.replace(tmp, folder)
        made.append(folder)
    return made


def _scene_folder(data_root: Path, directory: Path, grid: Grid, scene: str, source: str) -> Path:
    synthetic = SyntheticScene.parse(scene, source)
    if synthetic is not None:
        return synthetic_folder(directory, synthetic) / "dnerf"
    for candidate in (data_root / scene, data_root / grid.dataset / scene):
        if candidate.is_dir():
            return candidate.resolve()
    raise ConfigError(
        f"{source}: 'scenes' names '{scene}', which is neither {data_root / scene} "
        f"nor {data_root / grid.dataset / scene}"
    )


def _field_settings(variant: Variant) -> dict:
    return {"field": variant.field, **({"lambda_": variant.lambda_} if variant.field == "sde" else {})}


# The settings a grid's own keys (or the experiment) set for each run: an override may not set
# them, or a row would be labelled with one value and trained with another.
AXIS_SETTINGS = {
    "data.path": "'scenes'",
    "field": "'fields' or a variant's 'field'",
    "lambda_": "'lambdas' or a variant's 'lambda'",
    "seed": "'seeds'",
    "preset": "'preset'",
    "out": "the experiment (--out)",
    "resume": "the experiment (runs resume by themselves)",
}


def _check_axes(grid: Grid, where: str, overrides: dict, source: str) -> None:
    """Refuse an override of a setting that a grid axis owns (AXIS_SETTINGS, and each perturbation
    the grid's 'perturb' sweeps)."""
    owned = {**AXIS_SETTINGS, **{f"perturb.{kind}": f"'perturb.{kind}'" for kind, _ in grid.perturb}}
    for key in overrides:
        try:
            dotted = next(iter(settings.setting_keys(TrainConfig, {key: None})))
        except ConfigError:
            continue  # an unknown setting: named by the checks that follow
        if dotted in owned:
            raise ConfigError(f"{source}: {where}.{key} sets what the grid's {owned[dotted]} set for each run; "
                              f"give it there")  # fmt: skip


def cfc_twin(preset: str, data: Path, run_settings: dict, source: str) -> TrainConfig | None:
    """The CfC run an SDE row at lambda 0 is, or None when a setting makes it differ.

    At lambda 0 the SDE field is the CfC bit for bit: the same module, and no noise is drawn
    (tests/test_fields_cfc.py::test_noise_switches_off_exactly). So the plan trains it once, as the
    CfC run with the same settings: one folder for both rows, in this experiment and in any sibling
    (noise-study's lambda 0 row is paper-dnerf's and paper-nerfds' CfC runs). A setting only the sde
    field takes (another noise kind, a lambda schedule, adaptive lambda) keeps it an sde run: the CfC
    refuses it (FieldConfig's own rule), and with it the two are not the same module.
    """
    if run_settings.get("field") != "sde" or run_settings.get("lambda_") != 0:
        return None
    as_cfc = {key: value for key, value in run_settings.items() if key != "lambda_"} | {"field": "cfc"}
    try:
        return run_config(preset, data, as_cfc, source)
    except ConfigError:
        return None


def _check_overrides(grid: Grid, data: Path, source: str) -> None:
    """Every override mapping with the field it is for. When one fails, the error names the
    first key that fails alone; settings that only fail together are named as their mapping."""
    variants = grid.field_variants()
    checks = [("overrides", variants[0], grid.overrides)]
    checks += [(f"variants.{v.label}.overrides", v, v.overrides) for v in variants]
    for where, _, overrides in checks:
        _check_axes(grid, where, overrides, source)
    for where, variant, overrides in checks:
        base = _field_settings(variant)
        try:
            run_config(grid.preset, data, {**base, **overrides}, "")
            continue
        except ConfigError:
            pass
        for key, value in overrides.items():
            run_config(grid.preset, data, {**base, key: value}, f"{source}: {where}.{key}={value!r}")
        run_config(grid.preset, data, {**base, **overrides}, f"{source}: {where}")


def expand(spec: ExperimentSpec, data_root: str | Path, directory: str | Path) -> Experiment:
    """Every run of the spec, in a deterministic order, each with its own folder."""
    data_root = Path(data_root)
    if not data_root.is_dir():
        raise ConfigError(f"{data_root}: --data-root is not a folder")
    runs: list[RunEntry] = []
    grid_of: list[str] = []  # the grid each run comes from, as errors name it
    synthetic: dict[SyntheticScene, Path] = {}
    for g, grid in enumerate(spec.grids):
        source = f"spec '{spec.name}'" + (f" grids[{g}]" if len(spec.grids) > 1 else "")
        folders = {scene: _scene_folder(data_root, Path(directory), grid, scene, source) for scene in grid.scenes}
        for scene in grid.scenes:
            parsed = SyntheticScene.parse(scene, source)
            if parsed is not None:
                synthetic[parsed] = folders[scene].parent
        _check_overrides(grid, folders[grid.scenes[0]], source)
        for scene in grid.scenes:
            parsed = SyntheticScene.parse(scene, source)
            label = parsed.label if parsed is not None else scene
            for variant in grid.field_variants():
                for perturb, strength in grid.conditions():
                    condition = {f"perturb.{perturb}": _strength_value(perturb, strength)} if perturb else {}
                    overrides = {**grid.overrides, **variant.overrides, **condition}
                    for seed in grid.seeds:
                        run_settings = {**_field_settings(variant), "seed": seed, **overrides}
                        where = f"{source}: {scene}/{variant.label}"
                        cfg = run_config(grid.preset, folders[scene], run_settings, where)
                        cfg = cfc_twin(grid.preset, folders[scene], run_settings, where) or cfg
                        parent = Path(directory) / grid.dataset / label / cfg.field
                        run_dir = run_folder(cfg, parent).relative_to(Path(directory))
                        runs.append(
                            RunEntry(grid.dataset, label, variant.field, variant.lambda_, seed, grid.preset,
                                     str(folders[scene]), run_dir.as_posix(), settings.to_dict(cfg), variant.name,
                                     perturb, strength)  # fmt: skip
                        )
                        grid_of.append(source)
    seen: dict[str, RunEntry] = {}
    named: dict[str, tuple[RunEntry, str]] = {}
    for run, grid in zip(runs, grid_of):
        twin = seen.get(run.run_dir)
        if twin is not None and not (run.trained_as_cfc or twin.trained_as_cfc):
            raise ConfigError(f"spec '{spec.name}': {run.name} and {twin.name} are the same run")
        seen.setdefault(run.run_dir, run)
        # A run's name labels its log, its config file and its report row: one name, one run.
        if run.name in named:
            other, other_grid = named[run.name]
            changed = ", ".join(differing_settings(other.train_config(), run.train_config()))
            grids = other_grid if other_grid == grid else f"{other_grid} and {grid.rpartition(' ')[2]}"
            raise ConfigError(
                f"{grids}: two runs are named {run.name} but differ in {changed}; give the grids different "
                "'dataset' labels, or name the field configurations as variants"
            )
        named[run.name] = (run, grid)
    return Experiment(
        spec.to_dict(), str(data_root.resolve()), Path(directory), tuple(runs), tuple(synthetic.items())
    )


def _strength_value(perturb: str, strength: float) -> float | int:
    """The `--perturb.*` value of a strength (keep_frames counts frames)."""
    return int(strength) if perturb == "keep_frames" else strength


def distinct_runs(runs) -> list[RunEntry]:
    """One entry per run folder: an SDE row at lambda 0 and the CfC row it shares a folder with are
    trained once."""
    seen: set[str] = set()
    out = []
    for run in runs:
        if run.run_dir not in seen:
            seen.add(run.run_dir)
            out.append(run)
    return out


def write_manifest(experiment: Experiment) -> Path:
    return write_json_atomic(
        experiment.directory / MANIFEST,
        {
            "format": MANIFEST_FORMAT,
            "spec": experiment.spec,
            "data_root": experiment.data_root,
            "runs": [asdict(r) for r in experiment.runs],
        },
    )


def check_same_experiment(experiment: Experiment) -> bool:
    """Refuse a folder that holds another spec's experiment (its experiment.json would be replaced
    and its runs would leave its report). Returns whether the folder holds this spec as it was
    last run (False: a new folder, or this spec's name with other grids)."""
    if not (experiment.directory / MANIFEST).is_file():
        return False
    existing = read_manifest(experiment.directory)
    name = existing.spec.get("name") if isinstance(existing.spec, dict) else None
    if name != experiment.spec["name"]:
        raise ConfigError(
            f"{experiment.directory}: holds the experiment '{name}', not '{experiment.spec['name']}'; "
            "choose another --out"
        )
    return json.loads(json.dumps(experiment.spec)) == existing.spec


def read_manifest(directory: str | Path) -> Experiment:
    """The experiment `liquidgs experiment run` wrote to DIR/experiment.json."""
    directory = Path(directory)
    path = directory / MANIFEST
    if not path.is_file():
        raise LiquidGSError(f"{directory}: not an experiment folder (no {MANIFEST}; run `liquidgs experiment run`)")
    try:
        raw = json.loads(path.read_text())
        if raw.get("format") not in MANIFEST_FORMATS:
            raise ValueError(f"format is {raw.get('format')!r}, expected {MANIFEST_FORMAT!r}")
        runs = tuple(_manifest_run(r) for r in raw["runs"])
    except (ValueError, KeyError, TypeError, UnicodeDecodeError) as err:
        raise LiquidGSError(f"{path}: unreadable experiment manifest ({err})") from None
    return Experiment(raw["spec"], raw["data_root"], directory, runs)


def _manifest_run(raw: dict) -> RunEntry:
    if "train_args" in raw:  # format 1
        raw = {k: v for k, v in raw.items() if k != "train_args"} | {"config": None}
    return RunEntry(**raw)
