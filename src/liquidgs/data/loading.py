"""Format detection, load_dataset and check_dataset.

Validation levels: load_dataset reads and checks every JSON field and walks every image file
structurally (all PNG chunks and CRCs up to IEND, ~1 ms per 800x800 image), which catches
missing, truncated and corrupted files before a trainer writes anything; pixels are decoded
lazily when a frame is used. check_dataset additionally decodes every image in full.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import torch

from liquidgs.data.dnerf import read_dnerf
from liquidgs.data.nerfies import read_nerfies
from liquidgs.data.scene import DataConfig, SceneDataset
from liquidgs.data.validate import decode_image
from liquidgs.errors import ConfigError, DataError

READERS = {"dnerf": read_dnerf, "nerfies": read_nerfies}
CAPTURE_FORMATS = ("nerfies",)
"""Formats whose cameras were estimated from real footage (Nerfies, HyperNeRF, NeRF-DS, and what
`data video` / `data images` write). D-NeRF's frames are rendered, its cameras exact."""


CAPTURE_SWITCH = ("auto", "on", "off")
"""The choices of a training setting that is on for captures by default (for_captures)."""


def check_capture_switch(setting: str, choice: str) -> None:
    """ConfigError naming `setting` unless `choice` is one of CAPTURE_SWITCH."""
    if choice not in CAPTURE_SWITCH:
        raise ConfigError(f"{setting} must be one of {', '.join(CAPTURE_SWITCH)}, got {choice!r}")


def for_captures(choice: str, data_format: str | None) -> bool:
    """A training setting's auto / on / off: auto is on for captures, off otherwise (None: the
    format is unknown)."""
    if choice != "auto":
        return choice == "on"
    return data_format in CAPTURE_FORMATS


def detect_format(path: Path) -> str:
    """'dnerf' or 'nerfies', from the files the folder holds (never from its name)."""
    found = [
        fmt
        for fmt, marker in (("dnerf", "transforms_train.json"), ("nerfies", "dataset.json"))
        if (path / marker).is_file()
    ]
    if len(found) == 2:
        raise DataError(
            path,
            "holds both transforms_train.json (D-NeRF) and dataset.json (Nerfies); choose one with data.format",
            field="format",
        )
    if not found:
        raise DataError(path, "neither transforms_train.json (D-NeRF) nor dataset.json (Nerfies) found")
    return found[0]


def load_dataset(cfg: DataConfig) -> SceneDataset:
    """Validate the scene strictly and return it with lazily decoded images."""
    if not cfg.path.exists():
        raise DataError(cfg.path, "dataset folder not found")
    if not cfg.path.is_dir():
        raise DataError(cfg.path, "is a file, not a dataset folder")
    fmt = detect_format(cfg.path) if cfg.format == "auto" else cfg.format
    dataset = READERS[fmt](cfg)
    for message in dataset.warnings:
        warnings.warn(f"{cfg.path}: {message}", stacklevel=2)
    return dataset


@dataclass
class CheckReport:
    dataset: SceneDataset
    images_decoded: int

    def lines(self) -> list[str]:
        ds = self.dataset
        first_k = ds.train[0].camera.K
        fx, fy, cx, cy = (float(value) for value in (first_k[0, 0], first_k[1, 1], first_k[0, 2], first_k[1, 2]))
        same_k = all(torch.equal(frame.camera.K, first_k) for frames in ds.splits.values() for frame in frames)
        lines = [
            f"path:       {ds.root}",
            f"format:     {ds.format} ({ds.kind}), scene '{ds.scene_name}'",
            "frames:     " + ", ".join(f"{name} {len(frames)}" for name, frames in ds.splits.items()),
            "resolution: "
            + ", ".join(
                f"{name} {frames[0].camera.width}x{frames[0].camera.height}" for name, frames in ds.splits.items()
            ),
            f"intrinsics: fx {fx:.3f}  fy {fy:.3f}  cx {cx:.3f}  cy {cy:.3f}"
            + ("" if same_k else "  (first train frame; differs across frames)"),
            "time:       "
            + ", ".join(
                f"{name} [{min(f.time for f in frames):.4f}, {max(f.time for f in frames):.4f}]"
                for name, frames in ds.splits.items()
            ),
            f"extent:     {ds.camera_extent:.4f} (1.1 x largest train camera distance from their mean)"
            + ("  DEGENERATE: see the warning below" if ds.camera_extent_degenerate else ""),
            f"points:     {len(ds.points) if ds.points is not None else 'none'}",
            f"images:     {self.images_decoded} decoded in full, "
            + (f"{len(ds.warnings)} warning(s) below" if ds.warnings else "all OK"),
        ]
        lines += [f"warning:    {message}" for message in ds.warnings]
        return lines


def check_dataset(cfg: DataConfig) -> CheckReport:
    """load_dataset plus a full decode of every image; raises DataError on the first fault."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the report lists them instead
        dataset = load_dataset(cfg)
    images = {frame.image_path for frames in dataset.splits.values() for frame in frames}
    for image in sorted(images):
        decode_image(image)
    return CheckReport(dataset=dataset, images_decoded=len(images))
