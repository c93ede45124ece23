"""Loading a trained run (config.yml + checkpoint.pt) and its scene for evaluation, rendering and export;
the trainer sets up its device and scene with the same functions."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import torch

from liquidgs.cameras import Camera
from liquidgs.data import SceneDataset
from liquidgs.errors import ConfigError, LiquidGSError, check_finite
from liquidgs.fields import build_field
from liquidgs.gaussians import PARAM_KEYS
from liquidgs.train.config import TrainConfig, config_hash, load_yaml
from liquidgs.train.dataset import load_run_dataset
from liquidgs.train.dynamic_split import DYNAMIC, moving_indices, split_applies
from liquidgs.train.model import Deformed, deform, hold_sizes, render_frame
from liquidgs.train.run_folder import (
    CHECKPOINT,
    CONFIG,
    FAILURE,
    RESULTS,
    check_scene_print,
    read_checkpoint,
    source_record,
)


@dataclass
class TrainedRun:
    run_dir: Path
    config: TrainConfig
    params: torch.nn.ParameterDict
    field: torch.nn.Module
    sh_degree: int
    iteration: int
    finished: bool
    """results.json, the run's only done marker, exists and the checkpoint is at the last iteration."""
    moving: torch.Tensor | None = None
    """Indices of the Gaussians the field moves (train.dynamic_split); None: all of them."""

    @property
    def progress_label(self) -> str:
        """Where the checkpoint stands: readers accept runs in progress but say so."""
        if self.finished:
            return f"finished run, iteration {self.iteration}"
        if (self.run_dir / FAILURE).is_file():
            return f"failed run (why: {self.run_dir / FAILURE}): checkpoint at iteration {self.iteration}"
        return f"unfinished run: checkpoint at iteration {self.iteration} of {self.config.iterations}"

    @property
    def device(self) -> torch.device:
        return self.params["means"].device

    def source(self) -> dict:
        """The source record of a file derived from this run's checkpoint (run_folder.provenance)."""
        return source_record(self.run_dir, config_hash(self.config), self.iteration, self.run_dir / CHECKPOINT)

    def scene(self) -> SceneDataset:
        """The scene the run renders, refused in one line where it differs from the one it trained on."""
        check_scene_print(self.run_dir, self.config.data.path)
        return load_run_dataset(self.config)

    @torch.no_grad()
    def at_time(self, time: float) -> Deformed:
        """The Gaussians at `time`; a diverged run (NaN or infinity in them) is one line, not a score."""
        field = self.field if self.config.field != "static" else None
        gaussians = deform(self.params, field, time, moving=self.moving)
        check_finite(self.run_dir, f"the Gaussians at time {time:g}", vars(gaussians))
        return gaussians

    @torch.no_grad()
    def sample_at_time(self, time: float) -> Deformed:
        """One noisy deformation (the field's training-time noise, at the run's final step)."""
        with self.field.noise_on():
            return self.at_time(time)

    def render(self, camera: Camera, time: float, background, noisy: bool = False):
        """The scene at `time` from `camera`; noisy=True draws one Monte-Carlo sample of the field."""
        gaussians = self.sample_at_time(time) if noisy else self.at_time(time)
        return render_frame(
            gaussians, camera, sh_degree=self.sh_degree, background=background, backend=self.config.backend
        )

    @torch.no_grad()
    def monte_carlo(self, camera: Camera, time: float, background, samples: int):
        """Per-pixel mean [H,W,3] and standard deviation (mean over RGB) [H,W] of `samples` noisy renders."""
        total = torch.zeros(camera.height, camera.width, 3)
        total_sq = torch.zeros_like(total)
        for _ in range(samples):
            rgb = self.render(camera, time, background, noisy=True).rgb.cpu()
            total += rgb
            total_sq += rgb * rgb
        mean = total / samples
        variance = (total_sq - samples * mean * mean).clamp_min(0) / (samples - 1)
        return mean, variance.sqrt().mean(dim=-1)


def load_run(run_dir: str | Path, device: str = "auto") -> TrainedRun:
    """The run at run_dir, or a baked scene (bake.scene.BakedRun, the same interface, field None)."""
    run_dir = Path(run_dir)
    if not run_dir.exists():
        raise LiquidGSError(f"{run_dir}: does not exist")
    if not run_dir.is_dir():
        raise LiquidGSError(f"{run_dir}: is a file, not a run folder")
    from liquidgs.bake.scene import is_baked, load_baked  # bake imports this module

    if is_baked(run_dir):  # a baked scene reads like a run, without its network
        return load_baked(run_dir, resolve_device(device))
    if not (run_dir / CONFIG).is_file():
        raise LiquidGSError(f"{run_dir}: not a liquidgs run folder (no {CONFIG})")
    if not (run_dir / CHECKPOINT).is_file():
        raise LiquidGSError(f"{run_dir}: the run has no checkpoint yet ({CHECKPOINT})")
    cfg = load_yaml(run_dir / CONFIG)
    dev = resolve_device(device if device != "auto" else cfg.device)
    payload = read_checkpoint(run_dir / CHECKPOINT)
    params = torch.nn.ParameterDict(
        {k: torch.nn.Parameter(payload["params"][k].to(dev), requires_grad=False) for k in PARAM_KEYS}
    )
    field = build_field(cfg.field_config())
    try:
        field.load_state_dict(payload["field"])
    except RuntimeError as err:  # weights of another field than config.yml describes
        raise LiquidGSError(f"{run_dir / CHECKPOINT}: corrupt or unreadable checkpoint ({err})") from None
    state = payload["state"]
    if payload.get("sizes_held", False):  # trained with the size deltas dropped (motion.fixed_sizes)
        hold_sizes(field)
    field = field.to(dev).eval()
    field.set_progress(int(state["iteration"]))  # annealed noise schedules resume where training ended
    iteration = int(state["iteration"])
    finished = (run_dir / RESULTS).is_file() and iteration == cfg.iterations
    moving = None
    if split_applies(cfg.split, cfg.field):
        labels = payload["strategy"].get(DYNAMIC)
        if labels is None or labels.shape != params["means"].shape[:1]:
            raise LiquidGSError(f"{run_dir / CHECKPOINT}: no static/dynamic label for each Gaussian (split.apply)")
        moving = moving_indices(labels.bool()).to(dev)
    return TrainedRun(run_dir, cfg, params, field, int(state["sh_degree"]), iteration, finished, moving)


DEFAULT_THREADS = 1
"""A training process's torch threads unless OMP_NUM_THREADS says otherwise: one, so that a run
scores the same on any machine and `liquidgs train` and `experiment run` (one run per core) agree."""


def training_threads() -> int:
    """The torch intra-op threads (the compiled CPU kernels use as many) `liquidgs train` runs with:
    OMP_NUM_THREADS when set, else DEFAULT_THREADS."""
    value = os.environ.get("OMP_NUM_THREADS", "").strip()
    if not value:
        return DEFAULT_THREADS
    if not value.isdigit() or int(value) < 1:
        raise ConfigError(f"OMP_NUM_THREADS={value!r}: the thread count must be a positive integer")
    return int(value)


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except RuntimeError:
        raise ConfigError(f"unknown device '{name}' (auto, cpu, cuda or cuda:N)") from None
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device '{name}' asked for, but this torch sees no CUDA device")
    return device
