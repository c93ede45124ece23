"""`liquidgs render --run DIR`: look at a trained run.

Writes under DIR/renders (or --out): test/render, test/gt and test/depth PNGs for every test
view; sweep.mp4 (and sweep/ PNGs), time going 0 -> 1 seen from one fixed test camera; and
orbit.mp4, a circle around the scene at --orbit-time.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import tyro
from rich.console import Console
from rich.progress import track

from liquidgs.data import load_dataset
from liquidgs.errors import ConfigError
from liquidgs.media import depth_to_uint8, to_uint8, write_png, write_video
from liquidgs.render.cameras import orbit
from liquidgs.train.model import render_frame
from liquidgs.train.run import TrainedRun, load_run
from liquidgs.train.trainer import data_config


@dataclass
class RenderArgs:
    run: Path
    out: Path | None = None
    """Default: DIR/renders."""
    sweep_frames: int = 48
    sweep_camera: int = 0
    """Index of the test camera the time sweep is seen from."""
    orbit_frames: int = 72
    orbit_time: float = 0.5
    fps: int = 24
    device: str = "auto"


def render_view(run: TrainedRun, viewmat, K, width, height, time, background):
    return render_frame(
        run.at_time(time),
        viewmat,
        K,
        width,
        height,
        sh_degree=run.sh_degree,
        background=background,
        backend=run.config.backend,
    )


def render_run(args: RenderArgs, console: Console | None = None) -> dict[str, Path]:
    if not 0.0 <= args.orbit_time <= 1.0:
        raise ConfigError(f"--orbit-time {args.orbit_time} is outside [0, 1]")
    run = load_run(args.run, args.device)
    dataset = load_dataset(data_config(run.config))
    frames = dataset.test or dataset.train
    if not 0 <= args.sweep_camera < len(frames):
        raise ConfigError(f"--sweep-camera {args.sweep_camera} is not a test view (0..{len(frames) - 1})")
    out = args.out or args.run / "renders"
    background = torch.tensor(dataset.background, dtype=torch.float32)
    quiet = console is None

    for frame in track(frames, description="test views", console=console, disable=quiet):
        result = render_view(run, frame.viewmat, frame.K, frame.width, frame.height, frame.time, background)
        write_png(out / "test" / "render" / f"{frame.name}.png", result.rgb)
        write_png(out / "test" / "gt" / f"{frame.name}.png", frame.image())
        write_png(out / "test" / "depth" / f"{frame.name}.png", depth_to_uint8(result.depth, result.alpha))

    fixed = frames[args.sweep_camera]
    sweep = []
    for i in track(range(args.sweep_frames), description="time sweep", console=console, disable=quiet):
        t = i / max(args.sweep_frames - 1, 1)
        image = to_uint8(render_view(run, fixed.viewmat, fixed.K, fixed.width, fixed.height, t, background).rgb)
        write_png(out / "sweep" / f"{i:04d}.png", image)
        sweep.append(image)
    write_video(out / "sweep.mp4", sweep, fps=args.fps)

    path = orbit(torch.stack([f.viewmat for f in dataset.train]), args.orbit_frames)
    orbit_frames: list[np.ndarray] = []
    for viewmat in track(path, description="orbit", console=console, disable=quiet):
        result = render_view(run, viewmat, fixed.K, fixed.width, fixed.height, args.orbit_time, background)
        orbit_frames.append(to_uint8(result.rgb))
    write_video(out / "orbit.mp4", orbit_frames, fps=args.fps)
    return {"test": out / "test", "sweep": out / "sweep.mp4", "orbit": out / "orbit.mp4"}


def main(argv: list[str]) -> int:
    args = tyro.cli(RenderArgs, args=argv, prog="liquidgs render", description=__doc__)
    console = Console(stderr=True)
    written = render_run(args, console)
    for name, path in written.items():
        console.print(f"{name}: {path}")
    return 0
