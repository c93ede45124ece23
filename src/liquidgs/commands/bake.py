"""`liquidgs bake --run DIR [--out BAKED]`: distil a finished run's deformation field into explicit
per-Gaussian motion that renders without the network.

The field is sampled at uniform keyframe times over the capture's time range; between them each
Gaussian's position, rotation and scale follow a Catmull-Rom spline (rotation renormalised).
Keyframes double (9, 17, 33, ...) until every visible Gaussian (opacity >= 1/255) stays within
--tolerance half-way between keyframes, measured against the field: position and scale error as a
fraction of the Gaussian's largest axis, rotation error in radians. Past --max-keyframes the scene
is baked anyway, with a warning naming the Gaussians and times over budget (all in baked.json).

BAKED (default DIR/baked) is read by `render`, `eval`, `view` and `export` in place of a run
folder. It is built in a hidden folder beside BAKED and renamed into place when complete.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import torch
from rich.console import Console

from liquidgs.atomic import write_atomic, write_json_atomic
from liquidgs.bake.distil import BakeSettings, check_finished, describe_over_budget, distil
from liquidgs.bake.motion import CHANNELS
from liquidgs.bake.scene import BAKED_FORMAT, MANIFEST, SCENE, is_baked, read_manifest
from liquidgs.data.capture import build_atomically, refuse_taken
from liquidgs.errors import ConfigError, LiquidGSError, check_finite
from liquidgs.gaussians import PARAM_KEYS
from liquidgs.settings import parse_flags
from liquidgs.train.run import load_run
from liquidgs.train.run_folder import CONFIG

MAX_KEYFRAMES = 1025
"""The most keyframes (--max-keyframes): 16x the default 65, four doublings past it; bake's time and
the baked scene's bytes grow with them."""


@dataclass
class BakeArgs:
    run: Path
    """A finished run folder."""
    out: Path | None = None
    """Default: DIR/baked."""
    tolerance: float = BakeSettings.tolerance
    """Error budget half-way between keyframes (fraction of the Gaussian's size; radians)."""
    min_keyframes: int = BakeSettings.min_keyframes
    """Keyframes to start from (at least 2)."""
    max_keyframes: int = BakeSettings.max_keyframes
    """Keyframes the doubling stops at, at most 1,025 (MAX_KEYFRAMES)."""
    device: str = "auto"


def check_args(args: BakeArgs) -> Path:
    if not 0.0 < args.tolerance < 1.0:
        raise ConfigError(f"--tolerance must be in (0, 1), got {args.tolerance}")
    if not 2 <= args.min_keyframes <= args.max_keyframes <= MAX_KEYFRAMES:
        raise ConfigError(
            f"--min-keyframes and --max-keyframes must satisfy 2 <= min <= max <= {MAX_KEYFRAMES}, "
            f"got {args.min_keyframes} and {args.max_keyframes}"
        )
    if is_baked(args.run):
        source = read_manifest(args.run).get("source_run", "the run it came from")
        raise LiquidGSError(f"{args.run}: a baked scene, not a run; bake the run it came from ({source})")
    out = args.out or args.run / "baked"
    refuse_taken(out)
    return out


def bake(args: BakeArgs, console: Console | None = None) -> dict:
    out = check_args(args)
    run = load_run(args.run, args.device)
    check_finished(run, "bake")
    settings = BakeSettings(args.tolerance, args.min_keyframes, args.max_keyframes)
    distilled = distil(run, settings)
    payload = {
        "params": {k: run.params[k].detach().cpu().contiguous() for k in PARAM_KEYS},
        "keyframes": distilled.keyframes.contiguous(),
    }
    check_finite(args.run, "the Gaussians and their keyframes", [*payload["params"].values(), payload["keyframes"]])
    n = run.params["means"].shape[0]
    manifest = {
        "format": BAKED_FORMAT,
        "source_run": str(args.run.resolve()),
        "field": run.config.field,
        "iteration": run.iteration,
        "sh_degree": run.sh_degree,
        "gaussians": n,
        "keyframes": distilled.keyframes.shape[0],
        "keyframe_times": "uniform over [0, 1], the capture's normalised time range",
        "interpolation": "Catmull-Rom per channel (position, wxyz quaternion renormalised, scale)",
        "channels": CHANNELS,
        "error": distilled.report,
    }

    def build(folder: Path) -> None:
        shutil.copyfile(args.run / CONFIG, folder / CONFIG)
        write_atomic(folder / SCENE, lambda tmp: torch.save(payload, tmp))
        manifest["bytes_per_gaussian"] = (folder / SCENE).stat().st_size / n
        write_json_atomic(folder / MANIFEST, manifest)  # last: it marks the folder a baked scene

    build_atomically(out, build)
    if distilled.over_budget and console is not None:
        console.print(f"[yellow]warning:[/] {describe_over_budget(distilled.report, n)}; listed in {out / MANIFEST}")
    return {**manifest, "out": str(out)}


def main(argv: list[str]) -> int:
    args = parse_flags(BakeArgs, argv, prog="liquidgs bake", description=__doc__)
    console = Console(stderr=True)
    record = bake(args, console)
    error = record["error"]
    console.print(
        f"baked {record['gaussians']:,} Gaussians x {record['keyframes']} keyframes "
        f"({record['bytes_per_gaussian']:.0f} bytes per Gaussian); midpoint error: max "
        f"{error['max_relative_error']:.3g} of a Gaussian's size, max position {error['max_position_error']:.3g} "
        f"scene units -> {record['out']}",
        highlight=False,
        soft_wrap=True,
    )
    return 0
