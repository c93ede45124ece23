"""Camera paths in nerfstudio's camera_path.json format, with a `render_time` per camera.

Written by the viewer's keyframe recorder and read by `liquidgs render --camera-path`.
The file holds what nerfstudio's `ns-render camera-path` reads: `render_width`,
`render_height`, `fps`, `seconds` and `camera_path`, one entry per video frame with
`camera_to_world` (16 numbers, a row-major 4x4 in nerfstudio's OpenGL axes: x right, y up,
z backwards), `fov` (vertical, degrees), `aspect` and `render_time` in [0, 1]. The recorded
keyframes are kept in `keyframes` with the same fields (renderers read `camera_path` only).
Between keyframes the position, field of view and time move linearly and the orientation
by spherical interpolation. World coordinates are the dataset's own.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from liquidgs.atomic import write_json_atomic
from liquidgs.cameras import Camera
from liquidgs.errors import DataError

MAX_SIDE = 8192
MAX_FRAMES = 100_000
# OpenCV camera axes (x right, y down, z forward) <-> OpenGL axes (x right, y up, z backwards).
_FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass
class PathCamera:
    """One camera of a path as the file holds it (camera-to-world, but in OpenCV axes), at a time.

    Kept apart from `Camera` because a path interpolates position, rotation and field of view,
    and its image size is the path's."""

    camera_to_world: np.ndarray  # float64 [4,4]
    fov: float  # vertical field of view, degrees
    time: float  # scene time in [0, 1]

    def camera(self, width: int, height: int) -> Camera:
        """The pinhole camera of a width x height image, principal point at the centre."""
        return Camera.from_camera_to_world(self.camera_to_world, math.radians(self.fov), width, height)


@dataclass
class CameraPath:
    width: int
    height: int
    fps: float
    frames: list[PathCamera]
    """One camera per video frame."""


def interpolate(keyframes: list[PathCamera], n_frames: int) -> list[PathCamera]:
    """n_frames cameras evenly spread over the keyframes (linear position, fov and time; slerp rotation)."""
    if len(keyframes) == 1 or n_frames == 1:
        return [keyframes[0]] * n_frames
    rotations = Rotation.from_matrix(np.stack([k.camera_to_world[:3, :3] for k in keyframes]))
    knots = np.arange(len(keyframes), dtype=np.float64)
    slerp = Slerp(knots, rotations)
    frames = []
    for u in np.linspace(0.0, len(keyframes) - 1, n_frames):
        i = min(int(u), len(keyframes) - 2)
        w = u - i
        a, b = keyframes[i], keyframes[i + 1]
        c2w = np.eye(4)
        c2w[:3, :3] = slerp([u]).as_matrix()[0]
        c2w[:3, 3] = (1 - w) * a.camera_to_world[:3, 3] + w * b.camera_to_world[:3, 3]
        frames.append(PathCamera(c2w, (1 - w) * a.fov + w * b.fov, (1 - w) * a.time + w * b.time))
    return frames


def _camera_record(camera: PathCamera, aspect: float) -> dict:
    return {
        "camera_to_world": (camera.camera_to_world @ _FLIP_YZ).reshape(-1).tolist(),
        "fov": camera.fov,
        "aspect": aspect,
        "render_time": camera.time,
    }


def write_camera_path(
    path: str | Path, keyframes: list[PathCamera], width: int, height: int, fps: float, seconds: float
) -> Path:
    """Interpolate the keyframes into fps x seconds frames and write them atomically."""
    if not keyframes:
        raise ValueError("a camera path needs at least one keyframe")
    n_frames = max(1, round(fps * seconds))
    aspect = width / height
    record = {
        "camera_type": "perspective",
        "render_width": width,
        "render_height": height,
        "fps": fps,
        "seconds": seconds,
        "is_cycle": False,
        "keyframes": [_camera_record(k, aspect) for k in keyframes],
        "camera_path": [_camera_record(c, aspect) for c in interpolate(keyframes, n_frames)],
    }
    return write_json_atomic(Path(path), record)


def _number(path: Path, where: str, value, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise DataError(path, f"expected a number, got {json.dumps(value)[:40]}", field=where)
    if not low <= value <= high:
        raise DataError(path, f"{value} is outside [{low}, {high}]", field=where)
    return float(value)


def _read_camera(path: Path, where: str, entry) -> PathCamera:
    if not isinstance(entry, dict):
        raise DataError(path, "expected an object", field=where)
    for key in ("camera_to_world", "fov", "render_time"):
        if key not in entry:
            raise DataError(path, "missing (a dynamic scene needs it for every camera)", field=f"{where}.{key}")
    matrix = entry["camera_to_world"]
    if not isinstance(matrix, list) or len(matrix) not in (12, 16):
        raise DataError(path, "expected 16 numbers (a row-major 4x4)", field=f"{where}.camera_to_world")
    values = [_number(path, f"{where}.camera_to_world", v, -1e9, 1e9) for v in matrix]
    c2w = np.eye(4)
    c2w[: len(values) // 4] = np.reshape(values, (-1, 4))
    rotation = c2w[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-3) or np.linalg.det(rotation) < 0:
        raise DataError(path, "the 3x3 part is not a rotation", field=f"{where}.camera_to_world")
    fov = _number(path, f"{where}.fov", entry["fov"], 1e-3, 179.0)
    time = _number(path, f"{where}.render_time", entry["render_time"], 0.0, 1.0)
    return PathCamera(c2w @ _FLIP_YZ, fov, time)


def read_camera_path(path: str | Path) -> CameraPath:
    path = Path(path)
    try:
        record = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise DataError(path, f"not valid JSON ({err})") from None
    if not isinstance(record, dict):
        raise DataError(path, "expected a JSON object")
    for key in ("render_width", "render_height", "camera_path"):
        if key not in record:
            raise DataError(path, "missing", field=key)
    size = {}
    for key in ("render_width", "render_height"):
        value = record[key]
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_SIDE:
            raise DataError(path, f"expected an integer in 1..{MAX_SIDE}, got {json.dumps(value)[:40]}", field=key)
        size[key] = value
    fps = _number(path, "fps", record.get("fps", 24), 1.0, 240.0)
    cameras = record["camera_path"]
    if not isinstance(cameras, list) or not 1 <= len(cameras) <= MAX_FRAMES:
        raise DataError(path, f"expected a list of 1 to {MAX_FRAMES} cameras", field="camera_path")
    frames = [_read_camera(path, f"camera_path[{i}]", entry) for i, entry in enumerate(cameras)]
    return CameraPath(size["render_width"], size["render_height"], fps, frames)
