"""Typed training configuration with presets; every setting is overridable on the command line."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro
import yaml

from liquidgs import settings
from liquidgs.atomic import write_text_atomic
from liquidgs.data.dnerf import SCENE_BOUND
from liquidgs.data.flow import has_flow
from liquidgs.data.perturb import PerturbConfig
from liquidgs.data.scene import DataConfig
from liquidgs.errors import ConfigError
from liquidgs.fields import FieldConfig, FieldOptions
from liquidgs.fields.config import (
    FIELD_ONLY_OPTIONS,
    PRESET_NAMES,
    PresetName,
    check_choice,
    default_lambda,
    field_options_class,
    options_read,
    own_option_flags,
)
from liquidgs.fields.registry import check_recorded_field, field_record
from liquidgs.render import BACKENDS
from liquidgs.settings import to_dict, with_settings
from liquidgs.train.camera_opt import Alignment, CameraRefineConfig, known_format, refines
from liquidgs.train.dynamic_split import SplitConfig, split_applies
from liquidgs.train.exposure import ExposureConfig, compensates
from liquidgs.train.flow_loss import DEFAULT_WEIGHT, FlowLossConfig
from liquidgs.train.motion_reg import MotionRegConfig, motion_applies, split_in_place_of_neighbour_terms
from liquidgs.train.strategy import DensifyConfig


@dataclass
class OptimConfig:
    """Adam (eps 1e-15) learning rates of D-3DGS."""

    means_lr_init: float = 1.6e-4
    """Learning rate of the Gaussians' positions at the start (times spatial_lr_scale)."""
    means_lr_final: float = 1.6e-6
    """Learning rate of the positions after means_lr_steps (exponential decay)."""
    means_lr_steps: int = 30_000
    """Iterations over which the position learning rate decays."""
    spatial_lr_scale: float = 5.0
    """D-3DGS hard-codes 5 (not the camera extent) as the position learning-rate scale."""
    sh0_lr: float = 0.0025
    """Learning rate of the base (degree-0) colour."""
    shN_lr: float = 0.0025 / 20
    """Learning rate of the higher SH coefficients."""
    opacities_lr: float = 0.05
    """Learning rate of the opacities (logits)."""
    scales_lr: float = 0.005
    """Learning rate of the scales (logs)."""
    quats_lr: float = 0.001
    """Learning rate of the rotations (quaternions)."""
    field_lr_init: float = 8e-4
    """Learning rate of the deformation field at the end of warm-up."""
    field_lr_final: float = 1.6e-6
    """Learning rate of the field after field_lr_steps (exponential decay)."""
    field_lr_steps: int = 40_000
    """Iterations over which the field's learning rate decays."""
    adam_eps: float = 1e-15
    """Adam's epsilon for every parameter group (3DGS's 1e-15)."""


@dataclass
class EvalConfig:
    start: int = 5000
    """First periodic evaluation (D-3DGS: 5k, 6k, 7k, then every 1k)."""
    every: int = 1000
    """Iterations between periodic test evaluations after eval.start."""
    also: tuple[int, ...] = ()
    """Further evaluation iterations; the D-3DGS code's own list is --eval.start 10000 --eval.also 5000 6000 7000."""
    lpips_backbone: Literal["vgg", "alex", "squeeze"] = "vgg"
    """LPIPS backbone: vgg (what D-3DGS reports), alex or squeeze."""
    lpips_normalize: bool = True
    """True: images scaled to [-1,1] as LPIPS expects. False: the D-3DGS reference's quirk ([0,1] fed in)."""
    lpips_weights: Path | None = None
    """Backbone weights file or folder (else $LIQUIDGS_LPIPS_WEIGHTS, else the torch hub cache)."""
    quantize_8bit: bool = True
    """Score renders quantised to 8 bits, as the reference does (it scores PNGs written to disk)."""
    fps_frames: int = 25
    """Test views rendered for the FPS figure (the first 5 are dropped as warm-up)."""


@dataclass
class TrainConfig:
    data: Annotated[DataConfig, tyro.conf.OmitArgPrefixes]
    """The scene and how to read it (--data PATH, --downscale, --background, ...)."""
    field: str = "mlp"
    """Deformation field: static (no deformation, the floor every field must beat), mlp, cfc, sde,
    or any other registered field (liquidgs.fields.register; an unknown name lists them)."""
    preset: PresetName = "dnerf"
    """Schedule and field sizes: dnerf (D-NeRF, 40k iterations), nerfds (real captures, 20k, smoothed
    time) or tiny (a CPU schedule of 1.5k)."""
    lambda_: Annotated[
        float | None, tyro.conf.arg(name="lambda", metavar="FLOAT", help_behavior_hint="(default: 0.05 for sde)")
    ] = None
    """Gate-noise level of the 'sde' field (the paper's calibrated 0.05 unless given)."""
    iterations: int = 40_000
    """Training iterations (the preset's unless given)."""
    seed: int = 0
    """Seed of the initial points, the camera order and the field's weights."""
    out: Path | None = None
    """Run folder (default outputs/<scene>/<field>/<config hash>)."""
    resume: bool = False
    """Continue the run in --out from its checkpoint (only --iterations may change, to extend it)."""
    device: str = "auto"
    """auto (CUDA where torch sees a GPU, else the CPU), cpu, cuda or cuda:N."""
    backend: Literal[BACKENDS] = "auto"  # type: ignore[valid-type]
    """Rasteriser: auto (gsplat on CUDA, else the compiled CPU kernels, else torch), torch (the
    portable reference), cpu or gsplat."""
    warmup: int = 3000
    """Iterations with the deltas forced to zero (static 3DGS)."""
    sh_degree: int = 3
    """Highest spherical-harmonics degree of the Gaussians' colours (0..3)."""
    sh_interval: int = 1000
    """Iterations between two raises of the SH degree used, from 0 up to sh_degree."""
    ssim_weight: float = 0.2
    """Weight of the D-SSIM term in the photometric loss (1 - w) L1 + w (1 - SSIM)."""
    init_points: int = 100_000
    """Random initial points in [-init_extent, init_extent]^3 (used when the data has no point cloud);
    at most 10,000,000."""
    init_extent: float = SCENE_BOUND
    """Half-side of the cube the random initial points fill, where the scene has no point cloud."""
    smooth_time: bool = False
    """Annealed smooth training (D-3DGS, real data): t + N(0,1) * scale * s(i) after warm-up."""
    smooth_time_steps: int = 20_000
    """Iterations over which the annealed time noise of smooth_time decays to 0."""
    smooth_time_scale: Literal["frames", "stack"] = "frames"
    """'frames': 1/N_frames as the paper says; 'stack': 1/(cameras left in the epoch stack) as its code does."""
    checkpoint_every: int = 5000
    """Iterations between checkpoints (the last iteration is always checkpointed)."""
    divergence_drop_db: float = 10.0
    """Stop when the smoothed training PSNR falls this far below its best since the last scheduled
    disturbance (opacity reset, SH degree step, end of warm-up, densification burst)."""
    field_options: FieldOptions = dataclasses.field(default_factory=FieldOptions)
    """Sizes and noise variants of the built-in fields (name, preset and lambda come from the flags
    above); a field outside the built-in families is sized by its preset alone (hexplane reads one
    option, grid_lr_scale) and by the options it registered (a plugin's --field-options.*)."""
    perturb: PerturbConfig = dataclasses.field(default_factory=PerturbConfig)
    """Stress tests: corrupt or thin out the training split (test views stay clean)."""
    optim: OptimConfig = dataclasses.field(default_factory=OptimConfig)
    densify: DensifyConfig = dataclasses.field(default_factory=DensifyConfig)
    eval: EvalConfig = dataclasses.field(default_factory=EvalConfig)
    cameras: CameraRefineConfig = dataclasses.field(default_factory=CameraRefineConfig)
    """Camera refinement (on for captures, off for D-NeRF) and the aligned evaluation of test cameras."""
    motion: MotionRegConfig = dataclasses.field(default_factory=MotionRegConfig)
    """Rigidity and isometry over each Gaussian's nearest neighbours, and sizes held (on for captures,
    off for D-NeRF)."""
    exposure: ExposureConfig = dataclasses.field(default_factory=ExposureConfig)
    """A colour correction per training frame (on for captures, off for D-NeRF)."""
    flow: FlowLossConfig = dataclasses.field(default_factory=FlowLossConfig)
    """The optical-flow loss (on by default for captures with flow at the training scale, off
    elsewhere: with_motion_evidence)."""
    split: SplitConfig = dataclasses.field(default_factory=SplitConfig)
    """Static and dynamic Gaussians: the field moves only those the motion masks show moving (on by
    default for captures with flow at the training scale, off elsewhere: with_motion_evidence)."""

    def __post_init__(self) -> None:
        own = field_options_class(self.field)
        if type(self.field_options) is not own:  # e.g. built in code with FieldOptions(): the field's own defaults
            shared = {f.name: getattr(self.field_options, f.name) for f in dataclasses.fields(FieldOptions)}
            self.field_options = own(**shared)
        validate(self)

    def alignment(self, data_format: str | None) -> Alignment | None:
        """How a test view of this run is aligned before its second, labelled score: its pose where the
        run refines its cameras, its exposure where it compensates exposure; None where neither."""
        pose, exposure = refines(self.cameras, data_format), compensates(self.exposure, data_format)
        return Alignment(pose=pose, exposure=exposure) if pose or exposure else None

    @classmethod
    def settings_group(cls, key: str, raw: dict) -> type:
        """settings' hook: field_options holds the options of the field the config names."""
        if key == "field_options":
            name = raw.get("field", cls.field)
            return field_options_class(name) if isinstance(name, str) else FieldOptions
        return settings.nested_class(cls, key)

    @classmethod
    def settings_extra_flags(cls) -> list[settings.Flag]:
        """settings' hook: --field-options.* of every registered field's own options."""
        flags = []
        for key, owners in own_option_flags().items():
            hints = tuple(dict.fromkeys(hint for _, hint in owners))
            hint = hints[0] if len(hints) == 1 else typing.Union[hints]  # noqa: UP007 - a runtime union
            flag = f"field-options.{key.replace('_', '-')}"
            flags.append(settings.Flag(f"field_options.{key}", flag, hint, positional=False, required=False))
        return flags

    def field_config(self) -> FieldConfig:
        """The field's own configuration (validated by the field's rules)."""
        return FieldConfig.of(self.field_options, self.field, self.preset, self.lambda_)

    def resolved_lambda(self) -> float:
        return self.field_config().base_lambda


# Each preset's training schedule, as the settings it changes from TrainConfig's defaults (which are
# the dnerf preset: the current public D-3DGS code). The field sizes of a preset are fields/config.py's.
PRESET_SETTINGS: dict[str, dict] = {
    "dnerf": {},
    "nerfds": {"iterations": 20_000, "smooth_time": True},
    # A short CPU schedule for the built-in 128 px synthetic scenes: the D-3DGS recipe with every
    # step count scaled down, fewer initial points, and alex LPIPS. A short warm-up and a field
    # learning rate that stays high (5e-3 -> 5e-4): measured on the built-in puppet scene, warm-up
    # 300 with 2e-3 -> 2e-5 left the field nearly static.
    "tiny": {
        "iterations": 1500,
        "warmup": 100,
        "sh_interval": 300,
        "init_points": 5000,
        "checkpoint_every": 500,
        "optim.means_lr_steps": 1500,
        "optim.field_lr_init": 5e-3,
        "optim.field_lr_final": 5e-4,
        "optim.field_lr_steps": 1500,
        "densify.start": 100,
        "densify.stop": 1100,
        "densify.interval": 50,
        "densify.opacity_reset_interval": 600,
        "eval.start": 500,
        "eval.every": 500,
        "eval.lpips_backbone": "alex",
    },
}
assert tuple(PRESET_SETTINGS) == PRESET_NAMES


def preset_config(name: str, data: Path | DataConfig) -> TrainConfig:
    """Defaults of a preset for a scene (a path, or a DataConfig with its reading options)."""
    check_choice("preset", name, PRESET_NAMES)
    data = data if isinstance(data, DataConfig) else DataConfig(path=Path(data))
    return with_settings(TrainConfig(data=data, preset=name), PRESET_SETTINGS[name], f"preset {name}")


def stretched_schedule(preset: str, iterations: int) -> dict:
    """The settings that fit a preset's schedule to `iterations`: learning rates
    decay over all of them, densification runs until 3/4 of them with an opacity reset every
    2/5, and the one evaluation is at the end.

    Measured with the tiny preset (2-core CPU, final test PSNR, seeds 0-2): hellwarrior at
    100x100 stretched to 1,000 iterations puts every field 1.5-2.1 dB above the static model,
    where the preset's own 1,500-iteration schedule cut at 600 gave 0.2-0.7 dB.
    """
    start = preset_config(preset, Path(".")).densify.start
    n = iterations
    return {
        "iterations": n,
        "optim.means_lr_steps": n,
        "optim.field_lr_steps": n,
        "densify.stop": max(start + 1, 3 * n // 4),
        "densify.opacity_reset_interval": max(1, 2 * n // 5),
        "eval.start": n,
    }


MAX_ITERATIONS = 10_000_000
MAX_INIT_POINTS = 10_000_000
"""The most init_points: 100x the dnerf preset's 100,000."""
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
    "densify.reset_opacity_to": _open_unit,
    "densify.max_per_pixel": _non_negative,
}


def _setting(cfg: TrainConfig, dotted: str):
    value = cfg
    for part in dotted.split("."):
        value = getattr(value, part)
    return value


def validate(cfg: TrainConfig) -> None:
    """Every setting in range, so a run never fails mid-way on a value it could have refused.
    TrainConfig runs it when built; the field's, the data's and the perturbations' own rules run
    when their configs are built."""
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
    if not all(type(step) is int and 1 <= step <= _INT64_MAX for step in cfg.eval.also):
        raise ConfigError(f"eval.also must hold iterations >= 1, got {list(cfg.eval.also)}")
    cfg.field_config()  # the field's own rules, now that its name, preset and lambda are known


_FIELD_OPTION_NAMES = frozenset(f.name for f in dataclasses.fields(FieldOptions))


def with_motion_evidence(cfg: TrainConfig) -> TrainConfig:
    """`cfg` with the motion evidence it leaves to the scene decided: where the scene has optical flow
    and motion masks at the scale the run reads (data.flow.has_flow) the flow loss at DEFAULT_WEIGHT
    and the static/dynamic split on - the split, where it is decided so, in place of the neighbour
    terms a field registered local_deformation has by default (motion_reg.split_in_place_of_neighbour_terms)
    - elsewhere (D-NeRF, synthetic scenes, captures without flow) both off. A value set (flow.weight,
    split.apply, a motion weight) is kept. The one owner of these defaults: the trainer records its
    result in config.yml (the run resumes and reproduces as trained, whatever later happens to the
    scene's flow or to these defaults) and the identity hashes it."""
    if cfg.flow.weight is not None and cfg.split.apply is not None:
        return cfg
    found = has_flow(cfg.data)
    weight = cfg.flow.weight if cfg.flow.weight is not None else DEFAULT_WEIGHT if found else 0.0
    apply = cfg.split.apply if cfg.split.apply is not None else found
    decided_split = cfg.split.apply is None and apply
    motion = split_in_place_of_neighbour_terms(cfg.motion, cfg.field) if decided_split else cfg.motion
    return dataclasses.replace(cfg, flow=dataclasses.replace(cfg.flow, weight=weight),
                               split=dataclasses.replace(cfg.split, apply=apply), motion=motion)  # fmt: skip


def motion_evidence_note(given: TrainConfig, decided: TrainConfig) -> str | None:
    """The line a run prints where with_motion_evidence turned a setting left to the scene on: what it
    trains with, and how to train without."""
    flow_decided = given.flow.weight is None and decided.flow.weight > 0
    split_decided = given.split.apply is None and split_applies(decided.split, decided.field)
    if not (flow_decided or split_decided):
        return None
    parts = [f"the flow loss at {decided.flow.weight:g}"] if decided.flow.weight > 0 else []
    if split_applies(decided.split, decided.field):
        replaced = given.split.apply is None and decided.motion != given.motion
        parts.append("the static/dynamic split" + (" in place of the neighbour terms" if replaced else ""))
    off = " ".join(flag for flag, left in (("--flow.weight 0", flow_decided), ("--split.apply false", split_decided))
                   if left)  # fmt: skip
    found = "the scene has optical flow and motion masks at this scale"
    return f"{found}: training with {' and '.join(parts)} ({off} to train without)"


def check_given_settings(cfg: TrainConfig, given: typing.Iterable[str]) -> None:
    """ConfigError for a setting given on the command line (dotted keys) that this run never reads: a
    field option of another field, a motion term's setting where the motion terms are off. Only what
    was given is refused: presets and specs set options for every field of a grid, and config.yml
    keeps what it holds (its identity, and so its folder, unchanged)."""
    data_format = known_format(cfg.data)
    split_left_to_scene, flow_left_to_scene = cfg.split.apply is None, cfg.flow.weight is None
    cfg = with_motion_evidence(cfg)
    read = options_read(cfg.field)
    for key in given:
        group, _, name = key.partition(".")
        if group == "field_options" and name in _FIELD_OPTION_NAMES and name not in read:
            reads = f"reads {', '.join(read)}" if read else "reads no field options"
            raise ConfigError(f"--field-options.{name.replace('_', '-')} has no effect on field '{cfg.field}' "
                              f"(it {reads})")  # fmt: skip
        if group == "motion" and name != "apply" and not motion_applies(cfg.motion, data_format, cfg.field):
            if cfg.field == "static":
                why = "the static field does not move Gaussians"
            elif cfg.motion.apply == "off":
                why = "--motion.apply is off"
            elif data_format is None:
                continue  # the scene's format is not known yet: the data's own check says why
            else:
                why = f"--motion.apply auto is off for {data_format} data (on for captures)"
            raise ConfigError(f"--motion.{name.replace('_', '-')} has no effect: {why}, so no motion term is trained")
        if key == "motion.stillness" and split_applies(cfg.split, cfg.field):
            # The trainer holds static Gaussians exactly still instead (dynamic_split), so the term is not trained.
            decided = " (decided from the scene's motion masks)" if split_left_to_scene else ""
            raise ConfigError("--motion.stillness has no effect: the static/dynamic split holds the static Gaussians "
                              f"still{decided}; --split.apply false trains the term instead")  # fmt: skip
        if key == "flow.tracks" and not cfg.flow.weight:
            why = ("the scene has no optical flow at the training scale (liquidgs data flow)" if flow_left_to_scene
                   else "--flow.weight is 0")  # fmt: skip
            raise ConfigError(f"--flow.tracks has no effect: {why}, so the optical-flow loss is off")
        if group == "split" and name != "apply" and not split_applies(cfg.split, cfg.field):
            if cfg.field == "static":
                why = "the static field does not move Gaussians"
            elif split_left_to_scene:
                why = "the scene has no optical flow at the training scale (liquidgs data flow), so the split is off"
            else:
                why = "--split.apply is false"
            raise ConfigError(f"--split.{name.replace('_', '-')} has no effect: {why}")


# Settings that change where or how a run executes, not what it computes.
_NOT_IDENTITY = ("out", "resume", "device", "backend", "checkpoint_every", "data.cache_images")

IDENTITY_VERSION = 3
"""Version 3 (this code): version 2's settings with each written one way (normal_identity), so
equal settings hash equal. Version 2: every setting that changes what a run computes, as
config.yml holds it, with the scene path resolved and "identity": 2. A config already in normal
form has the same hash in both (the dict keeps the marker 2), so only the folders of configs that
were not are renamed, and run_folder still finds those. Version 1 (before the data settings were
grouped under `data`) is legacy_identity's; run folders named by it are still found too."""
_IDENTITY_MARKER = 2
"""The version the hashed dict carries: version 3 changed no layout, only how settings are written."""


_ABSENT_WHEN_UNSET = {"level_time_resolutions"}
"""Field-only options added after grid_lr_scale, left out of the owner's identity too while unset: unset is
what every run made before them had (grid_lr_scale is held even at None: see identity_v2)."""


def identity_v2(cfg: TrainConfig) -> dict:
    """What a run computes from, as version 2 wrote it. A setting added later must not change the
    identity of runs made without it: leave it out at the value those runs had (and test that)."""
    cfg = with_motion_evidence(cfg)  # flow and split as the run decides them from its scene
    d = to_dict(cfg)
    for dotted in _NOT_IDENTITY:
        *groups, last = dotted.split(".")
        node = d
        for part in groups:
            node = node[part]
        del node[last]
    # Added after version 2, each for one field: left out of the other fields' identities. The field
    # that reads one holds it even at None (its preset's value), so that its runs made before the
    # option existed (hexplane: the grid at the decoder's learning rate) are not taken for new ones.
    for key, owner in FIELD_ONLY_OPTIONS.items():
        if cfg.field != owner or (key in _ABSENT_WHEN_UNSET and not d["field_options"][key]):
            del d["field_options"][key]
    # Camera refinement, added after version 2: a run that does not refine (every run made before
    # it) has no `cameras` in its identity; one that does holds them with `refine` resolved.
    data_format = known_format(cfg.data)
    if refines(cfg.cameras, data_format):
        d["cameras"]["refine"] = "on"
    else:
        del d["cameras"]
    if motion_applies(cfg.motion, data_format, cfg.field):  # the motion regularisers likewise
        d["motion"]["apply"] = "on"
        if not cfg.motion.fixed_sizes:  # the regularisers' runs made before sizes could be held
            del d["motion"]["fixed_sizes"]
        stillness = cfg.motion.weights(cfg.field)[2]
        if stillness:  # resolved: a run of the field's default is not taken for one of another weight
            d["motion"]["stillness"] = stillness
        else:  # and as before the stillness term existed
            del d["motion"]["stillness"]
    else:
        del d["motion"]
    if compensates(cfg.exposure, data_format):  # and exposure compensation
        d["exposure"]["apply"] = "on"
    else:
        del d["exposure"]
    if not cfg.flow.weight:  # the optical-flow loss, added after version 2: off in every run made before it
        del d["flow"]
    elif not cfg.flow.tracks:  # tracks, added after the loss: off in every run made before them
        del d["flow"]["tracks"]
    if not split_applies(cfg.split, cfg.field):  # static and dynamic Gaussians, likewise
        del d["split"]
    elif cfg.split.occlusion is None:  # the occlusion test, added after the split: off in every run made before it
        del d["split"]["occlusion"]
    if not cfg.perturb.exposure:  # the exposure-flicker stress test, added after version 2
        del d["perturb"]["exposure"]
    d["data"]["path"] = str(Path(d["data"]["path"]).resolve())
    d["identity"] = _IDENTITY_MARKER
    return d


def _reads_as_dnerf(data: DataConfig) -> bool:
    path = data.path
    detected = (path / "transforms_train.json").is_file() and not (path / "dataset.json").is_file()
    return data.format == "dnerf" or (data.format == "auto" and detected)


def identity(cfg: TrainConfig) -> dict:
    """Version 3: version 2's with equal settings written one way - the form experiments write:
    - the LPIPS weights file: where the evaluation finds the published weights, not what the
      run computes (None, as when found through $LIQUIDGS_LPIPS_WEIGHTS);
    - lambda: the resolved noise level of a field that has one by default ('sde': None -> 0.05),
      None for the others (0 is their only value);
    - data.downscale of a D-NeRF scene: None for 1 (the reader's default; a Nerfies split's
      default depends on the split, so its None stays apart)."""
    d = identity_v2(cfg)
    d["eval"]["lpips_weights"] = None
    d["lambda_"] = cfg.resolved_lambda() if default_lambda(cfg.field) else None
    if d["data"]["downscale"] == 1 and _reads_as_dnerf(cfg.data):
        d["data"]["downscale"] = None
    return d


def config_hash(cfg: TrainConfig) -> str:
    return _hash(identity(cfg))


def _hash(d: dict) -> str:
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:10]


# Version 1 kept the data settings at the top level (data_format for data.format), a placeholder
# name, preset and lambda in field_options that never took effect, densify.split_scale_divisor
# (a setting nothing read: the split divides by 0.8 x split_count, as D-3DGS), and left out
# three settings at the values of runs made before they existed.
_V1_DATA_KEYS = {"path": "data", "format": "data_format", "downscale": "downscale", "background": "background",
                 "split": "split", "val_as_test": "val_as_test"}  # fmt: skip
_V1_FIELD_OPTIONS = {"name": "mlp", "preset": "dnerf", "lambda_": None}
_V1_SPLIT_SCALE_DIVISOR = 1.6


def legacy_identity(cfg: TrainConfig) -> dict:
    """The version-1 identity, whose hash named the run folders of liquidgs before version 2."""
    d = identity_v2(cfg)
    del d["identity"]
    data = d.pop("data")
    d.update({v1: data[key] for key, v1 in _V1_DATA_KEYS.items()})
    d["field_options"] = {**_V1_FIELD_OPTIONS, **d["field_options"]}
    d["densify"]["split_scale_divisor"] = _V1_SPLIT_SCALE_DIVISOR
    if not cfg.perturb.active:
        del d["perturb"]
    if not cfg.eval.also:
        del d["eval"]["also"]
    if not cfg.densify.max_per_pixel:
        del d["densify"]["max_per_pixel"]
    return d


def legacy_config_hash(cfg: TrainConfig) -> str:
    return _hash(legacy_identity(cfg))


def upgrade_v1(raw: dict) -> dict:
    """A version-1 config.yml (data settings at the top level) in the current shape."""
    raw = dict(raw)
    data = {key: raw.pop(v1) for key, v1 in _V1_DATA_KEYS.items() if v1 in raw}
    raw["data"] = data
    if isinstance(raw.get("field_options"), dict):
        raw["field_options"] = {k: v for k, v in raw["field_options"].items() if k not in _V1_FIELD_OPTIONS}
    if isinstance(raw.get("densify"), dict):
        raw["densify"] = {k: v for k, v in raw["densify"].items() if k != "split_scale_divisor"}
    return raw


def folder_names(cfg: TrainConfig) -> list[str]:
    """The names a run folder of this config may have: its hash, then those of the versions
    before (2, 1), where they differ."""
    return list(dict.fromkeys([config_hash(cfg), _hash(identity_v2(cfg)), legacy_config_hash(cfg)]))


def run_folder(cfg: TrainConfig, parent: Path) -> Path:
    """The folder under `parent` for this run: named by its config hash, or by an older version's
    hash where a run made then is there."""
    names = folder_names(cfg)
    return next((Path(parent) / name for name in names if (Path(parent) / name).exists()), Path(parent) / names[0])


def differing_settings(a: TrainConfig, b: TrainConfig) -> list[str]:
    """The settings of the identity, as dotted names, in which two configurations differ."""
    fa, fb = settings.flatten(identity(a)), settings.flatten(identity(b))
    return sorted(k for k in fa.keys() | fb.keys() if fa.get(k) != fb.get(k))


FIELD_PACKAGE = "field_package"
"""config.yml's record of the package (and version) the field came from: not a setting."""


def save_yaml(cfg: TrainConfig, path: Path) -> None:
    record = {**to_dict(cfg), FIELD_PACKAGE: field_record(cfg.field)}
    write_text_atomic(path, yaml.safe_dump(record, sort_keys=False))


def load_yaml(path: Path) -> TrainConfig:
    raw = settings.load_yaml_file(path, "run config")
    if not isinstance(raw, dict) or "data" not in raw:
        raise ConfigError(f"{path}: not a liquidgs run config (no 'data')")
    check_recorded_field(raw.get("field"), raw.pop(FIELD_PACKAGE, None), path)
    return from_dict(raw, path)


def from_dict(raw: dict, source: Path | str = "config") -> TrainConfig:
    """A TrainConfig from YAML (either version); a setting of the wrong type is one error naming it."""
    if not isinstance(raw.get("data"), dict):
        raw = upgrade_v1(raw)
    if "cameras" not in raw:  # stored before camera refinement existed: trained without it
        raw = {**raw, "cameras": {"refine": "off"}}
    if "motion" not in raw:  # stored before the motion regularisers existed: trained without them
        raw = {**raw, "motion": {"apply": "off"}}
    elif isinstance(raw["motion"], dict):
        if "fixed_sizes" not in raw["motion"]:  # stored before sizes could be held
            raw = {**raw, "motion": {**raw["motion"], "fixed_sizes": False}}
        if "stillness" not in raw["motion"]:  # stored before the stillness term: trained without it
            raw = {**raw, "motion": {**raw["motion"], "stillness": 0.0}}
    if "exposure" not in raw:  # stored before exposure compensation existed: trained without it
        raw = {**raw, "exposure": {"apply": "off"}}
    for group, off in (("flow", {"weight": 0.0}), ("split", {"apply": False})):  # stored before they existed
        if group not in raw:
            raw = {**raw, group: off}
    return settings.from_dict(TrainConfig, raw, source)
