"""Typed training configuration with presets; every setting is overridable on the command line."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro
import yaml

from liquidgs.atomic import write_text_atomic
from liquidgs.data.perturb import PerturbConfig
from liquidgs.data.scene import DataConfig
from liquidgs.errors import ConfigError
from liquidgs.fields import FieldConfig, FieldOptions
from liquidgs.fields.config import DEFAULT_SDE_LAMBDA
from liquidgs.train.strategy import DensifyConfig

PRESETS = ("dnerf", "nerfds", "tiny")
FIELDS = ("static", "mlp", "cfc", "sde")


@dataclass
class OptimConfig:
    """Adam (eps 1e-15) learning rates of D-3DGS."""

    means_lr_init: float = 1.6e-4
    means_lr_final: float = 1.6e-6
    means_lr_steps: int = 30_000
    spatial_lr_scale: float = 5.0
    """D-3DGS hard-codes 5 (not the camera extent) as the position learning-rate scale."""
    sh0_lr: float = 0.0025
    shN_lr: float = 0.0025 / 20
    opacities_lr: float = 0.05
    scales_lr: float = 0.005
    quats_lr: float = 0.001
    field_lr_init: float = 8e-4
    field_lr_final: float = 1.6e-6
    field_lr_steps: int = 40_000
    adam_eps: float = 1e-15


@dataclass
class EvalConfig:
    start: int = 5000
    """First periodic evaluation (D-3DGS: 5k, 6k, 7k, then every 1k)."""
    every: int = 1000
    also: tuple[int, ...] = ()
    """Further evaluation iterations; the D-3DGS code's own list is --eval.start 10000 --eval.also 5000 6000 7000."""
    lpips_backbone: Literal["vgg", "alex", "squeeze"] = "vgg"
    lpips_normalize: bool = True
    """True: images scaled to [-1,1] as LPIPS expects. False: the D-3DGS reference's quirk ([0,1] fed in)."""
    lpips_weights: Path | None = None
    """Backbone weights file or folder (else $LIQUIDGS_LPIPS_WEIGHTS, else the torch hub cache)."""
    quantize_8bit: bool = True
    """Score renders quantised to 8 bits, as the reference does (it scores PNGs written to disk)."""
    fps_frames: int = 25


@dataclass
class TrainConfig:
    data: Path
    """Dataset folder (D-NeRF or Nerfies/NeRF-DS layout)."""
    field: Literal["static", "mlp", "cfc", "sde"] = "mlp"
    """Deformation field; 'static' = no deformation, the floor every field must beat."""
    preset: Literal["dnerf", "nerfds", "tiny"] = "dnerf"
    lambda_: Annotated[float | None, tyro.conf.arg(name="lambda")] = None
    """Gate-noise level of the 'sde' field (default 0.05, the paper's calibrated value)."""
    iterations: int = 40_000
    downscale: int | None = None
    """Image downscale factor (default: 1 for D-NeRF, the split preset's for Nerfies)."""
    seed: int = 0
    out: Path | None = None
    """Run folder (default outputs/<scene>/<field>/<config hash>)."""
    resume: bool = False
    device: str = "auto"
    backend: Literal["auto", "torch", "gsplat"] = "auto"
    background: Literal["black", "white"] = "black"
    data_format: Literal["auto", "dnerf", "nerfies"] = "auto"
    split: Literal["auto", "nerfds", "vrig", "interp"] = "auto"
    """Nerfies split preset: nerfds | vrig | interp (auto = nerfds)."""
    val_as_test: bool = False
    warmup: int = 3000
    """Iterations with the deltas forced to zero (static 3DGS)."""
    sh_degree: int = 3
    sh_interval: int = 1000
    ssim_weight: float = 0.2
    init_points: int = 100_000
    """Random initial points in [-init_extent, init_extent]^3 (used when the data has no point cloud)."""
    init_extent: float = 1.3
    smooth_time: bool = False
    """Annealed smooth training (D-3DGS, real data): t + N(0,1) * scale * s(i) after warm-up."""
    smooth_time_steps: int = 20_000
    smooth_time_scale: Literal["frames", "stack"] = "frames"
    """'frames': 1/N_frames as the paper says; 'stack': 1/(cameras left in the epoch stack) as its code does."""
    checkpoint_every: int = 5000
    divergence_drop_db: float = 10.0
    """Stop when the smoothed training PSNR falls this far below its best since the last scheduled
    disturbance (opacity reset, SH degree step, end of warm-up, densification burst)."""
    field_options: FieldOptions = dataclasses.field(default_factory=FieldOptions)
    """Field sizes and noise variants (name, preset and lambda come from the flags above)."""
    perturb: PerturbConfig = dataclasses.field(default_factory=PerturbConfig)
    """Stress tests: corrupt or thin out the training split (test views stay clean)."""
    optim: OptimConfig = dataclasses.field(default_factory=OptimConfig)
    densify: DensifyConfig = dataclasses.field(default_factory=DensifyConfig)
    eval: EvalConfig = dataclasses.field(default_factory=EvalConfig)

    def field_config(self) -> FieldConfig:
        return FieldConfig.of(self.field_options, self.field, self.preset, self.resolved_lambda())

    def resolved_lambda(self) -> float:
        if self.lambda_ is None:
            return DEFAULT_SDE_LAMBDA if self.field == "sde" else 0.0
        return self.lambda_


def preset_config(name: str, data: Path) -> TrainConfig:
    """Defaults of a preset. dnerf/nerfds follow the current public D-3DGS code."""
    if name not in PRESETS:
        raise ConfigError(f"unknown preset '{name}' (choose from {', '.join(PRESETS)})")
    cfg = TrainConfig(data=data, preset=name)  # type: ignore[arg-type]
    if name == "nerfds":
        cfg.iterations = 20_000
        cfg.smooth_time = True
    elif name == "tiny":
        # A short CPU schedule for the built-in 128 px synthetic scenes: the D-3DGS recipe
        # with every step count scaled down, fewer initial points, and alex LPIPS.
        cfg.iterations = 1500
        cfg.warmup = 100
        cfg.sh_interval = 300
        cfg.init_points = 5000
        cfg.checkpoint_every = 500
        # A short warm-up and a field learning rate that stays high (5e-3 -> 5e-4): measured on
        # the built-in puppet scene, warm-up 300 with 2e-3 -> 2e-5 left the field nearly static.
        cfg.optim = OptimConfig(means_lr_steps=1500, field_lr_init=5e-3, field_lr_final=5e-4, field_lr_steps=1500)
        cfg.densify = DensifyConfig(start=100, stop=1100, interval=50, opacity_reset_interval=600)
        cfg.eval = EvalConfig(start=500, every=500, lpips_backbone="alex")
    return cfg


def stretched_schedule(preset: str, iterations: int) -> list[str]:
    """`liquidgs train` flags that fit a preset's schedule to `iterations`: learning rates
    decay over all of them, densification runs until 3/4 of them with an opacity reset every
    2/5, and the one evaluation is at the end.

    Measured with the tiny preset (2-core CPU, final test PSNR, seeds 0-2): hellwarrior at
    100x100 stretched to 1,000 iterations puts every field 1.5-2.1 dB above the static model,
    where the preset's own 1,500-iteration schedule cut at 600 gave 0.2-0.7 dB.
    """
    start = preset_config(preset, Path(".")).densify.start
    n = iterations
    return [
        "--iterations", str(n),
        "--optim.means-lr-steps", str(n),
        "--optim.field-lr-steps", str(n),
        "--densify.stop", str(max(start + 1, 3 * n // 4)),
        "--densify.opacity-reset-interval", str(max(1, 2 * n // 5)),
        "--eval.start", str(n),
    ]  # fmt: skip


MAX_ITERATIONS = 10_000_000
MAX_INIT_POINTS = 10_000_000
_INT64_MAX = 2**63 - 1

# Range of every integer setting: (lowest, highest). Zero intervals would divide by zero mid-run.
_INT_RANGES: dict[str, tuple[int, int]] = {
    "iterations": (1, MAX_ITERATIONS),
    "seed": (0, _INT64_MAX),
    "warmup": (0, _INT64_MAX),
    "sh_degree": (0, 3),
    "sh_interval": (1, _INT64_MAX),
    "init_points": (1, MAX_INIT_POINTS),
    "smooth_time_steps": (1, _INT64_MAX),
    "checkpoint_every": (1, _INT64_MAX),
    "optim.means_lr_steps": (1, _INT64_MAX),
    "optim.field_lr_steps": (1, _INT64_MAX),
    "densify.start": (0, _INT64_MAX),
    "densify.stop": (0, _INT64_MAX),
    "densify.interval": (1, _INT64_MAX),
    "densify.opacity_reset_interval": (1, _INT64_MAX),
    "densify.split_count": (1, 64),
    "eval.start": (0, _INT64_MAX),
    "eval.every": (1, _INT64_MAX),
    "eval.fps_frames": (1, 100_000),
}


def _positive(v: float) -> bool:
    return v > 0


def _non_negative(v: float) -> bool:
    return v >= 0


def _unit(v: float) -> bool:
    return 0 <= v <= 1


def _open_unit(v: float) -> bool:
    return 0 < v < 1


_RULE_TEXT = {_positive: "> 0", _non_negative: ">= 0", _unit: "in [0, 1]", _open_unit: "in (0, 1)"}

# Every float setting must be finite and pass its rule.
_FLOAT_RULES = {
    "init_extent": _positive,
    "ssim_weight": _unit,
    "divergence_drop_db": _positive,
    **{f"optim.{name}": _non_negative for name in (
        "means_lr_init", "means_lr_final", "sh0_lr", "shN_lr", "opacities_lr", "scales_lr", "quats_lr",
        "field_lr_init", "field_lr_final",
    )},  # fmt: skip
    "optim.spatial_lr_scale": _positive,
    "optim.adam_eps": _positive,
    "densify.grad_threshold": _non_negative,
    "densify.prune_opacity": _unit,
    "densify.percent_dense": _non_negative,
    "densify.max_screen_radius": _positive,
    "densify.max_world_size": _positive,
    "densify.split_scale_divisor": _positive,
    "densify.reset_opacity_to": _open_unit,
    "densify.max_per_pixel": _non_negative,
}


def _setting(cfg: TrainConfig, dotted: str):
    value = cfg
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


def validate(cfg: TrainConfig) -> None:
    """Every setting in range, so a run never fails mid-way on a value it could have refused."""
    if cfg.field not in FIELDS:
        raise ConfigError(f"unknown field '{cfg.field}' (choose from {', '.join(FIELDS)})")
    for name, (lo, hi) in _INT_RANGES.items():
        value = _setting(cfg, name)
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            bound = f"between {lo} and {hi}" if hi < _INT64_MAX else f">= {lo}"
            raise ConfigError(f"{name.replace('_', '-')} must be an integer {bound}, got {value!r}")
    for name, rule in _FLOAT_RULES.items():
        value = _setting(cfg, name)
        is_number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if not (is_number and math.isfinite(value) and rule(value)):
            raise ConfigError(f"{name.replace('_', '-')} must be a finite number {_RULE_TEXT[rule]}, got {value!r}")
    if cfg.lambda_ is not None and not (math.isfinite(cfg.lambda_) and cfg.lambda_ >= 0):
        raise ConfigError(f"lambda must be a finite number >= 0, got {cfg.lambda_}")
    if cfg.field == "cfc" and cfg.resolved_lambda() != 0.0:
        raise ConfigError("the 'cfc' field is the deterministic cell (lambda = 0); use --field sde for noise")
    if not all(type(step) is int and 1 <= step <= _INT64_MAX for step in cfg.eval.also):
        raise ConfigError(f"eval.also must hold iterations >= 1, got {list(cfg.eval.also)}")
    if cfg.downscale is not None and cfg.downscale < 1:
        raise ConfigError(f"downscale must be >= 1, got {cfg.downscale}")
    cfg.field_config()  # the field's own rules, now that its name, preset and lambda are known
    cfg.perturb.validate()


def to_dict(cfg: TrainConfig) -> dict:
    def convert(value):
        if isinstance(value, Path):
            return str(value)
        if isinstance(value, dict):
            return {k: convert(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [convert(v) for v in value]
        return value

    return convert(dataclasses.asdict(cfg))


# Settings that change where or how a run executes, not what it computes.
_NOT_IDENTITY = ("out", "resume", "device", "backend", "checkpoint_every")


# Before field_options lost them, it held a placeholder name, preset and lambda that never took
# effect; config hashes (and so run folder names) were computed with them and must not change.
_LEGACY_FIELD_OPTIONS = {"name": "mlp", "preset": "dnerf", "lambda_": None}


def identity(cfg: TrainConfig) -> dict:
    """What a run computes from. An unperturbed run has no 'perturb' key, so it hashes as it
    did before perturbations existed."""
    d = to_dict(cfg)
    for key in _NOT_IDENTITY:
        d.pop(key, None)
    d["data"] = str(Path(d["data"]).resolve())
    d["field_options"] = {**_LEGACY_FIELD_OPTIONS, **d["field_options"]}
    if not cfg.perturb.active:
        del d["perturb"]
    if not cfg.eval.also:  # runs without extra evaluations hash as they did before the setting existed
        del d["eval"]["also"]
    if not cfg.densify.max_per_pixel:  # uncapped runs hash as they did before the cap existed
        del d["densify"]["max_per_pixel"]
    return d


def config_hash(cfg: TrainConfig) -> str:
    return hashlib.sha256(json.dumps(identity(cfg), sort_keys=True).encode()).hexdigest()[:10]


def differing_settings(a: TrainConfig, b: TrainConfig) -> list[str]:
    """The settings of the identity, as dotted names, in which two configurations differ."""

    def flatten(d: dict, prefix: str = "") -> dict:
        flat = {}
        for key, value in d.items():
            if isinstance(value, dict):
                flat.update(flatten(value, f"{prefix}{key}."))
            else:
                flat[f"{prefix}{key}"] = value
        return flat

    fa, fb = flatten(identity(a)), flatten(identity(b))
    return sorted(k for k in fa.keys() | fb.keys() if fa.get(k) != fb.get(k))


def data_config(cfg: TrainConfig) -> DataConfig:
    """The run's data settings, as the data loader takes them."""
    return DataConfig(
        path=cfg.data,
        format=cfg.data_format,
        downscale=cfg.downscale,
        background=cfg.background,
        split=cfg.split,
        val_as_test=cfg.val_as_test,
    )


def save_yaml(cfg: TrainConfig, path: Path) -> None:
    write_text_atomic(path, yaml.safe_dump(to_dict(cfg), sort_keys=False))


def load_yaml(path: Path) -> TrainConfig:
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as err:
        raise ConfigError(f"{path}: unreadable run config ({type(err).__name__})") from None
    if not isinstance(raw, dict) or "data" not in raw:
        raise ConfigError(f"{path}: not a liquidgs run config (no 'data')")
    return from_dict(raw, path)


def _describe(hint) -> str:
    if typing.get_origin(hint) is Literal:
        return "one of " + ", ".join(map(str, typing.get_args(hint)))
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return " or ".join(_describe(arg) for arg in typing.get_args(hint))
    return {int: "an integer", float: "a number", bool: "true or false", str: "a string", Path: "a path",
            type(None): "null"}.get(hint, str(hint))  # fmt: skip


def _matches(value, hint) -> bool:
    """Whether a YAML value fits a setting's type (the types TrainConfig and its parts use)."""
    origin = typing.get_origin(hint)
    if origin is Literal:
        return any(value == choice and type(value) is type(choice) for choice in typing.get_args(hint))
    if origin in (typing.Union, types.UnionType):
        return any(_matches(value, arg) for arg in typing.get_args(hint))
    if hint is type(None):
        return value is None
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint in (int, bool, str):
        return type(value) is hint
    if hint is Path:
        return isinstance(value, str)
    if typing.get_origin(hint) is tuple:
        return isinstance(value, list) and all(_matches(item, typing.get_args(hint)[0]) for item in value)
    return True


def from_dict(raw: dict, source: Path | str = "config") -> TrainConfig:
    """A TrainConfig from YAML; a setting of the wrong type is one error naming it."""

    def build(cls, values: dict, prefix: str):
        if not isinstance(values, dict):
            raise ConfigError(f"{source}: setting '{prefix.rstrip('.')}' must be a mapping, got {values!r}")
        kwargs = {}
        fields = {f.name: f for f in dataclasses.fields(cls)}
        hints = typing.get_type_hints(cls)
        for key, value in values.items():
            if key not in fields:
                raise ConfigError(f"{source}: unknown setting '{prefix}{key}' for {cls.__name__}")
            factory = fields[key].default_factory
            if callable(factory) and dataclasses.is_dataclass(factory()):
                kwargs[key] = build(type(factory()), value, f"{prefix}{key}.")
                continue
            if not _matches(value, hints[key]):
                raise ConfigError(
                    f"{source}: setting '{prefix}{key}' must be {_describe(hints[key])}, got {value!r}"[:300]
                )
            is_path = Path in (hints[key], *typing.get_args(hints[key]))
            if typing.get_origin(hints[key]) is tuple:  # YAML holds lists
                value = tuple(value)
            kwargs[key] = Path(value) if is_path and value is not None else value
        return cls(**kwargs)

    raw = dict(raw)
    if isinstance(raw.get("field_options"), dict):  # config.yml of an older version: drop the placeholders
        raw["field_options"] = {k: v for k, v in raw["field_options"].items() if k not in _LEGACY_FIELD_OPTIONS}
    return build(TrainConfig, raw, "")
