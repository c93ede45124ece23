"""A baked scene: a folder that `render`, `eval`, `view` and `export` read like a run, rendered
without evaluating any network.

    config.yml    the source run's configuration, as it was (dataset, background, backend)
    scene.pt      canonical Gaussians (the run's parameters) and the keyframes [K, N, 10]
    baked.json    what was baked, from which run, and the measured error (BAKED_FORMAT); written
                  last, it marks the folder a baked scene
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import torch

from liquidgs.bake.motion import CHANNELS, POSITION, QUATERNION, SCALE, interpolate
from liquidgs.cameras import Camera
from liquidgs.errors import LiquidGSError
from liquidgs.gaussians import PARAM_KEYS
from liquidgs.gaussians.model import activate
from liquidgs.train.config import TrainConfig, load_yaml
from liquidgs.train.model import Deformed, render_frame

MANIFEST = "baked.json"
SCENE = "scene.pt"
BAKED_FORMAT = "liquidgs-baked/1"


def is_baked(folder: Path) -> bool:
    return (folder / MANIFEST).is_file()


@dataclass
class BakedRun:
    """The interface of train.run.TrainedRun that readers use, served from keyframes."""

    run_dir: Path
    config: TrainConfig
    params: torch.nn.ParameterDict
    keyframes: torch.Tensor
    """[K, N, 10] at motion.keyframe_times(K): position, unit quaternion, scale."""
    sh_degree: int
    iteration: int
    manifest: dict
    field = None
    """No network: readers that need one (field.pt, Monte-Carlo noise) check for None."""
    finished = True
    """bake reads finished runs only."""

    @property
    def progress_label(self) -> str:
        return f"baked scene of {self.manifest['source_run']} (iteration {self.iteration})"

    @property
    def device(self) -> torch.device:
        return self.params["means"].device

    @torch.no_grad()
    def at_time(self, time: float) -> Deformed:
        state = interpolate(self.keyframes, time)
        act = self._activated
        return Deformed(state[:, POSITION], state[:, QUATERNION], state[:, SCALE], act["opacities"], act["colors"])

    @property
    def _activated(self) -> dict[str, torch.Tensor]:
        if not hasattr(self, "_activated_cache"):
            self._activated_cache = activate(self.params)
        return self._activated_cache

    def render(self, camera: Camera, time: float, background, noisy: bool = False):
        if noisy:
            raise LiquidGSError(f"{self.run_dir}: a baked scene has no noise to sample (it holds the field's mean)")
        return render_frame(
            self.at_time(time), camera, sh_degree=self.sh_degree, background=background, backend=self.config.backend
        )


def read_manifest(folder: Path) -> dict:
    path = folder / MANIFEST
    try:
        manifest = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise LiquidGSError(f"{path}: unreadable ({err})") from None
    if not isinstance(manifest, dict) or manifest.get("format") != BAKED_FORMAT:
        found = manifest.get("format") if isinstance(manifest, dict) else None
        raise LiquidGSError(f"{path}: format {found!r} is not {BAKED_FORMAT!r}")
    return manifest


def load_baked(folder: str | Path, device: str | torch.device = "cpu") -> BakedRun:
    folder = Path(folder)
    manifest = read_manifest(folder)
    cfg = load_yaml(folder / "config.yml")
    try:
        payload = torch.load(folder / SCENE, map_location=device, weights_only=True)
        params = torch.nn.ParameterDict(
            {k: torch.nn.Parameter(payload["params"][k].float(), requires_grad=False) for k in PARAM_KEYS}
        )
        keyframes = payload["keyframes"].float()
    except (OSError, RuntimeError, KeyError, TypeError) as err:
        raise LiquidGSError(f"{folder / SCENE}: unreadable baked scene ({err})") from None
    n = params["means"].shape[0]
    if keyframes.ndim != 3 or keyframes.shape[1:] != (n, CHANNELS) or keyframes.shape[0] < 1:
        raise LiquidGSError(f"{folder / SCENE}: keyframes {tuple(keyframes.shape)} do not fit {n} Gaussians")
    return BakedRun(folder, cfg, params, keyframes, int(manifest["sh_degree"]), int(manifest["iteration"]), manifest)
