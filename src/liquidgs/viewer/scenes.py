"""What the viewer can show: trained runs (Gaussians + deformation field) and exported PLYs.

Everything here is loaded and checked before the server starts, so bad input is one line.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import torch

from liquidgs.cameras import Camera
from liquidgs.errors import LiquidGSError
from liquidgs.gaussians import activate, read_ply, read_ply_comments
from liquidgs.render import rasterize
from liquidgs.train.run import TrainedRun, load_run
from liquidgs.train.run_folder import check_source, same_source, source_in_comments

SPLIT_COLOURS = torch.tensor([[0.2, 0.45, 1.0], [1.0, 0.5, 0.05]])
"""The static / dynamic view's flat colours: static Gaussians blue, dynamic ones orange."""


class RunScene:
    """A finished liquidgs run: renders through its deformation field at any time in [0, 1]."""

    def __init__(self, run: TrainedRun, label: str):
        self.run = run
        self.label = label
        self.dataset = run.scene()
        self.background = torch.tensor(self.dataset.background, dtype=torch.float32)

    @property
    def has_noise(self) -> bool:
        return self.run.config.field == "sde" and self.run.field is not None  # baked: the mean only

    @property
    def has_split(self) -> bool:
        """Whether the run labels its Gaussians static or dynamic (train.dynamic_split; a baked scene
        keeps no labels)."""
        return getattr(self.run, "moving", None) is not None

    @torch.no_grad()
    def render(self, camera: Camera, time: float) -> torch.Tensor:
        return self.run.render(camera, time, self.background).rgb

    @torch.no_grad()
    def render_split(self, camera: Camera, time: float) -> torch.Tensor:
        """The scene at `time` with each Gaussian in its label's flat colour (SPLIT_COLOURS)."""
        g = self.run.at_time(time)
        dynamic = torch.zeros(g.means.shape[0], dtype=torch.long, device=g.means.device)
        dynamic[self.run.moving] = 1
        colours = SPLIT_COLOURS.to(g.means)[dynamic]
        return rasterize(
            g.means, g.quats, g.scales, g.opacities, colours, camera.viewmat.to(g.means), camera.K.to(g.means),
            camera.width, camera.height, sh_degree=None, background=self.background.to(g.means),
            backend=self.run.config.backend,
        ).rgb  # fmt: skip

    @torch.no_grad()
    def uncertainty(self, camera: Camera, time: float, samples: int) -> torch.Tensor:
        """Per-pixel Monte-Carlo standard deviation [H,W] (the estimate `liquidgs render` writes)."""
        _, std = self.run.monte_carlo(camera, time, self.background, samples)
        return std


class PlyScene:
    """An exported PLY, or a PLY sequence (a folder of *.ply) spread evenly over time [0, 1]."""

    has_noise = False
    has_split = False

    def __init__(self, path: Path, background: torch.Tensor):
        self.label = path.name
        self.background = background
        files = ply_files(path)
        check_ply_sources(files)
        self.frames = [activate(read_ply(f)) for f in files]
        bases = {f["colors"].shape[1] for f in self.frames}
        if len(bases) != 1:
            raise LiquidGSError(f"{path}: the PLY files hold different numbers of SH coefficients ({sorted(bases)})")
        self.sh_degree = math.isqrt(bases.pop()) - 1
        self.files = files

    def frame_at(self, time: float) -> dict[str, torch.Tensor]:
        return self.frames[round(time * (len(self.frames) - 1))]

    @torch.no_grad()
    def render(self, camera: Camera, time: float) -> torch.Tensor:
        g = self.frame_at(time)
        return rasterize(
            g["means"], g["quats"], g["scales"], g["opacities"], g["colors"], camera.viewmat, camera.K,
            camera.width, camera.height, sh_degree=self.sh_degree, background=self.background,
        ).rgb  # fmt: skip


def check_ply_sources(files: list[Path]) -> None:
    """The frames of a sequence come from one run, and that run (where it still is) has not trained
    past them; a PLY without a source record (another tool's) is read as it is."""
    sources = [source_in_comments(read_ply_comments(f)) for f in files]
    for file, source in zip(files[1:], sources[1:], strict=True):
        if not same_source(source, sources[0]):
            raise LiquidGSError(f"{file}: from another run or checkpoint than {files[0]}; a sequence mixes two")
    if sources[0] is not None:
        check_source(files[0], sources[0], again="export it again")


def ply_files(path: Path) -> list[Path]:
    """The PLY itself, or a folder's *.ply in frame order (numbers compared as numbers)."""
    if not path.exists():
        raise LiquidGSError(f"{path}: does not exist")
    if path.is_file():
        return [path]
    files = sorted(path.glob("*.ply"), key=lambda p: [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", p.name)])
    if not files:
        raise LiquidGSError(f"{path}: no .ply files in this folder")
    return files


def load_runs(run_dirs: list[Path], device: str = "auto") -> list[RunScene]:
    """Finished runs of one scene; anything else is refused before the server starts."""
    scenes = []
    for run_dir in run_dirs:
        run = load_run(run_dir, device)
        if not run.finished:
            raise LiquidGSError(f"{run_dir}: not a finished liquidgs run ({run.progress_label})")
        kind = run.config.field if run.field is not None else f"{run.config.field}, baked"
        label = f"{len(scenes) + 1}: {kind} ({run_dir.name})"
        run.at_time(0.5)  # a diverged run is refused here, not frame by frame in the browser
        scene = RunScene(run, label)
        if scenes and scene.run.config.data.path != scenes[0].run.config.data.path:
            raise LiquidGSError(
                f"{run_dir}: trained on {scene.run.config.data.path}, but {run_dirs[0]} on "
                f"{scenes[0].run.config.data.path}; the viewer compares runs of one scene"
            )
        scenes.append(scene)
    return scenes


def scene_centre_and_radius(points: torch.Tensor) -> tuple[np.ndarray, float]:
    """Median point and the 90th-percentile distance from it (robust to stray Gaussians)."""
    centre = points.median(dim=0).values
    radius = float(torch.quantile((points - centre).norm(dim=1), 0.9))
    return centre.double().numpy(), max(radius, 1e-3)
