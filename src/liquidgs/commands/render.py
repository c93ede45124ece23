"""`liquidgs render --run DIR`: look at a trained run.

Writes under DIR/renders (or --out): test/render, test/gt and test/depth PNGs for every test
view; sweep.mp4 (and sweep/ PNGs), time going 0 -> 1 seen from one fixed test camera; and
orbit.mp4, a circle around the scene at --orbit-time.

With --uncertainty-samples K (the 'sde' field), every test view is also rendered K times
with the field's noise on: test/mc_mean holds the per-pixel mean and test/uncertainty the
per-pixel standard deviation (mean over RGB, scaled so that white = the largest value over
all views); uncertainty.json lists each view's mean and max standard deviation.

With --camera-path FILE (nerfstudio's camera_path.json with a render_time per camera, as the
viewer's keyframe recorder writes it) only that path is rendered, to <FILE stem>.mp4.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from rich.console import Console
from rich.progress import track

from liquidgs.atomic import write_json_atomic
from liquidgs.cameras import orbit
from liquidgs.errors import ConfigError
from liquidgs.media import depth_to_uint8, to_uint8, write_png, write_video
from liquidgs.render.camera_path import CameraPath, read_camera_path
from liquidgs.settings import parse_flags
from liquidgs.train.run import TrainedRun, load_run

MAX_FRAMES = 100_000
MAX_SAMPLES = 1024
"""The most --uncertainty-samples: 64x the 16 the docs use; each is one more render of every test view."""


@dataclass
class RenderArgs:
    run: Path
    """A run folder, or a baked scene (`liquidgs bake`)."""
    out: Path | None = None
    """Default: DIR/renders."""
    sweep_frames: int = 48
    """Frames of the time sweep (sweep.mp4), from one test camera over [0, 1]."""
    sweep_camera: int = 0
    """Index of the test camera the time sweep is seen from."""
    orbit_frames: int = 72
    """Frames of the orbit around the scene (orbit.mp4)."""
    orbit_time: float = 0.5
    """The time in [0, 1] the orbit shows."""
    fps: int = 24
    """Frames per second of the videos (1 to 240)."""
    uncertainty_samples: int = 0
    """Monte-Carlo passes per test view for uncertainty maps (0: none, else 2 and at most 1,024;
    needs the 'sde' field)."""
    camera_path: Path | None = None
    """A camera_path.json to render to video instead of the test views, sweep and orbit."""
    device: str = "auto"
    """auto (CUDA where torch sees a GPU, else the CPU), cpu, cuda or cuda:N."""


@torch.no_grad()
def monte_carlo_views(run: TrainedRun, frames, samples: int, background, out: Path, console) -> Path:
    """Per-pixel mean and standard deviation of `samples` noisy renders of every test view."""
    stats = {}
    for frame in track(frames, description="uncertainty", console=console, disable=console is None):
        stats[frame.name] = run.monte_carlo(frame.camera, frame.time, background, samples)
    peak = max(float(std.max()) for _, std in stats.values()) or 1.0
    with run.field.noise_on():
        noise_level = run.field.current_lambda()
    summary = {"samples": samples, "lambda": noise_level, "white_is_std": peak, "views": {}}
    for name, (mean, std) in stats.items():
        write_png(out / "test" / "mc_mean" / f"{name}.png", mean)
        write_png(out / "test" / "uncertainty" / f"{name}.png", (std / peak)[..., None].expand(-1, -1, 3))
        summary["views"][name] = {"mean_std": float(std.mean()), "max_std": float(std.max())}
    return write_json_atomic(out / "uncertainty.json", summary)


def render_camera_path(run: TrainedRun, camera_path: CameraPath, background, video: Path, console) -> Path:
    """The camera path's frames, each at its own render_time, as an mp4."""
    width, height = camera_path.width, camera_path.height
    images = []
    for camera in track(camera_path.frames, description="camera path", console=console, disable=console is None):
        result = run.render(camera.camera(width, height), camera.time, background)
        images.append(to_uint8(result.rgb))
    return write_video(video, images, fps=round(camera_path.fps))


def render_run(args: RenderArgs, console: Console | None = None) -> dict[str, Path]:
    if not 0.0 <= args.orbit_time <= 1.0:
        raise ConfigError(f"--orbit-time {args.orbit_time} is outside [0, 1]")
    if not (args.uncertainty_samples == 0 or 2 <= args.uncertainty_samples <= MAX_SAMPLES):
        raise ConfigError(f"--uncertainty-samples must be 0 or 2 to {MAX_SAMPLES:,}, got {args.uncertainty_samples:,}")
    for flag, value in (("--sweep-frames", args.sweep_frames), ("--orbit-frames", args.orbit_frames)):
        if not 1 <= value <= MAX_FRAMES:
            raise ConfigError(f"{flag} must be between 1 and {MAX_FRAMES}, got {value}")
    if not 1 <= args.fps <= 240:
        raise ConfigError(f"--fps must be between 1 and 240, got {args.fps}")
    camera_path = read_camera_path(args.camera_path) if args.camera_path is not None else None
    run = load_run(args.run, args.device)
    if console is not None and not run.finished:
        console.print(f"[yellow]note:[/] {args.run}: {run.progress_label}")
    if args.uncertainty_samples and run.config.field != "sde":
        raise ConfigError(f"--uncertainty-samples needs a run of the 'sde' field; {args.run} used '{run.config.field}'")
    if args.uncertainty_samples and run.field is None:
        raise ConfigError(f"--uncertainty-samples needs the field's noise; {args.run} is a baked scene (its mean)")
    dataset = run.scene()
    frames = dataset.test or dataset.train
    if not 0 <= args.sweep_camera < len(frames):
        raise ConfigError(f"--sweep-camera {args.sweep_camera} is not a test view (0..{len(frames) - 1})")
    run.at_time(frames[0].time)  # a diverged run: its one line before any progress bar or file
    out = args.out or args.run / "renders"
    background = torch.tensor(dataset.background, dtype=torch.float32)
    if camera_path is not None:
        video = out / f"{args.camera_path.stem}.mp4"
        return {"camera_path": render_camera_path(run, camera_path, background, video, console)}
    quiet = console is None

    for frame in track(frames, description="test views", console=console, disable=quiet):
        result = run.render(frame.camera, frame.time, background)
        write_png(out / "test" / "render" / f"{frame.name}.png", result.rgb)
        if frame.image_path.is_file():  # a baked scene away from its scene folder has cameras, no images
            write_png(out / "test" / "gt" / f"{frame.name}.png", frame.image())
        write_png(out / "test" / "depth" / f"{frame.name}.png", depth_to_uint8(result.depth, result.alpha))

    fixed = frames[args.sweep_camera]
    sweep = []
    for i in track(range(args.sweep_frames), description="time sweep", console=console, disable=quiet):
        t = i / max(args.sweep_frames - 1, 1)
        image = to_uint8(run.render(fixed.camera, t, background).rgb)
        write_png(out / "sweep" / f"{i:04d}.png", image)
        sweep.append(image)
    write_video(out / "sweep.mp4", sweep, fps=args.fps)

    path = orbit(torch.stack([f.camera.viewmat for f in dataset.train]), args.orbit_frames)
    orbit_frames: list[np.ndarray] = []
    for viewmat in track(path, description="orbit", console=console, disable=quiet):
        result = run.render(dataclasses.replace(fixed.camera, viewmat=viewmat), args.orbit_time, background)
        orbit_frames.append(to_uint8(result.rgb))
    write_video(out / "orbit.mp4", orbit_frames, fps=args.fps)
    written = {"test": out / "test", "sweep": out / "sweep.mp4", "orbit": out / "orbit.mp4"}
    if args.uncertainty_samples:
        written["uncertainty"] = monte_carlo_views(run, frames, args.uncertainty_samples, background, out, console)
    return written


def main(argv: list[str]) -> int:
    args = parse_flags(RenderArgs, argv, prog="liquidgs render", description=__doc__)
    console = Console(stderr=True)
    written = render_run(args, console)
    for name, path in written.items():
        console.print(f"{name}: {path}")
    return 0
