"""`liquidgs data undistort`: a Nerfies/HyperNeRF scene whose cameras carry lens distortion ->
a copy whose images are undistorted into pinhole cameras (the rasteriser is pinhole).

Each camera/<id>.json becomes a COLMAP OPENCV camera (FULL_OPENCV when k3 is nonzero: Nerfies'
k1, k2, k3, p1, p2 are OpenCV's), and COLMAP's own undistorter warps the images (see
colmap.undistorters: the border is cropped to valid pixels, the focal length is kept). The finest
rgb/<k>x folder is undistorted; every coarser folder the scene had is made from it by exact area
averages, so the folders agree with each other and with the camera files. Poses, times, splits,
scene.json and points.npy are unchanged: undistortion moves pixels, not cameras.

The new scene is built beside the output and renamed into place (atomic.build_atomically).
"""

from __future__ import annotations

import math
import shutil
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from liquidgs.atomic import build_atomically, write_json_atomic
from liquidgs.data.capture import refuse_taken
from liquidgs.data.colmap import Log, Undistorter, describe_camera, import_pycolmap, undistorters
from liquidgs.data.loading import detect_format, load_dataset
from liquidgs.data.nerfies import (
    CAMERA_FOLDER,
    DATASET_FILE,
    METADATA_FILE,
    POINTS_FILE,
    RGB_FOLDER,
    SCENE_FILE,
    NerfiesCamera,
    _id_list,
    camera_json,
    camera_path,
    check_image_size,
    read_camera,
    rgb_folder,
)
from liquidgs.data.scene import DataConfig
from liquidgs.data.validate import decode_image, probe_image, read_json
from liquidgs.errors import DataError
from liquidgs.media import save_frame_png

# What the new scene holds besides camera/ and rgb/. Anything else (capture.json, colmap/, masks,
# depth maps) describes the distorted images or is not part of the layout, and is left out.
COPIED_FILES = (DATASET_FILE, METADATA_FILE, SCENE_FILE, POINTS_FILE)


@dataclass
class UndistortSummary:
    frames: int
    lenses: list[str]
    """Each distinct lens, 'OPENCV 1920x1080 (...) -> PINHOLE 1904x1072 (...)', at the finest folder."""
    folders: list[int]
    image_size: tuple[int, int]
    """rgb/1x size of the new scene (width, height)."""
    left_out: list[str]
    seconds: float


def colmap_camera(camera: NerfiesCamera, factor: int, size: tuple[int, int]):
    """The Nerfies camera as COLMAP's OPENCV (or FULL_OPENCV with k3) for images at 1/factor of
    its image_size that measure `size` (width, height). Pixel centres are at +0.5 in both."""
    pycolmap = import_pycolmap()
    fx = camera.focal_length / factor
    fy = fx * camera.pixel_aspect_ratio
    cx, cy = (float(value) for value in camera.principal_point / factor)
    k1, k2, k3, p1, p2 = (float(value) for value in camera.distortion)
    if k3 == 0.0:
        return pycolmap.Camera(model="OPENCV", width=size[0], height=size[1], params=[fx, fy, cx, cy, k1, k2, p1, p2])
    params = [fx, fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]  # k4..k6: the rational model's denominator
    return pycolmap.Camera(model="FULL_OPENCV", width=size[0], height=size[1], params=params)


def undistort_scene(scene: Path, out: Path, log: Log) -> UndistortSummary:
    """Write the undistorted copy of the Nerfies scene `scene` at `out` (which must be new or empty)."""
    started = time.perf_counter()
    ids, cameras, folders, sizes = _read_scene(scene)
    refuse_taken(out)
    finest = folders[0]
    multiple = math.lcm(*(factor // finest for factor in folders))
    # One undistorter per distinct lens (a capture usually has one camera, HyperNeRF's vrig two).
    lens_of = {image_id: colmap_camera(cameras[image_id], finest, sizes[image_id]) for image_id in ids}
    lenses: dict[tuple, object] = {}
    for lens in lens_of.values():
        lenses.setdefault(_lens_key(lens), lens)
    planned = dict(zip(lenses, undistorters(list(lenses.values()), multiple)))
    undistorter_of = {image_id: planned[_lens_key(lens)] for image_id, lens in lens_of.items()}
    described = [f"{describe_camera(u.distorted)} -> {describe_camera(u.pinhole)}" for u in planned.values()]
    for line in described:
        log(f"undistortion (rgb/{finest}x): {line}, cropped to valid pixels")
    left_out = sorted(
        p.name + ("/" if p.is_dir() else "")
        for p in scene.iterdir()
        if p.name not in (*COPIED_FILES, CAMERA_FOLDER, RGB_FOLDER) and not p.name.startswith(".")
    )

    def build(building: Path) -> None:
        for name in COPIED_FILES:
            if (scene / name).is_file():
                shutil.copy2(scene / name, building / name)
        (building / CAMERA_FOLDER).mkdir()
        for factor in folders:
            rgb_folder(building, factor).mkdir(parents=True)
        for count, image_id in enumerate(ids, start=1):
            undistorter = undistorter_of[image_id]
            write_json_atomic(
                camera_path(building, image_id), camera_json(_pinhole_camera(cameras[image_id], undistorter, finest))
            )
            pixels = undistorter.image(_opaque_or_rgba(decode_image(rgb_folder(scene, finest) / f"{image_id}.png")))
            for factor in folders:
                scaled = _area_average(pixels, factor // finest)
                save_frame_png(scaled, rgb_folder(building, factor) / f"{image_id}.png")
            if count % 25 == 0:
                log(f"undistortion: {count}/{len(ids)} frames")

    build_atomically(out, build)
    first = next(iter(planned.values())).pinhole
    return UndistortSummary(
        frames=len(ids),
        lenses=described,
        folders=folders,
        image_size=(first.width * finest, first.height * finest),
        left_out=left_out,
        seconds=round(time.perf_counter() - started, 2),
    )


def _read_scene(scene: Path) -> tuple[list[str], dict[str, NerfiesCamera], list[int], dict[str, tuple[int, int]]]:
    """(every id of dataset.json, its camera, the rgb/<k>x factors finest first, each id's image
    size in the finest folder), validated; a scene without distortion is refused."""
    if not scene.exists():
        raise DataError(scene, "scene folder not found")
    if not scene.is_dir():
        raise DataError(scene, "is a file, not a scene folder")
    if detect_format(scene) != "nerfies":
        raise DataError(
            scene,
            "is a D-NeRF scene (transforms_*.json), whose cameras have no distortion; data undistort reads "
            "the Nerfies layout (dataset.json, camera/<id>.json, rgb/<k>x/)",
        )
    folders = sorted(int(p.name[:-1]) for p in (scene / RGB_FOLDER).glob("*x") if p.name[:-1].isdigit() and p.is_dir())
    folders = [factor for factor in folders if factor > 0]
    if not folders:
        raise DataError(scene / RGB_FOLDER, "no rgb/<k>x image folder found")
    for factor in folders[1:]:
        if factor % folders[0]:
            raise DataError(
                rgb_folder(scene, factor),
                f"cannot be made from the finest folder rgb/{folders[0]}x ({factor} is not a multiple of {folders[0]})",
            )
    # The reader's own checks (splits, times, cameras, image sizes, points), at the finest folder.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the distortion warning is why we are here
        load_dataset(DataConfig(path=scene, format="nerfies", downscale=folders[0], cache_images=0))

    dataset_path = scene / DATASET_FILE
    dataset = read_json(dataset_path)
    ids: list[str] = []
    for key in ("ids", "train_ids", "val_ids"):
        if isinstance(dataset, dict) and key in dataset:
            ids += [image_id for image_id in _id_list(dataset, key, dataset_path) if image_id not in ids]
    cameras, sizes = {}, {}
    for image_id in ids:
        path = camera_path(scene, image_id)
        if not path.is_file():
            raise DataError(dataset_path, f"id '{image_id}' has no camera file {path}", field="ids")
        camera = read_camera(path)
        if camera.skew != 0:
            message = f"skew {camera.skew:g}: COLMAP's camera models have no skew, so it cannot be undistorted"
            raise DataError(path, message, field="skew")
        cameras[image_id] = camera
        for factor in reversed(folders):  # ends with the finest
            image = rgb_folder(scene, factor) / f"{image_id}.png"
            width, height = probe_image(image, dataset_path, "ids")
            check_image_size(path, camera, image, (width, height), factor)
        sizes[image_id] = (width, height)
    if not any(np.any(camera.distortion != 0) for camera in cameras.values()):
        raise DataError(
            scene / CAMERA_FOLDER,
            f"no lens distortion to remove: radial_distortion and tangential_distortion are zero in all "
            f"{len(cameras)} camera files",
        )
    return ids, cameras, folders, sizes


def _lens_key(camera) -> tuple:
    return (camera.model_name, tuple(camera.params), camera.width, camera.height)


def _pinhole_camera(camera: NerfiesCamera, undistorter: Undistorter, finest: int) -> NerfiesCamera:
    """The camera file of an undistorted image: same pose, the pinhole intrinsics at 1x, no distortion."""
    fx, fy, cx, cy = (float(value) for value in undistorter.pinhole.params)
    return NerfiesCamera(
        rotation=camera.rotation,
        position=camera.position,
        focal_length=fx * finest,
        pixel_aspect_ratio=fy / fx,
        principal_point=np.array([cx, cy]) * finest,
        skew=0.0,
        image_size=(undistorter.pinhole.width * finest, undistorter.pinhole.height * finest),
        distortion=np.zeros(5),
    )


def _opaque_or_rgba(rgba: np.ndarray) -> np.ndarray:
    """RGB when every pixel is opaque (then the PNG written is RGB too), else RGBA."""
    return rgba[..., :3] if bool((rgba[..., 3] == 255).all()) else rgba


def _area_average(pixels: np.ndarray, factor: int) -> np.ndarray:
    """Exact factor x factor block means (premultiplied for RGBA, as the loader composites)."""
    if factor == 1:
        return pixels
    if pixels.shape[2] == 3:
        return np.asarray(Image.fromarray(pixels).reduce(factor))
    height, width = pixels.shape[0] // factor, pixels.shape[1] // factor
    blocks = pixels[: height * factor, : width * factor].astype(np.float64)
    blocks = blocks.reshape(height, factor, width, factor, 4)
    alpha = blocks[..., 3:].mean(axis=(1, 3))
    color = (blocks[..., :3] * blocks[..., 3:]).mean(axis=(1, 3))
    rgb = np.divide(color, alpha, out=np.zeros_like(color), where=alpha > 0)
    return np.rint(np.concatenate([rgb, alpha], axis=-1)).clip(0, 255).astype(np.uint8)
