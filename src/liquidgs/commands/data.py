"""`liquidgs data {synth,check}`: generate built-in synthetic scenes, validate dataset folders."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import tyro

from liquidgs.args import parse_args
from liquidgs.data import DataConfig, check_dataset, generate_synthetic
from liquidgs.errors import ConfigError


@dataclass
class SynthArgs:
    """Render a built-in synthetic dynamic scene in both the D-NeRF and the Nerfies layout."""

    scene: str
    """Scene name, one of liquidgs.data.SYNTHETIC_SCENES: puppet (fast articulated motion, the
    default scene of the demo) or spinner (slow rigid motion)."""
    out: Path
    """Output folder; gets dnerf/ and nerfies/ subfolders."""
    size: int = 128
    """Image width and height in pixels."""
    frames: int = 80
    """Total frames (train, val and test interleaved in time)."""
    seed: int = 0
    """Seed of the random camera positions."""


@dataclass
class CheckArgs:
    """Validate a dataset folder (every JSON field, every image fully decoded) and summarise it."""

    path: tyro.conf.Positional[Path]
    """Scene folder."""
    format: Literal["auto", "dnerf", "nerfies"] = "auto"
    """Dataset format; auto detects it from the files in the folder."""
    split: Literal["auto", "nerfds", "vrig", "interp"] = "auto"
    """Nerfies split preset (auto = nerfds)."""
    downscale: int | None = None
    """Image downscale factor (default: 1 for D-NeRF, the split preset's for Nerfies)."""
    background: Literal["black", "white"] = "black"
    """Background colour RGBA images are composited on."""
    val_as_test: bool = False
    """D-NeRF: use the val split as test."""


MAX_SIZE = 4096
MAX_FRAMES = 10_000


def synth(args: SynthArgs) -> int:
    if not 8 <= args.size <= MAX_SIZE or not 8 <= args.frames <= MAX_FRAMES:
        raise ConfigError(
            f"--size must be between 8 and {MAX_SIZE} and --frames between 8 and {MAX_FRAMES}, "
            f"got {args.size} and {args.frames}"
        )
    if args.seed < 0:
        raise ConfigError(f"--seed must be >= 0, got {args.seed}")
    out_dir = generate_synthetic(args.scene, args.out, size=args.size, frames=args.frames, seed=args.seed)
    print(f"scene '{args.scene}' ({args.frames} frames, {args.size}x{args.size}) written to:")
    print(f"  {out_dir / 'dnerf'}    (D-NeRF layout)")
    print(f"  {out_dir / 'nerfies'}  (Nerfies layout)")
    return 0


def check(args: CheckArgs) -> int:
    config = DataConfig(
        path=args.path,
        format=args.format,
        split=args.split,
        downscale=args.downscale,
        background=args.background,
        val_as_test=args.val_as_test,
        cache_images=0,
    )
    print("\n".join(check_dataset(config).lines()))
    return 0


SUBCOMMANDS = {"synth": (SynthArgs, synth), "check": (CheckArgs, check)}


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in SUBCOMMANDS:
        usage = "usage: liquidgs data {synth,check} [--help]"
        if argv and argv[0] in ("-h", "--help"):
            print(usage)
            return 0
        raise ConfigError(f"choose a subcommand: synth or check ({usage})")
    spec, run = SUBCOMMANDS[argv[0]]
    return run(parse_args(spec, argv[1:], prog=f"liquidgs data {argv[0]}", description=spec.__doc__))

