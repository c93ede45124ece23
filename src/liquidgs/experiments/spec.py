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

Stress tests add two keys. `variants:` names field configurations, in place of fields x lambdas:

    variants:
      cfc: {field: cfc}
      sde-annealed: {field: sde, lambda: 0.1, overrides: {field_options.lambda_schedule: linear,
                                                          field_options.lambda_decay_steps: 300}}

`perturb:` maps a `--perturb.*` setting to the strengths to train at; strength 0 is the clean
run, trained once and shared by every perturbation:

    perturb: {time_jitter: [0, 0.02, 0.05], time_split: [0, 0.75]}

A scene named `synthetic:NAME:SIZE` (e.g. synthetic:puppet:64) is the built-in synthetic
scene NAME rendered at SIZE px, generated once under the experiment folder.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

from liquidgs import settings
from liquidgs.data import SYNTHETIC_SCENES, PerturbConfig
from liquidgs.errors import ConfigError
from liquidgs.fields.config import PAPER_LAMBDA, PRESET_NAMES, FieldConfig, default_lambda
from liquidgs.fields.registry import field_type

GRID_KEYS = ("dataset", "preset", "scenes", "fields", "lambdas", "variants", "perturb", "seeds", "overrides")
VARIANT_KEYS = ("field", "lambda", "overrides")
PERTURBATIONS = tuple(f.name for f in dataclasses.fields(PerturbConfig))
SYNTHETIC_PREFIX = "synthetic:"
SPEC_KEYS = ("name", "description", "grids", *GRID_KEYS)

DNERF_SCENES = ("hellwarrior", "mutant", "hook", "bouncingballs", "lego", "trex", "standup", "jumpingjacks")
NERFDS_SCENES = ("sieve", "plate", "bell", "press", "cup", "as", "basin")
# The four D-NeRF scenes every developer and CI machine has (../shared/data/dnerf).
SHARED_DNERF_SCENES = ("bouncingballs", "hellwarrior", "lego", "standup")
NOISE_STUDY_LAMBDAS = (0.0, 0.05, 0.1, 0.2)


@dataclass(frozen=True)
class Variant:
    """A named field configuration: a field, its noise level and `liquidgs train` overrides."""

    name: str
    """'' for the rows fields x lambdas describe, which keep their usual names (e.g. sde-l0.05)."""
    field: str
    lambda_: float = 0.0
    overrides: dict = field(default_factory=dict)

    @property
    def label(self) -> str:
        if self.name:
            return self.name
        return f"{self.field}-l{self.lambda_:g}" if self.field == "sde" else self.field


@dataclass(frozen=True)
class SyntheticScene:
    """A built-in synthetic scene a spec names as synthetic:NAME:SIZE."""

    name: str
    size: int

    @property
    def label(self) -> str:
        return f"{self.name}-{self.size}px"

    @classmethod
    def parse(cls, scene: str, source: str) -> SyntheticScene | None:
        """The synthetic scene `scene` names, or None when it names a folder."""
        if not scene.startswith(SYNTHETIC_PREFIX):
            return None
        name, _, size = scene[len(SYNTHETIC_PREFIX) :].partition(":")
        if name not in SYNTHETIC_SCENES or not size.isdigit() or not 8 <= int(size) <= 1024:
            raise ConfigError(
                f"{source}: scene '{scene}' must be synthetic:NAME:SIZE with NAME one of "
                f"{', '.join(SYNTHETIC_SCENES)} and SIZE 8-1024 px"
            )
        return cls(name, int(size))


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
    variants: tuple[Variant, ...] = ()
    """Named field configurations; when empty, fields x lambdas (sde only) make the rows."""
    perturb: tuple[tuple[str, tuple[float, ...]], ...] = ()
    """(perturbation, strengths) pairs; the clean run (strength 0) is always trained."""

    def field_variants(self) -> tuple[Variant, ...]:
        if self.variants:
            return self.variants
        return tuple(
            Variant("", name, lam if name == "sde" else 0.0)
            for name in self.fields
            for lam in (self.lambdas if name == "sde" else (0.0,))
        )

    def run_count(self) -> int:
        return len(self.scenes) * len(self.field_variants()) * len(self.conditions()) * len(self.seeds)

    def conditions(self) -> list[tuple[str, float]]:
        """The clean condition ('', 0), then every (perturbation, non-zero strength)."""
        return [("", 0.0)] + [(kind, s) for kind, strengths in self.perturb for s in strengths if s != 0]


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
                    "variants": {
                        v.label: {"field": v.field, "lambda": v.lambda_, "overrides": dict(v.overrides)}
                        for v in g.variants
                    },
                    "perturb": {kind: list(strengths) for kind, strengths in g.perturb},
                }
                for g in self.grids
            ],
        }


# The tiny schedule cut to 600 iterations so the 12 runs of `mini` fit in 30 minutes on a 2-core
# CPU; decay, densification and opacity reset scaled to match.
MINI_SCHEDULE = {
    "iterations": 600,
    "optim.means_lr_steps": 600,
    "optim.field_lr_steps": 600,
    "densify.stop": 500,
    "densify.opacity_reset_interval": 300,
    "eval.start": 300,
    "eval.every": 300,
    "eval.fps_frames": 10,
}
MARGIN_SEEDS = (0, 1, 2)
MARGIN_SYNTHETIC_SCENES = ("synthetic:puppet:64", "synthetic:spinner:64")


def _paper_grid(dataset: str, preset: str, scenes, **kw) -> Grid:
    return Grid(dataset=dataset, preset=preset, scenes=tuple(scenes), fields=("mlp", "cfc", "sde"), **kw)


# The paper inherits its evaluation from the public D-3DGS code, whose metrics call LPIPS-VGG on
# [0,1] images without normalize=True (../shared/specs/d3dgs.md): the paper's specs score LPIPS so.
# It trains on the datasets' cameras and images as given, with the photometric loss alone: no camera
# refinement, no motion regularisers, no exposure compensation, and neither the optical-flow loss nor
# the static/dynamic split (on for a capture with flow), which liquidgs would otherwise switch on for
# NeRF-DS (a capture); off, the runs' identities are those of before they existed.
PAPER_PROTOCOL = {"eval.lpips_normalize": False, "cameras.refine": "off", "motion.apply": "off",
                  "exposure.apply": "off", "flow.weight": 0.0, "split.apply": False}  # fmt: skip
PAPER_SEEDS = (0, 1, 2)
_PAPER_TABLES = {
    "dnerf": ("dnerf", DNERF_SCENES, "Table I and the cost table: the 8 D-NeRF scenes at full resolution"),
    "nerfds": ("nerfds", NERFDS_SCENES, "Table II: the 7 NeRF-DS scenes"),
}
_PROTOCOL_TEXT = (
    "LPIPS on [0,1] inputs as the D-3DGS metrics code (not normalised), cameras as given (no refinement), "
    "no motion regularisers"
)


def _paper_table_specs() -> dict[str, ExperimentSpec]:
    """paper-<dataset>: single runs (seed 0) as the paper's Tables I and II are, the same runs as
    noise-study's lambda 0.05 row; paper-<dataset>-3seeds: seeds 0-2, for the spread."""
    specs = {}
    for dataset, (preset, scenes, what) in _PAPER_TABLES.items():
        variants = (("", (0,), "seed 0 (single runs, as printed)"), ("-3seeds", PAPER_SEEDS, "seeds 0-2"))
        for suffix, seeds, runs in variants:
            name = f"paper-{dataset}{suffix}"
            specs[name] = ExperimentSpec(
                name,
                (_paper_grid(dataset, preset, scenes, seeds=seeds, overrides=dict(PAPER_PROTOCOL)),),
                f"{what}, MLP / CfC / SDE-LNN (lambda 0.05), {runs}, preset {preset}, {_PROTOCOL_TEXT}.",
            )
    return specs


BUILTIN_SPECS: dict[str, ExperimentSpec] = {
    **_paper_table_specs(),
    "noise-study": ExperimentSpec(
        "noise-study",
        (
            Grid("dnerf", "dnerf", DNERF_SCENES, ("sde",), NOISE_STUDY_LAMBDAS, overrides=dict(PAPER_PROTOCOL)),
            Grid("nerfds", "nerfds", NERFDS_SCENES, ("sde",), NOISE_STUDY_LAMBDAS, overrides=dict(PAPER_PROTOCOL)),
        ),
        "Table IV: SDE-LNN at lambda 0, 0.05, 0.1, 0.2 on both datasets (data root holding dnerf/ and nerfds/), "
        f"seed 0, {_PROTOCOL_TEXT}; its lambda 0.05 runs are paper-dnerf's and paper-nerfds' SDE-LNN runs.",
    ),
    "seeds": ExperimentSpec(
        "seeds",
        (Grid("dnerf", "dnerf", ("hellwarrior",), ("sde",), (0.0,), PAPER_SEEDS, overrides=dict(PAPER_PROTOCOL)),),
        f"The paper's statistical calibration: hellwarrior, SDE-LNN at lambda 0, 3 seeds, {_PROTOCOL_TEXT}.",
    ),
    "mini": ExperimentSpec(
        "mini",
        (Grid("dnerf", "tiny", SHARED_DNERF_SCENES, ("mlp", "cfc", "sde", "hexplane"),
              overrides={"downscale": 8, **MINI_SCHEDULE}),),  # fmt: skip
        "The paper's tables at CPU scale, with HexPlane (4DGaussians' field) beside the paper's three: the four "
        "shared D-NeRF scenes at 1/8 resolution (100x100), MLP / CfC / SDE-LNN / HexPlane, one seed, the tiny "
        "schedule cut to 600 iterations.",
    ),
}


BUILTIN_SPECS["margins"] = ExperimentSpec(
    "margins",
    (
        Grid("dnerf", "tiny", SHARED_DNERF_SCENES, ("static", "mlp", "cfc"), seeds=MARGIN_SEEDS,
             overrides={"downscale": 8, **MINI_SCHEDULE}),
        Grid("synthetic", "tiny", MARGIN_SYNTHETIC_SCENES, ("static", "mlp", "cfc"), seeds=MARGIN_SEEDS,
             overrides=dict(MINI_SCHEDULE)),
    ),  # fmt: skip
    "Does the tiny preset learn motion? The static model, the MLP and the CfC, 3 seeds, with the schedule of "
    "mini (tiny cut to 600 iterations, decay, densification and opacity reset scaled) on the four shared "
    "D-NeRF scenes at 1/8 (100x100) and on the built-in puppet and spinner scenes at 64 px (generated under "
    "the experiment folder): 54 runs. The report gives each field's margin over the static model, over the "
    "whole test images and over the moving pixels (built-in scenes) or the foreground (D-NeRF).",
)


FAMILIES = ("static", "mlp", "cfc", "sde", "hexplane")
BUILTIN_SPECS["families"] = ExperimentSpec(
    "families",
    tuple(dataclasses.replace(grid, fields=FAMILIES) for grid in BUILTIN_SPECS["margins"].grids),
    "Deformation families under one recipe: the static model, the D-3DGS MLP, the CfC, SDE-LNN (lambda 0.05) "
    "and HexPlane (4DGaussians' field), each with its tiny preset, on margins' scenes, schedule and seeds (the "
    "four shared D-NeRF scenes at 1/8 and the built-in puppet and spinner at 64 px, mini's 600 iterations, 3 "
    "seeds): 90 runs; its 36 D-NeRF runs of margins' fields are margins' (shared when both live under one "
    "folder; a built-in scene is generated in each experiment's folder, so those runs are its own). The report "
    "gives each field's margin over the static model, whole image and moving pixels or foreground, and the cost "
    "table.",
)


def _stress_variants(lambdas: tuple[float, ...], variant_lambda: float, decay_steps: int, mlp: bool) -> tuple:
    """The deterministic cells, sde at each lambda, and the smarter noise variants at `variant_lambda`."""
    return (
        *((Variant("mlp", "mlp"),) if mlp else ()),
        Variant("cfc", "cfc"),
        *(Variant(f"sde-l{lam:g}", "sde", lam) for lam in lambdas),
        Variant("sde-annealed", "sde", variant_lambda, {
            "field_options.lambda_schedule": "linear", "field_options.lambda_decay_steps": decay_steps}),
        *((Variant("sde-adaptive", "sde", variant_lambda, {"field_options.adaptive_lambda": True}),) if mlp else ()),
        Variant("sde-ou", "sde", variant_lambda, {"field_options.noise": "ou"}),
    )  # fmt: skip


STRESS_PERTURBATIONS = (
    ("time_jitter", (0.0, 0.01, 0.03, 0.1)),
    ("pose_rot_deg", (0.0, 0.5, 1.0, 2.0)),
    ("pose_trans", (0.0, 0.005, 0.01, 0.02)),
    ("keep_frames", (0.0, 40.0, 20.0, 10.0)),
    ("time_split", (0.0, 0.5, 0.75)),
    ("image_noise", (0.0, 0.02, 0.05, 0.1)),
)
STRESS_MINI_ITERATIONS = 300
STRESS_MINI_OVERRIDES = {
    "iterations": STRESS_MINI_ITERATIONS,
    "warmup": 50,
    "optim.means_lr_steps": STRESS_MINI_ITERATIONS,
    "optim.field_lr_steps": STRESS_MINI_ITERATIONS,
    "densify.start": 50,
    "densify.stop": 250,
    "eval.fps_frames": 10,
}
STRESS_MINI_GRID = dict(
    preset="tiny",
    variants=_stress_variants((0.1,), 0.1, 250, mlp=False),
    perturb=(("time_jitter", (0.0, 0.03, 0.1)), ("time_split", (0.0, 0.75))),
    seeds=(0, 1),
    fields=("cfc", "sde"),
)
BUILTIN_SPECS["stress"] = ExperimentSpec(
    "stress",
    (
        Grid("dnerf", "dnerf", SHARED_DNERF_SCENES, ("mlp", "cfc", "sde"), seeds=(0, 1, 2),
             variants=_stress_variants(NOISE_STUDY_LAMBDAS[1:], 0.1, 20_000, mlp=True),
             perturb=STRESS_PERTURBATIONS),
    ),  # fmt: skip
    "When does the noise help? MLP, CfC, SDE-LNN at lambda 0.05 / 0.1 / 0.2, and SDE-LNN (lambda 0.1) annealed "
    "to 0 by step 20k, input-dependent, and with OU hidden-state noise, each under every perturbation of the "
    "training split (time jitter, camera rotation and translation, fewer frames, extrapolation in time, image "
    "noise) at 3-4 strengths, 0 included; the four shared D-NeRF scenes at full resolution, preset dnerf, 3 "
    "seeds: 1,728 runs of 40,000 iterations, a job for a GPU cluster.",
)
BUILTIN_SPECS["stress-mini"] = ExperimentSpec(
    "stress-mini",
    (
        Grid("synthetic", scenes=("synthetic:puppet:64",), overrides=STRESS_MINI_OVERRIDES, **STRESS_MINI_GRID),
        Grid("dnerf", scenes=("hellwarrior",), overrides={**STRESS_MINI_OVERRIDES, "downscale": 8},
             **STRESS_MINI_GRID),
    ),  # fmt: skip
    "The stress test at CPU scale: CfC, SDE-LNN (lambda 0.1), and SDE-LNN annealed to 0 by step 250 and with OU "
    "hidden-state noise, under time jitter (0.03, 0.1) and extrapolation in time (train t < 0.75), 2 seeds, on "
    "the built-in puppet scene at 64 px (generated under the experiment folder) and the shared D-NeRF "
    "hellwarrior at 1/8 (100x100): 64 runs of 300 iterations of the tiny schedule (warm-up 50, decay and "
    "densification scaled to match)."
)


def _folder_safe(value) -> bool:
    """A name that is one folder under the experiment's: no '/', not '.', '..' or hidden."""
    return isinstance(value, str) and bool(value) and not {"/", "\\"} & set(value) and not value.startswith(".")


def _as_tuple(value, key: str, source: str, kind) -> tuple:
    """One value or a list of them, each checked as a setting of type `kind` is (settings.matches)."""
    values = value if isinstance(value, (list, tuple)) else [value]
    if not values:
        raise ConfigError(f"{source}: '{key}' is empty")
    for v in values:
        if not settings.matches(v, kind):
            kind_text = settings.describe(kind).split(" ", 1)[1]
            raise ConfigError(f"{source}: '{key}' must hold {kind_text} values, got {v!r}")
    return tuple(kind(v) for v in values)


def _check_field(name, source: str, key: str) -> None:
    try:
        field_type(name)
    except ConfigError as error:  # unknown, or registered by two packages
        raise ConfigError(f"{source}: '{key}': {error}") from None


def _check_lambda(lam: float, source: str, key: str) -> None:
    """The sde field's own rule for lambda (FieldConfig's)."""
    try:
        FieldConfig(name="sde", lambda_=lam)
    except ConfigError as err:
        raise ConfigError(f"{source}: '{key}': {err}") from None


def _overrides(raw, source: str, key: str = "overrides") -> dict:
    overrides = raw or {}
    if not isinstance(overrides, dict):
        raise ConfigError(f"{source}: '{key}' must be a mapping of `liquidgs train` settings")
    return _flatten(overrides)


def _variants(raw, source: str) -> tuple[Variant, ...]:
    if not isinstance(raw, dict) or not raw:
        raise ConfigError(f"{source}: 'variants' must be a non-empty mapping of name -> {{field, lambda, overrides}}")
    variants = []
    for name, body in raw.items():
        where = f"variants.{name}"
        if not _folder_safe(name):
            raise ConfigError(f"{source}: variant names must be non-empty folder-safe strings, got {name!r}")
        if not isinstance(body, dict) or "field" not in body:
            raise ConfigError(f"{source}: '{where}' must be a mapping with a 'field'")
        unknown = [k for k in body if k not in VARIANT_KEYS]
        if unknown:
            raise ConfigError(f"{source}: '{where}' has unknown key '{unknown[0]}' (known: {', '.join(VARIANT_KEYS)})")
        _check_field(body["field"], source, f"{where}.field")
        lam = body.get("lambda", default_lambda(body["field"]))
        if isinstance(lam, bool) or not isinstance(lam, (int, float)):
            raise ConfigError(f"{source}: '{where}.lambda' must be a number, got {lam!r}")
        _check_lambda(float(lam), source, f"{where}.lambda")
        overrides = _overrides(body.get("overrides"), source, f"{where}.overrides")
        variants.append(Variant(name, body["field"], float(lam), overrides))
    return tuple(variants)


def _perturb(raw, source: str) -> tuple[tuple[str, tuple[float, ...]], ...]:
    if not isinstance(raw, dict):
        raise ConfigError(f"{source}: 'perturb' must be a mapping of perturbation -> strengths")
    out = []
    for kind, strengths in raw.items():
        key = str(kind).replace("-", "_")
        if key not in PERTURBATIONS:
            raise ConfigError(f"{source}: 'perturb' names unknown perturbation '{kind}' ({', '.join(PERTURBATIONS)})")
        values = _as_tuple(strengths, f"perturb.{key}", source, float)
        for value in values:
            if not math.isfinite(value) or value < 0 or (key == "keep_frames" and value != int(value)):
                kind_of = "whole numbers" if key == "keep_frames" else "finite numbers"
                raise ConfigError(f"{source}: 'perturb.{key}' must hold {kind_of} >= 0 (0: clean), got {value!r}")
        out.append((key, tuple(dict.fromkeys(values))))
    return tuple(out)


def _grid(raw: dict, source: str) -> Grid:
    required = ("preset", "scenes") if "variants" in raw else ("preset", "scenes", "fields")
    missing = [k for k in required if k not in raw]
    if missing:
        raise ConfigError(f"{source}: missing key '{missing[0]}'")
    if "variants" in raw and ("fields" in raw or "lambdas" in raw):
        raise ConfigError(f"{source}: give either 'variants' or 'fields'/'lambdas', not both")
    preset = raw["preset"]
    if preset not in PRESET_NAMES:
        raise ConfigError(f"{source}: 'preset' is '{preset}' (choose from {', '.join(PRESET_NAMES)})")
    variants = _variants(raw["variants"], source) if "variants" in raw else ()
    fields = tuple(dict.fromkeys(v.field for v in variants)) or _as_tuple(raw["fields"], "fields", source, str)
    for name in fields:
        _check_field(name, source, "fields")
    lambdas = _as_tuple(raw.get("lambdas", PAPER_LAMBDA), "lambdas", source, float)
    for lam in lambdas:
        _check_lambda(lam, source, "lambdas")
    seeds = _as_tuple(raw.get("seeds", 0), "seeds", source, int)
    if any(s < 0 for s in seeds):
        raise ConfigError(f"{source}: 'seeds' must be >= 0, got {list(seeds)}")
    scenes = _as_tuple(raw["scenes"], "scenes", source, str)
    for scene in scenes:
        # Each scene names a folder of the experiment's (its runs are written under it).
        if SyntheticScene.parse(scene, source) is None and not _folder_safe(scene):
            raise ConfigError(f"{source}: 'scenes' must hold folder names under --data-root, got {scene!r}")
    dataset = raw.get("dataset", preset)
    if not _folder_safe(dataset):
        raise ConfigError(f"{source}: 'dataset' must be a non-empty folder-safe string, got {dataset!r}")
    return Grid(
        dataset=dataset,
        preset=preset,
        scenes=scenes,
        fields=fields,
        lambdas=tuple(dict.fromkeys(lambdas)),
        seeds=tuple(dict.fromkeys(seeds)),
        overrides=_overrides(raw.get("overrides"), source),
        variants=variants,
        perturb=_perturb(raw.get("perturb", {}), source),
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
    if not _folder_safe(name):
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
    raw = settings.load_yaml_file(path, "spec")
    return spec_from_dict(raw, str(path))
