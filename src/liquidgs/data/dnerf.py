"""Reader for D-NeRF (Blender) scenes: transforms_{train,val,test}.json plus RGBA PNGs."""

from __future__ import annotations

import math
from pathlib import Path, PurePosixPath

import numpy as np
import torch

from liquidgs.cameras import Camera, centred_intrinsics, focal_from_fov
from liquidgs.data.images import ImageLoader
from liquidgs.data.scene import BACKGROUNDS, DataConfig, Frame, SceneDataset
from liquidgs.data.validate import as_array, as_number, check_rotation, probe_image, read_json, require
from liquidgs.errors import ConfigError, DataError

SPLIT_FILES = {"train": "transforms_train.json", "test": "transforms_test.json", "val": "transforms_val.json"}

SCENE_BOUND = 1.3
"""D-NeRF's Blender scenes lie inside [-1.3, 1.3]^3: D-3DGS draws its random initial Gaussians there
(TrainConfig.init_extent) and the built-in synthetic scenes keep their surfaces inside it."""

# Blender/OpenGL cameras look down -z with y up; OpenCV looks down +z with y down.
BLENDER_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


def read_dnerf(cfg: DataConfig) -> SceneDataset:
    if cfg.split != "auto":
        raise ConfigError(
            f"data.split: '{cfg.split}' is a Nerfies preset; D-NeRF scenes use their "
            "transforms_{train,val,test}.json (split=auto)"
        )
    factor = cfg.downscale or 1
    background = BACKGROUNDS[cfg.background]
    loader = ImageLoader(background, factor, cfg.cache_images)
    splits: dict[str, list[Frame]] = {}
    for split, filename in SPLIT_FILES.items():
        path = cfg.path / filename
        if split == "val" and not path.exists():
            continue  # val is optional; train and test are not
        splits[split] = _read_split(path, cfg.path, factor, loader)
    if cfg.val_as_test:
        if "val" not in splits:
            raise DataError(cfg.path / SPLIT_FILES["val"], "file not found (needed by val_as_test)")
        splits["test"] = splits["val"]
    return SceneDataset(format="dnerf", scene_name=cfg.path.name, root=cfg.path, splits=splits, background=background)


def _read_split(path: Path, root: Path, factor: int, loader: ImageLoader) -> list[Frame]:
    meta = read_json(path)
    angle_x = as_number(
        require(meta, "camera_angle_x", path, "camera_angle_x"),
        path,
        "camera_angle_x",
        positive=True,
        high=math.pi - 1e-6,
    )
    items = require(meta, "frames", path, "frames")
    if not isinstance(items, list):
        raise DataError(path, "expected a list of frames", field="frames")
    if not items:
        raise DataError(path, "empty split: no frames", field="frames")
    frames: list[Frame] = []
    first: tuple[Path, int, int] | None = None
    for index, item in enumerate(items):
        prefix = f"frames[{index}]"
        file_path = require(item, "file_path", path, f"{prefix}.file_path")
        if not isinstance(file_path, str) or not file_path:
            raise DataError(path, "expected a relative image path", field=f"{prefix}.file_path")
        name = PurePosixPath(file_path).name.removesuffix(".png")
        image = root / (file_path if file_path.endswith(".png") else file_path + ".png")
        time = as_number(require(item, "time", path, f"{prefix}.time"), path, f"{prefix}.time", low=0.0, high=1.0)
        field = f"{prefix}.transform_matrix"
        cam_to_world = as_array(require(item, "transform_matrix", path, field), (4, 4), path, field)
        if not np.allclose(cam_to_world[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
            raise DataError(path, f"last row must be [0, 0, 0, 1], got {cam_to_world[3].tolist()}", field=field)
        check_rotation(cam_to_world[:3, :3], path, field)

        width, height = probe_image(image, path, f"{prefix}.file_path")
        if first is None:
            first = (image, width, height)
        elif (width, height) != first[1:]:
            raise DataError(
                path,
                f"image {image} is {width}x{height} but {first[0]} is {first[1]}x{first[2]}; "
                "all images of a split must have one size",
                field=f"{prefix}.file_path",
            )
        width, height = width // factor, height // factor
        if width < 1 or height < 1:
            raise ConfigError(f"data.downscale: {factor} is larger than the images of {path}")

        viewmat = torch.from_numpy(np.linalg.inv(cam_to_world @ BLENDER_TO_OPENCV)).float()
        K = centred_intrinsics(focal_from_fov(angle_x, width), width, height)
        camera = Camera(viewmat, K, width, height)
        frames.append(Frame(name=name, time=time, camera=camera, image_path=image, _loader=loader))
    return frames
