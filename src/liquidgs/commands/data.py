"""`liquidgs data {synth,check}`: generate built-in synthetic scenes, validate dataset folders."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import tyro

from liquidgs.data import DataConfig, check_dataset, generate_synthetic


def synth(scene: str, out: Path, size: int = 128, frames: int = 80, seed: int = 0) -> int:
    """Render a built-in synthetic dynamic scene in both the D-NeRF and the Nerfies layout.

    Args:
        scene: Scene name, one of liquidgs.data.SYNTHETIC_SCENES: puppet (fast articulated motion,
            the default scene of the demo) or spinner (slow rigid motion).
        out: Output folder; gets dnerf/ and nerfies/ subfolders.
        size: Image width and height in pixels.
        frames: Total frames (train, val and test interleaved in time).
        seed: Seed of the random camera positions.
    """
    out_dir = generate_synthetic(scene, out, size=size, frames=frames, seed=seed)
    print(f"scene '{scene}' ({frames} frames, {size}x{size}) written to:")
    print(f"  {out_dir / 'dnerf'}    (D-NeRF layout)")
    print(f"  {out_dir / 'nerfies'}  (Nerfies layout)")
    return 0


def check(
    path: tyro.conf.Positional[Path],
    format: Literal["auto", "dnerf", "nerfies"] = "auto",
    split: Literal["auto", "nerfds", "vrig", "interp"] = "auto",
    downscale: int | None = None,
    background: Literal["black", "white"] = "black",
    val_as_test: bool = False,
) -> int:
    """Validate a dataset folder (every JSON field, every image fully decoded) and summarise it.

    Args:
        path: Scene folder.
        format: Dataset format; auto detects it from the files in the folder.
        split: Nerfies split preset (auto = nerfds).
        downscale: Image downscale factor (default: 1 for D-NeRF, the split preset's for Nerfies).
        background: Background colour RGBA images are composited on.
        val_as_test: D-NeRF: use the val split as test.
    """
    config = DataConfig(
        path=path,
        format=format,
        split=split,
        downscale=downscale,
        background=background,
        val_as_test=val_as_test,
        cache_images=0,
    )
    print("\n".join(check_dataset(config).lines()))
    return 0


def main(argv: list[str]) -> int:
    try:
        return tyro.extras.subcommand_cli_from_dict({"synth": synth, "check": check}, args=argv, prog="liquidgs data")
    except SystemExit as exit_:  # usage errors and --help: return the code instead of exiting
        return exit_.code if isinstance(exit_.code, int) else 2
