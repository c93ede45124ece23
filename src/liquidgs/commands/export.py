"""`liquidgs export --run DIR`: PLY files that standard 3DGS viewers open.

Writes DIR/export/canonical.ply, field.pt (the field's weights and config, to evaluate it
elsewhere), one PLY per --time with the deltas baked in, and with --sequence N a PLY
sequence sequence/frame_0000.ply ... at N evenly spaced times (SuperSplat/brush timelines).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import torch
from rich.console import Console
from rich.progress import track

from liquidgs.atomic import write_atomic
from liquidgs.errors import ConfigError
from liquidgs.gaussians import write_ply
from liquidgs.settings import parse_flags
from liquidgs.train.run import TrainedRun, load_run


@dataclass
class ExportArgs:
    run: Path
    out: Path | None = None
    """Default: DIR/export."""
    time: list[float] = field(default_factory=list)
    """Times in [0,1] to export a deformed PLY for."""
    sequence: int = 0
    """Number of evenly spaced frames of a PLY sequence (0: none)."""
    device: str = "auto"


def baked_params(run: TrainedRun, time: float) -> dict[str, torch.Tensor]:
    """The deformed Gaussians at `time` in PLY parameter form.

    The rasteriser uses the absolute value of each scale (only its square enters the
    covariance), so a scale pushed below zero by d_scaling is stored as log|s|.
    """
    g = run.at_time(time)
    return {
        "means": g.means,
        "scales": torch.log(g.scales.abs().clamp_min(1e-12)),
        "quats": torch.nn.functional.normalize(g.quats, dim=-1),
        "opacities": run.params["opacities"],
        "sh0": run.params["sh0"],
        "shN": run.params["shN"],
    }


MAX_SEQUENCE = 100_000


def time_file_name(time: float) -> str:
    return f"time_{time + 0.0:.4f}.ply"  # + 0.0 turns -0.0 into 0.0


def export_run(args: ExportArgs, console: Console | None = None) -> list[Path]:
    names: dict[str, float] = {}
    for t in args.time:
        if not (math.isfinite(t) and 0.0 <= t <= 1.0):
            raise ConfigError(f"--time {t} is outside [0, 1]")
        name = time_file_name(t)
        if name in names and names[name] != t:
            raise ConfigError(f"--time {names[name]} and {t} would both be written to {name}")
        names[name] = t
    if not 0 <= args.sequence <= MAX_SEQUENCE:
        raise ConfigError(f"--sequence must be between 0 and {MAX_SEQUENCE}, got {args.sequence}")
    run = load_run(args.run, args.device)
    if console is not None and not run.finished:
        console.print(f"[yellow]note:[/] {args.run}: {run.progress_label}")
    out = args.out or args.run / "export"
    written = [write_ply(out / "canonical.ply", run.params)]
    if run.field is not None:  # a baked scene has no network
        payload = {"config": dataclasses.asdict(run.config.field_config()), "state_dict": run.field.state_dict()}
        written.append(write_atomic(out / "field.pt", lambda tmp: torch.save(payload, tmp)))
    for t in args.time:
        written.append(write_ply(out / time_file_name(t), baked_params(run, t)))
    if args.sequence:
        times = [i / max(args.sequence - 1, 1) for i in range(args.sequence)]
        for i, t in enumerate(track(times, description="PLY sequence", console=console, disable=console is None)):
            written.append(write_ply(out / "sequence" / f"frame_{i:04d}.ply", baked_params(run, t)))
    return written


def main(argv: list[str]) -> int:
    args = parse_flags(ExportArgs, argv, prog="liquidgs export", description=__doc__)
    console = Console(stderr=True)
    written = export_run(args, console)
    console.print(f"wrote {len(written)} files under {written[0].parent}")
    return 0
