"""`liquidgs view --run DIR [--run DIR2 ...]` or `--ply PATH`: look at a scene in the browser.

Serves a viser page (bound to 127.0.0.1 unless --host says otherwise) and prints its URL.
The picture is rendered here, by the project's rasteriser, at the time on the time slider:
play / pause, sweep speed and loop; a free camera and buttons to jump to any training or
test camera (at its frame time) with its ground truth toggled over the render; several runs
of one scene switched or side by side; for an 'sde' run the Monte-Carlo standard deviation
over K noisy passes as a heat map; keyframes (camera + time) saved as a camera_path.json
that `liquidgs render --run DIR --camera-path FILE` turns into a video.

--ply takes an exported PLY, or a folder of them (a PLY sequence, spread over time 0 -> 1).
--benchmark prints the render loop's frame rate as JSON instead of serving.
"""

from __future__ import annotations

import json
import signal
import socket
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import torch
import tyro

from liquidgs.errors import ConfigError
from liquidgs.settings import parse_flags

MAX_PORT = 65535


@dataclass
class ViewArgs:
    run: Annotated[list[Path], tyro.conf.UseAppendAction] = field(default_factory=list)
    """Finished run folder; repeat --run to compare runs of one scene."""
    ply: Path | None = None
    """An exported PLY, or a folder of PLYs (a sequence), instead of runs."""
    host: str = "127.0.0.1"
    """Address to listen on; 0.0.0.0 makes the viewer reachable from other machines."""
    port: int = 8080
    """Port to listen on (the next free one if taken; 0: any free port)."""
    resolution: int = 256
    """Longest side of the picture at rest, in pixels (half of it while the camera moves)."""
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Background colour for --ply (runs use their dataset's)."""
    camera_path: Path | None = None
    """Where "Save camera path" writes. Default: FIRST_RUN/camera_paths/camera_path.json."""
    benchmark: int = 0
    """Print the render loop's frame rate over this many frames as JSON and exit (0: serve)."""
    threads: int | None = None
    """Torch CPU threads for rendering (default: torch's own choice)."""
    device: str = "auto"
    """auto (CUDA where torch sees a GPU, else the CPU), cpu, cuda or cuda:N."""


def check_args(args: ViewArgs) -> None:
    if bool(args.run) == (args.ply is not None):
        raise ConfigError("give --run DIR (one or more) or --ply PATH")
    if not 0 <= args.port <= MAX_PORT:
        raise ConfigError(f"--port must be between 0 and {MAX_PORT}, got {args.port}")
    if not 32 <= args.resolution <= 4096:
        raise ConfigError(f"--resolution must be between 32 and 4096, got {args.resolution}")
    if not all(0.0 <= c <= 1.0 for c in args.background):
        raise ConfigError(f"--background values must be in [0, 1], got {args.background}")
    try:
        infos = socket.getaddrinfo(args.host, None, type=socket.SOCK_STREAM)
        with socket.socket(infos[0][0], socket.SOCK_STREAM) as probe:
            probe.bind((args.host, 0))
    except OSError as err:
        raise ConfigError(f"--host {args.host}: cannot listen there ({err.strerror or err})") from None
    if args.threads is not None and args.threads < 1:
        raise ConfigError(f"--threads must be at least 1, got {args.threads}")
    if args.benchmark < 0:
        raise ConfigError(f"--benchmark must be 0 or a number of frames, got {args.benchmark}")


def load_scenes(args: ViewArgs):
    from liquidgs.viewer.scenes import PlyScene, load_runs

    if args.run:
        return load_runs(args.run, args.device)
    return [PlyScene(args.ply, torch.tensor(args.background, dtype=torch.float32))]


def main(argv: list[str]) -> int:
    args = parse_flags(ViewArgs, argv, prog="liquidgs view", description=__doc__)
    check_args(args)
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    scenes = load_scenes(args)  # every input error is raised here, before the server starts

    from liquidgs.viewer.server import Viewer

    try:
        viewer = Viewer(scenes, args.host, args.port, args.resolution, args.camera_path)
    except OSError as err:
        raise ConfigError(f"cannot listen on {args.host}:{args.port} ({err.strerror or err})") from None
    if args.benchmark:
        from liquidgs.viewer.benchmark import benchmark_viewer

        try:
            print(json.dumps(benchmark_viewer(viewer, args.benchmark), indent=2))
        finally:
            viewer.stop()
        return 0

    stop = threading.Event()
    # Handlers rather than KeyboardInterrupt: a shell's background job starts with SIGINT ignored.
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.set())
    print(f"liquidgs view: open {viewer.url} in a browser (Ctrl-C stops)", flush=True)
    while not stop.wait(0.5):
        pass
    viewer.stop()
    print("liquidgs view: stopped", flush=True)
    return 0
