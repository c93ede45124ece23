"""Reader for the Nerfies family (Nerfies, HyperNeRF, NeRF-DS).

Files: scene.json, metadata.json, dataset.json, camera/<id>.json, rgb/<k>x/<id>.png and an
optional points.npy. Cameras are OpenCV-style (orientation = world->camera rotation) in the
capture's frame; positions and points move into the scene frame by (p - center) * scale.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from liquidgs.cameras import Camera
from liquidgs.data.images import ImageLoader
from liquidgs.data.scene import BACKGROUNDS, NERFIES_PRESETS, DataConfig, Frame, SceneDataset
from liquidgs.data.validate import as_array, as_number, check_rotation, probe_image, read_json, require
from liquidgs.errors import ConfigError, DataError

# The layout's names, for the reader here and for the writers (the own-video pipeline).
SCENE_FILE = "scene.json"
DATASET_FILE = "dataset.json"
METADATA_FILE = "metadata.json"
POINTS_FILE = "points.npy"
CAMERA_FOLDER = "camera"
RGB_FOLDER = "rgb"


def camera_path(root: Path, image_id: str) -> Path:
    return root / CAMERA_FOLDER / f"{image_id}.json"


def rgb_folder(root: Path, factor: int) -> Path:
    """rgb/<factor>x: the images at 1/factor of the cameras' image_size."""
    return root / RGB_FOLDER / f"{factor}x"


@dataclass(frozen=True)
class NerfiesCamera:
    """A camera/<id>.json at full (1x) resolution."""

    rotation: np.ndarray  # world -> camera, OpenCV axes
    position: np.ndarray  # camera centre in the capture frame
    focal_length: float
    pixel_aspect_ratio: float
    principal_point: np.ndarray
    skew: float
    image_size: tuple[int, int]  # (width, height)
    distortion: np.ndarray  # k1, k2, k3, p1, p2 (OpenCV's order: radial, then tangential)


def camera_json(camera: NerfiesCamera) -> dict:
    """The camera/<id>.json that read_camera reads back as `camera`."""
    radial, tangential = camera.distortion[:3], camera.distortion[3:5]
    return {
        "orientation": camera.rotation.tolist(),
        "position": camera.position.tolist(),
        "focal_length": float(camera.focal_length),
        "principal_point": camera.principal_point.tolist(),
        "skew": float(camera.skew),
        "pixel_aspect_ratio": float(camera.pixel_aspect_ratio),
        "radial_distortion": [*map(float, radial), *[0.0] * (3 - len(radial))],
        "tangential_distortion": [*map(float, tangential), *[0.0] * (2 - len(tangential))],
        "image_size": list(camera.image_size),
    }


def read_camera(path: Path) -> NerfiesCamera:
    data = read_json(path)

    def number(key: str, **limits: float | bool) -> float:
        return as_number(require(data, key, path, key), path, key, **limits)

    rotation = as_array(require(data, "orientation", path, "orientation"), (3, 3), path, "orientation")
    check_rotation(rotation, path, "orientation")
    size = as_array(require(data, "image_size", path, "image_size"), (2,), path, "image_size")
    if (size < 1).any() or (size != np.round(size)).any():
        raise DataError(path, f"expected two positive integers, got {size.tolist()}", field="image_size")
    # Legacy Nerfies captures name the tangential coefficients `tangential`.
    tangential_key = "tangential_distortion" if "tangential_distortion" in data else "tangential"
    # Nerfies' lens is OpenCV's k1, k2, k3 (radial) and p1, p2 (tangential); shorter lists mean
    # zeros after them, so the coefficients always sit at the same place in `distortion`.
    distortion = []
    for key, count in (("radial_distortion", 3), (tangential_key, 2)):
        values = data.get(key, [])
        if not isinstance(values, list):
            raise DataError(path, "expected a list of coefficients", field=key)
        if len(values) > count:
            raise DataError(path, f"expected at most {count} coefficients, got {len(values)}", field=key)
        distortion.append(np.pad(as_array(values, (len(values),), path, key), (0, count - len(values))))
    return NerfiesCamera(
        rotation=rotation,
        position=as_array(require(data, "position", path, "position"), (3,), path, "position"),
        focal_length=number("focal_length", positive=True),
        pixel_aspect_ratio=number("pixel_aspect_ratio", positive=True) if "pixel_aspect_ratio" in data else 1.0,
        principal_point=as_array(
            require(data, "principal_point", path, "principal_point"), (2,), path, "principal_point"
        ),
        skew=number("skew") if "skew" in data else 0.0,
        image_size=(int(size[0]), int(size[1])),
        distortion=np.concatenate(distortion),
    )


def check_image_size(camera_file: Path, camera: NerfiesCamera, image: Path, size: tuple[int, int], factor: int) -> None:
    """An image at 1/factor must be the camera's image_size / factor (to the pixel)."""
    expected = (camera.image_size[0] / factor, camera.image_size[1] / factor)
    if abs(size[0] - expected[0]) >= 1 or abs(size[1] - expected[1]) >= 1:
        raise DataError(
            camera_file,
            f"image {image} gives {size[0]}x{size[1]} at 1/{factor}, expected {expected[0]:g}x{expected[1]:g}",
            field="image_size",
        )


def _split_preset(cfg: DataConfig, dataset) -> str:
    """The split preset data.split names, with 'auto' decided from dataset.json: HyperNeRF's interp
    captures ship an empty val_ids, their test frames every 4th id (D-3DGS picks this split from an
    interp* folder name; the file says it here)."""
    if cfg.split != "auto":
        return cfg.split
    interp = isinstance(dataset, dict) and dataset.get("val_ids") == []
    return "interp" if interp else "nerfds"


def read_scale(cfg: DataConfig) -> int:
    """k of the scale a Nerfies scene's frames are read at (1/k of the camera files' size): data.downscale,
    else its split's default."""
    return cfg.downscale or NERFIES_PRESETS[_split_preset(cfg, read_json(cfg.path / DATASET_FILE))]


def read_nerfies(cfg: DataConfig) -> SceneDataset:
    root = cfg.path
    if cfg.val_as_test:
        raise ConfigError("data.val_as_test: applies to D-NeRF scenes; Nerfies splits come from data.split")
    scene_path = root / SCENE_FILE
    scene = read_json(scene_path)
    scale = as_number(require(scene, "scale", scene_path, "scale"), scene_path, "scale", positive=True)
    center = as_array(require(scene, "center", scene_path, "center"), (3,), scene_path, "center")

    dataset_path = root / DATASET_FILE
    dataset = read_json(dataset_path)
    preset = _split_preset(cfg, dataset)
    notes = []
    if cfg.split == "auto" and preset == "interp":
        notes.append(
            "dataset.json has an empty val_ids, so split 'auto' reads it as an interp capture "
            "(train ids[::4], test ids[2::4], 1/2 size); --split chooses another"
        )
    factor = cfg.downscale or NERFIES_PRESETS[preset]
    if preset == "interp":
        ids = _id_list(dataset, "ids", dataset_path)
        id_splits = {"train": (ids[::4], "ids"), "test": (ids[2::4], "ids")}
    else:
        id_splits = {
            "train": (_id_list(dataset, "train_ids", dataset_path), "train_ids"),
            "test": (_id_list(dataset, "val_ids", dataset_path), "val_ids"),
        }
    for split, (ids, field) in id_splits.items():
        if not ids:
            hint = " (a HyperNeRF interp capture has none: use --split interp)" if field == "val_ids" else ""
            raise DataError(dataset_path, f"empty {split} split for preset '{preset}'{hint}", field=field)

    times = _read_times(root / METADATA_FILE, [i for ids, _ in id_splits.values() for i in ids])
    folder, source_factor = _image_folder(root, factor)
    extra_factor = factor // source_factor  # area-averaging still needed after the folder's own
    background = BACKGROUNDS[cfg.background]
    loader = ImageLoader(background, extra_factor, cfg.cache_images)

    splits: dict[str, list[Frame]] = {}
    distorted: list[str] = []
    skewed: list[str] = []
    for split, (ids, field) in id_splits.items():
        frames: list[Frame] = []
        for image_id in ids:
            camera_file = camera_path(root, image_id)
            if not camera_file.is_file():
                raise DataError(dataset_path, f"id '{image_id}' has no camera file {camera_file}", field=field)
            camera = read_camera(camera_file)
            if np.any(camera.distortion != 0):
                distorted.append(image_id)
            if camera.skew != 0:
                skewed.append(image_id)
            image = folder / f"{image_id}.png"
            width, height = probe_image(image, dataset_path, field)
            width, height = width // extra_factor, height // extra_factor
            check_image_size(camera_file, camera, image, (width, height), factor)
            if frames and (width, height) != (frames[0].camera.width, frames[0].camera.height):
                raise DataError(
                    dataset_path,
                    f"image {image} is {width}x{height} but {frames[0].image_path} is "
                    f"{frames[0].camera.width}x{frames[0].camera.height}; all images of a split must have one size",
                    field=field,
                )
            frames.append(
                _frame(image_id, times[image_id], camera, center, scale, factor, width, height, image, loader)
            )
        splits[split] = frames

    warnings = notes
    if distorted:
        warnings.append(
            f"{len(set(distorted))} camera(s) have nonzero lens distortion (e.g. camera/"
            f"{distorted[0]}.json); the rasteriser is pinhole, so the images are used as they are "
            f"(liquidgs data undistort {root} --out NEW writes a pinhole copy)"
        )
    if skewed:
        warnings.append(
            f"{len(set(skewed))} camera(s) have nonzero skew (e.g. camera/{skewed[0]}.json); "
            "K carries it, but a rasteriser that reads only fx, fy, cx, cy ignores it"
        )
    points, colors = _read_points(root / POINTS_FILE, center, scale)
    return SceneDataset(
        format="nerfies",
        scene_name=root.name,
        root=root,
        splits=splits,
        background=background,
        points=points,
        point_colors=colors,
        warnings=warnings,
    )


def _id_list(dataset: object, key: str, path: Path) -> list[str]:
    ids = require(dataset, key, path, key)
    if not isinstance(ids, list) or not all(isinstance(i, str) and i for i in ids):
        raise DataError(path, "expected a list of id strings", field=key)
    return ids


def _read_times(path: Path, ids: list[str]) -> dict[str, float]:
    """time = time_id / max(time_id over the ids used)."""
    metadata = read_json(path)
    time_ids = {}
    for image_id in ids:
        entry = require(metadata, image_id, path, image_id)
        field = f"{image_id}.time_id"
        time_ids[image_id] = as_number(require(entry, "time_id", path, field), path, field, low=0.0)
    largest = max(time_ids.values())
    return {i: (t / largest if largest > 0 else 0.0) for i, t in time_ids.items()}


def _image_folder(root: Path, factor: int) -> tuple[Path, int]:
    """rgb/<factor>x, or else the finest rgb/<k>x with k dividing factor (area-averaged further)."""
    available = sorted(int(p.name[:-1]) for p in (root / RGB_FOLDER).glob("*x") if p.name[:-1].isdigit() and p.is_dir())
    for k in sorted(available, reverse=True):
        if factor % k == 0:
            return rgb_folder(root, k), k
    raise DataError(
        rgb_folder(root, factor),
        "image folder not found, and no rgb/<k>x folder with k dividing "
        f"{factor} to downscale from (found: {', '.join(f'{k}x' for k in available) or 'none'})",
    )


def _frame(
    image_id: str,
    time: float,
    camera: NerfiesCamera,
    center: np.ndarray,
    scale: float,
    factor: int,
    width: int,
    height: int,
    image: Path,
    loader: ImageLoader,
) -> Frame:
    fx = camera.focal_length / factor
    fy = fx * camera.pixel_aspect_ratio
    cx, cy = camera.principal_point / factor
    K = torch.tensor([[fx, camera.skew / factor, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=torch.float32)
    viewmat = np.eye(4)
    viewmat[:3, :3] = camera.rotation
    viewmat[:3, 3] = -camera.rotation @ ((camera.position - center) * scale)
    camera = Camera(torch.from_numpy(viewmat).float(), K, width, height)
    return Frame(name=image_id, time=time, camera=camera, image_path=image, _loader=loader)


def _read_points(path: Path, center: np.ndarray, scale: float) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """points.npy: [N,3] positions, or [N,6] positions and colours in [0,1]."""
    if not path.exists():
        return None, None
    try:
        array = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as err:
        raise DataError(path, f"cannot read points ({err})") from None
    if array.ndim != 2 or array.shape[1] not in (3, 6) or len(array) == 0:
        raise DataError(path, f"expected shape [N,3] or [N,6], got {list(array.shape)}")
    if not np.isfinite(array).all():
        raise DataError(path, "contains non-finite values")
    points = torch.from_numpy(((array[:, :3] - center) * scale).astype(np.float32))
    colors = torch.from_numpy(array[:, 3:].astype(np.float32)) if array.shape[1] == 6 else None
    return points, colors
