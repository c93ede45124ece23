"""The dataset types the trainer consumes: DataConfig, Frame and SceneDataset."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import torch
import tyro

from liquidgs.cameras import Camera
from liquidgs.data.images import ImageLoader
from liquidgs.errors import ConfigError

BACKGROUNDS = {"black": (0.0, 0.0, 0.0), "white": (1.0, 1.0, 1.0)}

# Nerfies-family split presets: which ids are train/test and which rgb/<k>x folder to read.
# They reproduce the reference's choices, which it makes from the parent folder's name.
NERFIES_PRESETS = {"nerfds": 1, "vrig": 4, "interp": 2}

# The choices of DataConfig's settings, owned here (commands that read a scene take these types).
DATA_FORMATS = ("auto", "dnerf", "nerfies")
SPLITS = ("auto", *NERFIES_PRESETS)
DataFormat = Literal[DATA_FORMATS]
Split = Literal[SPLITS]
Background = Literal[tuple(BACKGROUNDS)]


@dataclass
class DataConfig:
    """Where and how to read a dynamic scene."""

    # Flag names: TrainConfig shows these settings without a prefix (--data, --data-format, --downscale).
    path: Annotated[Path, tyro.conf.arg(name="data")]
    """Scene folder (D-NeRF: transforms_*.json; Nerfies/NeRF-DS/HyperNeRF: dataset.json)."""
    format: Annotated[DataFormat, tyro.conf.arg(name="data_format")] = "auto"
    """`auto` detects the format from the files in the folder, never from its name."""
    downscale: int | None = None
    """Image downscale factor. None: 1 for D-NeRF (area-averaged for other values), the split
    preset's rgb/<k>x folder for Nerfies (nerfds 1, vrig 4, interp 2)."""
    background: Background = "black"
    """Colour RGBA images are composited on: rgb*a + bg*(1-a)."""
    split: Split = "auto"
    """Nerfies presets: nerfds = train_ids/val_ids, vrig = train_ids/val_ids, interp =
    ids[::4]/ids[2::4]. `auto` is nerfds for Nerfies and the transforms files for D-NeRF."""
    val_as_test: bool = False
    """D-NeRF: evaluate on the val split (the reference does so for lego)."""
    cache_images: int = 512
    """Decoded images kept in memory (uint8, LRU); 0 keeps none. Enough for every view of a
    D-NeRF or NeRF-DS scene (about 420 MB for 220 views at 800x800): training visits the
    views in a reshuffled order, which an LRU smaller than the split misses almost always
    (measured: with 64 on hellwarrior, decoding an 800x800 PNG each step doubled it)."""

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        if self.format not in DATA_FORMATS:
            raise ConfigError(f"data.format: unknown format '{self.format}' ({', '.join(DATA_FORMATS)})")
        if self.background not in BACKGROUNDS:
            raise ConfigError(f"data.background: unknown background '{self.background}' ({', '.join(BACKGROUNDS)})")
        if self.split not in SPLITS:
            raise ConfigError(f"data.split: unknown split '{self.split}' ({', '.join(SPLITS)})")
        if self.downscale is not None and (isinstance(self.downscale, bool) or self.downscale < 1):
            raise ConfigError(f"data.downscale: must be a positive integer, got {self.downscale}")
        if self.cache_images < 0:
            raise ConfigError(f"data.cache_images: must be >= 0, got {self.cache_images}")


@dataclass(eq=False)
class Frame:
    """One posed image at a time. The camera (float32 viewmat and K) describes the image as image() returns it."""

    name: str
    time: float
    camera: Camera
    image_path: Path
    _loader: ImageLoader = field(repr=False)

    def image_uint8(self) -> np.ndarray:
        """Read-only uint8 [H,W,3], composited on the background; shared with the cache."""
        return self._loader.load(self.image_path)

    def image(self) -> torch.Tensor:
        """float32 [H,W,3] in [0,1], composited on the background (a fresh tensor)."""
        return torch.from_numpy(self.image_uint8().astype(np.float32)).div_(255.0)


def spread_extent(points: torch.Tensor) -> float:
    """1.1 x the largest distance of a point from their mean (D-3DGS's extent of the cameras)."""
    points = points.double()
    return 1.1 * float((points - points.mean(dim=0)).norm(dim=1).max())


def camera_extent(frames: list[Frame]) -> float:
    return spread_extent(torch.stack([frame.camera.centre for frame in frames]))


MIN_CAMERA_EXTENT = 1e-6
"""Below this the train cameras sit at one position (a fixed camera, a single frame): the
extent densification scales its size tests by is meaningless and must come from elsewhere."""


@dataclass(eq=False)
class SceneDataset:
    format: Literal["dnerf", "nerfies"]
    scene_name: str
    root: Path
    splits: dict[str, list[Frame]]
    background: tuple[float, float, float]
    points: torch.Tensor | None = None
    """float32 [N,3] initial points in the frames' world frame, or None."""
    point_colors: torch.Tensor | None = None
    """float32 [N,3] in [0,1] when the points come with colours, else None."""
    warnings: list[str] = field(default_factory=list)
    """Things a pinhole rasteriser cannot honour (distortion, skew)."""
    camera_extent: float = field(init=False)

    def __post_init__(self) -> None:
        self.camera_extent = camera_extent(self.train)
        if self.camera_extent_degenerate:
            self.warnings.append(
                f"the {len(self.train)} train camera(s) all sit at one position (camera extent "
                f"{self.camera_extent:.4f}); training takes the scene extent from the initial points instead"
            )

    @property
    def camera_extent_degenerate(self) -> bool:
        return self.camera_extent < MIN_CAMERA_EXTENT

    @property
    def kind(self) -> Literal["synthetic", "real"]:
        """Selects the trainer presets: D-NeRF scenes are synthetic, Nerfies-family real."""
        return "synthetic" if self.format == "dnerf" else "real"

    @property
    def train(self) -> list[Frame]:
        return self.splits["train"]

    @property
    def test(self) -> list[Frame]:
        return self.splits["test"]
