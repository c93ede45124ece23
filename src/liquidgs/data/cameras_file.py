"""A scene's cameras without its images: what a baked folder carries, so that rendering, viewing
and the share formats work where the scene folder is not.

    {"format": CAMERAS_FORMAT, "scene": name, "data_format": "dnerf" | "nerfies", "root": the scene
     folder it was read from, "background": [r, g, b],
     "splits": {split: [{"name", "time", "width", "height", "K": [9], "viewmat": [16], "image"}]}}

A dataset read back from it has each frame's camera and time as the run saw them (perturbations
included) and no images: a frame asked for its image says so in one line, naming where it was.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch

from liquidgs.cameras import Camera
from liquidgs.data.images import ImageLoader
from liquidgs.data.scene import Frame, SceneDataset
from liquidgs.errors import DataError

CAMERAS_FORMAT = "liquidgs-cameras-1"
CAMERAS_FILE = "cameras.json"


def cameras_record(dataset: SceneDataset) -> dict:
    def frame_record(frame: Frame) -> dict:
        camera = frame.camera
        return {
            "name": frame.name,
            "time": float(frame.time),
            "width": int(camera.width),
            "height": int(camera.height),
            "K": camera.K.double().flatten().tolist(),
            "viewmat": camera.viewmat.double().flatten().tolist(),
            "image": str(frame.image_path),
        }

    return {
        "format": CAMERAS_FORMAT,
        "scene": dataset.scene_name,
        "data_format": dataset.format,
        "root": str(dataset.root),
        "background": [float(c) for c in dataset.background],
        "splits": {split: [frame_record(f) for f in frames] for split, frames in dataset.splits.items()},
    }


class _NoImages(ImageLoader):
    def load(self, path: Path):
        raise DataError(path, "the scene's image is not at hand (a baked folder carries cameras, not images)")


def _numbers(raw, count: int) -> bool:
    return (
        isinstance(raw, list)
        and len(raw) == count
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in raw)
    )


def dataset_from_cameras(raw, path: Path) -> SceneDataset:
    """The SceneDataset `cameras_record` described; anything malformed is one line naming `path` and field."""
    if not isinstance(raw, dict) or raw.get("format") != CAMERAS_FORMAT:
        raise DataError(path, f"not a {CAMERAS_FORMAT} file", field="format")
    for key, kind in (("scene", str), ("data_format", str), ("root", str), ("splits", dict)):
        if not isinstance(raw.get(key), kind):
            raise DataError(path, f"missing or not a {kind.__name__}", field=key)
    if raw["data_format"] not in ("dnerf", "nerfies"):
        raise DataError(path, f"unknown format {raw['data_format']!r}", field="data_format")
    if not _numbers(raw.get("background"), 3):
        raise DataError(path, "must be three finite numbers", field="background")
    background = tuple(float(c) for c in raw["background"])
    loader = _NoImages(background, 1, capacity=0)
    splits: dict[str, list[Frame]] = {}
    for split, frames in raw["splits"].items():
        if not isinstance(frames, list):
            raise DataError(path, "must be a list of frames", field=f"splits.{split}")
        splits[split] = []
        for i, f in enumerate(frames):
            where = f"splits.{split}[{i}]"
            if not (isinstance(f, dict) and isinstance(f.get("name"), str) and isinstance(f.get("image"), str)):
                raise DataError(path, "must be an object with a name and an image", field=where)
            sizes = [f.get("width"), f.get("height")]
            if not all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in sizes):
                raise DataError(path, "width and height must be positive integers", field=where)
            if not (_numbers([f.get("time")], 1) and _numbers(f.get("K"), 9) and _numbers(f.get("viewmat"), 16)):
                raise DataError(path, "time, K [9] and viewmat [16] must be finite numbers", field=where)
            camera = Camera(
                torch.tensor(f["viewmat"], dtype=torch.float64).reshape(4, 4).float(),
                torch.tensor(f["K"], dtype=torch.float64).reshape(3, 3).float(),
                f["width"],
                f["height"],
            )
            splits[split].append(Frame(f["name"], float(f["time"]), camera, Path(f["image"]), loader))
    if not splits.get("train"):
        raise DataError(path, "no train frames", field="splits.train")
    splits.setdefault("test", [])
    return SceneDataset(raw["data_format"], raw["scene"], Path(raw["root"]), splits, background)
