"""Built-in synthetic dynamic scenes, rendered by analytic ray casting.

The renderer is independent of any Gaussian rasteriser: rays through the pixels are
intersected with spheres, capsules and boxes in closed form, coloured by procedural textures
fixed to each primitive (so motion is visible) and Lambert-shaded by world-fixed lights (so
colour does not depend on the viewpoint). Each pixel averages supersample^2 rays, which gives
anti-aliased colour and alpha. Everything is numpy-vectorised and deterministic by seed.

Each scene is written in both layouts, with the same cameras, times and images:
  OUT/dnerf/    transforms_{train,val,test}.json, {train,val,test}/r_###.png
  OUT/nerfies/  scene.json, metadata.json, dataset.json, camera/<id>.json, rgb/1x/<id>.png, points.npy
Splits are by frame: frame i has time i/(frames-1); i % 8 == 4 is test and i % 8 == 6 is val
(interleaved in time), the rest - always including the first and last frame - is train. The
Nerfies layout has no val: its val_ids are the test frames, and the val frames are only in `ids`.
"""

from __future__ import annotations

import io
import json
import math
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from PIL import Image

from liquidgs.atomic import disk_full
from liquidgs.cameras import DNERF_CAMERA_ANGLE_X, centred_intrinsics, focal_from_fov
from liquidgs.errors import ConfigError, LiquidGSError

CAMERA_RADIUS = 4.0
ELEVATION_RANGE = (math.radians(-20.0), math.radians(75.0))
POINT_COUNT = 4096
# World-fixed key and fill lights: shade = ambient + sum(weight * max(0, n . light)).
LIGHTS = ((np.array([0.4, -0.5, 0.77]), 0.6), (np.array([-0.5, 0.6, -0.3]), 0.25))
AMBIENT = 0.3
_EPSILON = 1e-6

Color = tuple[float, float, float]


@dataclass(frozen=True)
class Primitive:
    """A textured solid. Local frame: sphere centred at 0; capsule from 0 to length*z; box centred."""

    name: str
    shape: Literal["sphere", "capsule", "box"]
    size: tuple[float, ...]  # sphere (radius,); capsule (radius, length); box (half x, half y, half z)
    colors: tuple[Color, Color]
    # 3D checker cells, bands along local z, or cells of random shades between the two colours
    # (no repeats, so a feature matcher can tell places apart: the video test scene's walls).
    pattern: Literal["checker", "stripes", "speckle"]
    period: float
    rotation: np.ndarray  # local -> world
    translation: np.ndarray  # local origin in world coordinates


def _rot_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _puppet(time: float) -> list[Primitive]:
    """Fast articulated motion: a figure doing two jumping jacks, arms bending at the elbow."""
    phase = 2.0 * math.pi * 2.0 * time
    swing = 0.5 - 0.5 * math.cos(phase)  # 0 at rest, 1 at the top of a jump
    forward = 0.4 * math.sin(phase)
    body = _rot_z(0.6 * math.sin(2.0 * math.pi * time))  # the whole figure yaws back and forth
    lift = np.array([0.0, 0.0, 0.06 * swing])
    torso, head = ((0.95, 0.55, 0.1), (0.1, 0.15, 0.45)), ((0.9, 0.2, 0.75), (0.45, 0.1, 0.375))
    arm, leg = ((0.2, 0.75, 0.3), (0.95, 0.95, 0.8)), ((0.2, 0.4, 0.9), (0.6, 0.6, 0.6))

    def place(name, shape, size, colors, pattern, period, rotation, position):
        return Primitive(name, shape, size, colors, pattern, period, body @ rotation, body @ (position + lift))

    parts = [
        place("torso", "box", (0.27, 0.16, 0.37), torso, "checker", 0.17, np.eye(3), np.array([0.0, 0.0, 0.05])),
        place("head", "sphere", (0.24,), head, "checker", 0.13, np.eye(3), np.array([0.0, 0.0, 0.7])),
    ]
    for side, sign in (("left", 1.0), ("right", -1.0)):
        # A capsule points along local +z; rot_y(pi - a) points it a radians up from straight down.
        raise_angle, bend = 0.2 + 2.1 * swing, 0.9 * swing
        upper = _rot_x(sign * forward) @ _rot_y(sign * (math.pi - raise_angle))
        fore = _rot_x(sign * forward) @ _rot_y(sign * (math.pi - raise_angle - bend))
        shoulder = np.array([sign * 0.35, 0.0, 0.34])
        elbow = shoulder + upper @ np.array([0.0, 0.0, 0.4])
        spread = 0.45 * swing
        thigh = _rot_x(-sign * forward) @ _rot_y(sign * (math.pi - spread))
        parts += [
            place(f"{side}_upper_arm", "capsule", (0.08, 0.4), arm, "stripes", 0.1, upper, shoulder),
            place(f"{side}_forearm", "capsule", (0.07, 0.36), arm, "stripes", 0.1, fore, elbow),
            place(
                f"{side}_leg",
                "capsule",
                (0.1, 0.72),
                leg,
                "stripes",
                0.12,
                thigh,
                np.array([sign * 0.15, 0.0, -0.33]),
            ),
        ]
    return parts


def _spinner(time: float) -> list[Primitive]:
    """Slow rigid motion: a textured toy turning a quarter turn while drifting and tilting."""
    rotation = _rot_z(0.5 * math.pi * time) @ _rot_x(0.25 * math.sin(math.pi * time))
    offset = np.array([0.25 * (2.0 * time - 1.0), 0.1 * math.sin(math.pi * time), 0.05])

    def place(name, shape, size, colors, pattern, period, local_rotation, position):
        return Primitive(
            name,
            shape,
            size,
            colors,
            pattern,
            period,
            rotation @ local_rotation,
            rotation @ position + offset,
        )

    return [
        place(
            "block",
            "box",
            (0.45, 0.32, 0.28),
            ((0.1, 0.6, 0.6), (0.95, 0.9, 0.75)),
            "checker",
            0.14,
            np.eye(3),
            np.zeros(3),
        ),
        place(
            "ball",
            "sphere",
            (0.28,),
            ((0.9, 0.25, 0.15), (0.95, 0.8, 0.2)),
            "checker",
            0.12,
            np.eye(3),
            np.array([0.0, 0.0, 0.56]),
        ),
        # rot_x(-pi/2) turns the capsule's +z axis into +y: an axle through the block.
        place(
            "axle",
            "capsule",
            (0.09, 1.4),
            ((0.35, 0.2, 0.6), (0.85, 0.85, 0.9)),
            "stripes",
            0.1,
            _rot_x(-0.5 * math.pi),
            np.array([0.0, -0.7, 0.0]),
        ),
    ]


def _still(time: float) -> list[Primitive]:
    """Nothing moves: the puppet standing at rest. A control: where there is no motion, whatever a
    deformation field gains over the static model is something other than motion (camera error)."""
    return _puppet(0.0)


SCENES: dict[str, Callable[[float], list[Primitive]]] = {"puppet": _puppet, "spinner": _spinner, "still": _still}
SYNTHETIC_SCENES: tuple[str, ...] = tuple(SCENES)
DEFAULT_SYNTHETIC_SCENE = "puppet"


def scene_primitives(name: str, time: float) -> list[Primitive]:
    """The primitives of scene `name` at `time` in [0, 1], in world coordinates."""
    if name not in SCENES:
        raise ConfigError(f"unknown synthetic scene '{name}' (choose from {', '.join(SYNTHETIC_SCENES)})")
    return SCENES[name](time)


# ---- ray casting -------------------------------------------------------------------------------


def _rotate(rotation: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """rotation @ v for each row v of [N,3]; einsum, because BLAS matmul on a [N,3] x [3,3]
    product is ~10x slower here (thread start-up for a tiny inner dimension)."""
    return np.einsum("ij,nj->ni", rotation, vectors)


def _sphere_distance(origin: np.ndarray, dirs: np.ndarray, center: np.ndarray, radius: float) -> np.ndarray:
    """Distance along unit `dirs` to the first hit of a sphere (inf where none)."""
    offset = origin - center
    b = dirs @ offset
    disc = b * b - (offset @ offset - radius * radius)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    return np.where((disc > 0) & (t > _EPSILON), t, np.inf)


def _intersect(prim: Primitive, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(distance [N], local hit point [N,3], local unit normal [N,3]) of world rays against prim."""
    o = prim.rotation.T @ (origin - prim.translation)
    d = _rotate(prim.rotation.T, dirs)
    if prim.shape == "sphere":
        t = _sphere_distance(o, d, np.zeros(3), prim.size[0])
        points = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
        return t, points, points / prim.size[0]
    if prim.shape == "capsule":
        radius, length = prim.size
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        b = o[0] * d[:, 0] + o[1] * d[:, 1]
        disc = b * b - a * (o[0] ** 2 + o[1] ** 2 - radius**2)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_side = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        z = o[2] + t_side * d[:, 2]
        t_side = np.where((disc > 0) & (a > 1e-12) & (t_side > _EPSILON) & (z >= 0) & (z <= length), t_side, np.inf)
        t = np.minimum(
            t_side,
            np.minimum(
                _sphere_distance(o, d, np.zeros(3), radius),
                _sphere_distance(o, d, np.array([0.0, 0.0, length]), radius),
            ),
        )
        points = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
        axis_points = np.zeros_like(points)
        axis_points[:, 2] = np.clip(points[:, 2], 0.0, length)
        return t, points, (points - axis_points) / radius
    half = np.asarray(prim.size)
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / d
        t1, t2 = (-half - o) * inverse, (half - o) * inverse
    near, far = np.minimum(t1, t2), np.maximum(t1, t2)
    t_near, t_far = near.max(axis=1), far.min(axis=1)
    t = np.where((t_near <= t_far) & (t_near > _EPSILON), t_near, np.inf)
    points = o + np.where(np.isfinite(t), t, 0.0)[:, None] * d
    normals = np.zeros_like(points)
    axis = near.argmax(axis=1)
    rows = np.arange(len(d))
    normals[rows, axis] = -np.sign(d[rows, axis])
    return t, points, normals


def _cell_hash(cells: np.ndarray) -> np.ndarray:
    """A deterministic pseudo-random value in [0, 1) per integer cell [N,3] (a 64-bit mixing hash)."""
    key = (cells.astype(np.uint64) * np.array([0x9E3779B1, 0x85EBCA77, 0xC2B2AE3D], dtype=np.uint64)).sum(axis=1)
    for shift in (33, 29, 32):
        key ^= key >> np.uint64(shift)
        key *= np.uint64(0xFF51AFD7ED558CCD)
    return (key >> np.uint64(40)).astype(np.float64) / float(1 << 24)


def _shade(prim: Primitive, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    # The quarter-cell offset keeps texture edges off the faces of boxes with round sizes.
    cells = np.floor(points / prim.period + 0.25).astype(np.int64)
    if prim.pattern == "speckle":
        mix = _cell_hash(cells)[:, None]
        base = (1.0 - mix) * np.asarray(prim.colors[0]) + mix * np.asarray(prim.colors[1])
    else:
        parity = (cells.sum(axis=1) if prim.pattern == "checker" else cells[:, 2]) % 2
        base = np.where(parity[:, None] == 0, np.asarray(prim.colors[0]), np.asarray(prim.colors[1]))
    world_normals = _rotate(prim.rotation, normals)
    shade = np.full(len(points), AMBIENT)
    for direction, weight in LIGHTS:
        shade += weight * np.maximum(world_normals @ (direction / np.linalg.norm(direction)), 0.0)
    return base * shade[:, None]


def cast_rays(prims: list[Primitive], origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(colour [N,3], index of the primitive hit or -1 [N]) for unit rays from one origin."""
    best = np.full(len(dirs), np.inf)
    colors = np.zeros((len(dirs), 3))
    hit = np.full(len(dirs), -1)
    for index, prim in enumerate(prims):
        # Only rays that pass through the primitive's bounding sphere are intersected exactly:
        # each limb covers a small part of the image, so this skips most of the work.
        center, radius = _bounding_sphere(prim)
        along = dirs @ (center - origin)
        miss = np.sum((center - origin) ** 2) - along**2 > radius**2
        candidates = np.flatnonzero(~miss & (along > 0))
        t, points, normals = _intersect(prim, origin, dirs[candidates])
        closer = t < best[candidates]
        rays = candidates[closer]
        best[rays] = t[closer]
        hit[rays] = index
        colors[rays] = _shade(prim, points[closer], normals[closer])
    return colors, hit


def _bounding_sphere(prim: Primitive) -> tuple[np.ndarray, float]:
    if prim.shape == "sphere":
        return prim.translation, prim.size[0]
    if prim.shape == "capsule":
        radius, length = prim.size
        return prim.translation + prim.rotation[:, 2] * (0.5 * length), 0.5 * length + radius
    return prim.translation, float(np.linalg.norm(prim.size))


def render_rgba(
    prims: list[Primitive],
    K: np.ndarray,
    cam_to_world: np.ndarray,
    width: int,
    height: int,
    supersample: int = 2,
) -> np.ndarray:
    """uint8 RGBA [H,W,4] (straight alpha) of an OpenCV pinhole camera; pixel centres at i + 0.5."""
    s = supersample
    offsets = (np.arange(s) + 0.5) / s
    us = (np.arange(width)[:, None] + offsets).ravel()
    rows_per_chunk = max(1, 2**16 // (width * s * s))  # bounds memory at large sizes
    rgba = np.zeros((height, width, 4))
    for row in range(0, height, rows_per_chunk):
        rows = min(rows_per_chunk, height - row)
        vs = (np.arange(row, row + rows)[:, None] + offsets).ravel()
        u, v = np.meshgrid(us, vs)
        dirs = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1).reshape(-1, 3)
        dirs = _rotate(cam_to_world[:3, :3], dirs)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        colors, hit = cast_rays(prims, cam_to_world[:3, 3], dirs)
        samples = np.concatenate([colors * (hit >= 0)[:, None], (hit >= 0)[:, None]], axis=1)
        rgba[row : row + rows] = samples.reshape(rows, s, width, s, 4).mean(axis=(1, 3))
    alpha = rgba[..., 3:]
    rgb = np.divide(rgba[..., :3], alpha, out=np.zeros_like(rgba[..., :3]), where=alpha > 0)
    return np.rint(np.concatenate([rgb, alpha], axis=-1) * 255.0).clip(0, 255).astype(np.uint8)


def surface_points(prims: list[Primitive], count: int, rng: np.random.Generator) -> np.ndarray:
    """[count, 3] points uniformly spread over the primitives' surfaces (by area)."""
    areas = []
    for prim in prims:
        if prim.shape == "sphere":
            areas.append(4.0 * math.pi * prim.size[0] ** 2)
        elif prim.shape == "capsule":
            areas.append(2.0 * math.pi * prim.size[0] * prim.size[1] + 4.0 * math.pi * prim.size[0] ** 2)
        else:
            hx, hy, hz = prim.size
            areas.append(8.0 * (hx * hy + hy * hz + hx * hz))
    counts = rng.multinomial(count, np.asarray(areas) / sum(areas))
    chunks = []
    for prim, n in zip(prims, counts):
        unit = rng.normal(size=(n, 3))
        unit /= np.linalg.norm(unit, axis=1, keepdims=True)
        if prim.shape == "sphere":
            local = unit * prim.size[0]
        elif prim.shape == "capsule":
            radius, length = prim.size
            # Hemispherical caps: a sphere point with z > 0 moves to the far end; the rest of
            # the points, in proportion to the side's area, go on the cylinder.
            local = unit * radius + np.outer(unit[:, 2] > 0, [0.0, 0.0, length])
            side = rng.random(n) < length / (length + 2.0 * radius)
            angle = rng.uniform(0.0, 2.0 * math.pi, side.sum())
            local[side] = np.stack(
                [radius * np.cos(angle), radius * np.sin(angle), rng.uniform(0.0, length, side.sum())], axis=1
            )
        else:
            half = np.asarray(prim.size)
            face_areas = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]])
            axis = rng.choice(3, size=n, p=face_areas / face_areas.sum())
            local = rng.uniform(-half, half, size=(n, 3))
            local[np.arange(n), axis] = half[axis] * rng.choice([-1.0, 1.0], size=n)
        chunks.append(_rotate(prim.rotation, local) + prim.translation)
    return np.concatenate(chunks)


# ---- cameras and files -------------------------------------------------------------------------


def orbit_camera(rng: np.random.Generator) -> np.ndarray:
    """A camera-to-world [4,4] (OpenCV axes) on the sphere of CAMERA_RADIUS, looking at the origin."""
    azimuth = rng.uniform(0.0, 2.0 * math.pi)
    elevation = math.asin(rng.uniform(*np.sin(ELEVATION_RANGE)))  # uniform in area over the band
    center = CAMERA_RADIUS * np.array(
        [
            math.cos(elevation) * math.cos(azimuth),
            math.cos(elevation) * math.sin(azimuth),
            math.sin(elevation),
        ]
    )
    forward = -center / np.linalg.norm(center)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    cam_to_world = np.eye(4)
    cam_to_world[:3, :3] = np.stack([right, down, forward], axis=1)
    cam_to_world[:3, 3] = center
    return cam_to_world


def split_of(index: int, frames: int) -> str:
    if index in (0, frames - 1):
        return "train"  # the first and last frame fix the time range of both layouts
    return {4: "test", 6: "val"}.get(index % 8, "train")


def _write_json(path: Path, data: object) -> None:
    path.write_text(json.dumps(data, indent=2) + "\n")


MOVING_THRESHOLD = 0.1
"""A pixel moves when some channel (or coverage) changes by more than this between neighbouring frames."""


def moving_mask(
    name: str, K: np.ndarray, cam_to_world: np.ndarray, width: int, height: int, time: float, step: float
) -> np.ndarray:
    """bool [H,W]: pixels of this view whose ground truth changes between time - step and time + step.

    The scene is rendered again from the same camera at the neighbouring frame times (clamped
    to [0, 1]), so the mask is where the motion is, not where the camera moved.
    """
    frames = []
    for t in (max(time - step, 0.0), time, min(time + step, 1.0)):
        rgba = render_rgba(scene_primitives(name, t), K, cam_to_world, width, height).astype(np.float32) / 255.0
        frames.append(np.concatenate([rgba[..., :3] * rgba[..., 3:], rgba[..., 3:]], axis=-1))
    before, now, after = frames
    changed = np.maximum(np.abs(now - before), np.abs(now - after)).max(axis=-1)
    return changed > MOVING_THRESHOLD


LAYOUTS = ("dnerf", "nerfies")
"""The folders a generated scene has: the same views in the D-NeRF and in the Nerfies layout."""


def generate_synthetic(
    name: str, out_dir: str | Path, size: int = 128, frames: int = 80, seed: int = 0, supersample: int = 2
) -> Path:
    """Render scene `name` and write it to out_dir/dnerf and out_dir/nerfies; returns out_dir.

    The scene is rendered into a temporary folder beside out_dir and moved into place when
    complete, so a failure (a full disk, Ctrl-C) leaves no partial scene; a scene already at
    out_dir is replaced whole or, on failure, kept.
    """
    if name not in SCENES:
        raise ConfigError(f"unknown synthetic scene '{name}' (choose from {', '.join(SYNTHETIC_SCENES)})")
    if size < 8 or frames < 8 or supersample < 1:
        raise ConfigError(
            f"synthetic scene: need size >= 8, frames >= 8, supersample >= 1 (got {size}, {frames}, {supersample})"
        )
    out = Path(out_dir)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    try:
        shutil.rmtree(tmp, ignore_errors=True)
        _write_scene(name, tmp, size, frames, seed, supersample)
        if not out.exists():
            os.replace(tmp, out)
            return out
        for layout in LAYOUTS:  # into an existing folder: each layout replaced whole
            if (out / layout).exists():
                os.replace(out / layout, tmp / f"replaced-{layout}")
            os.replace(tmp / layout, out / layout)
    except BaseException as err:
        shutil.rmtree(tmp, ignore_errors=True)
        if disk_full(err):
            kept = "the previous scene is kept" if out.exists() else "nothing was written"
            raise LiquidGSError(
                f"no space left on {out.parent} while writing the synthetic scene {out}; {kept}"
            ) from None
        raise
    shutil.rmtree(tmp)
    return out


def _write_scene(name: str, out: Path, size: int, frames: int, seed: int, supersample: int) -> None:
    dnerf, nerfies = (out / layout for layout in LAYOUTS)
    for folder in (
        dnerf / "train",
        dnerf / "val",
        dnerf / "test",
        nerfies / "camera",
        nerfies / "rgb" / "1x",
    ):
        folder.mkdir(parents=True, exist_ok=True)

    rng = np.random.default_rng(seed)
    focal = focal_from_fov(DNERF_CAMERA_ANGLE_X, size)
    K = centred_intrinsics(focal, size, size, dtype=torch.float64).numpy()
    transforms: dict[str, list[dict]] = {"train": [], "val": [], "test": []}
    ids = [f"{i:04d}" for i in range(frames)]
    metadata = {}
    for index, image_id in enumerate(ids):
        time = index / (frames - 1)
        cam_to_world = orbit_camera(rng)
        rgba = render_rgba(scene_primitives(name, time), K, cam_to_world, size, size, supersample)
        buffer = io.BytesIO()
        Image.fromarray(rgba, "RGBA").save(buffer, format="PNG")

        split = split_of(index, frames)
        file_path = f"./{split}/r_{len(transforms[split]):03d}"
        (dnerf / f"{file_path}.png").write_bytes(buffer.getvalue())
        transforms[split].append(
            {
                "file_path": file_path,
                "time": time,
                "transform_matrix": (cam_to_world @ np.diag([1.0, -1.0, -1.0, 1.0])).tolist(),
            }
        )

        (nerfies / "rgb" / "1x" / f"{image_id}.png").write_bytes(buffer.getvalue())
        _write_json(
            nerfies / "camera" / f"{image_id}.json",
            {
                "orientation": cam_to_world[:3, :3].T.tolist(),
                "position": cam_to_world[:3, 3].tolist(),
                "focal_length": focal,
                "principal_point": [size / 2, size / 2],
                "skew": 0.0,
                "pixel_aspect_ratio": 1.0,
                "radial_distortion": [0.0, 0.0, 0.0],
                "tangential_distortion": [0.0, 0.0],
                "image_size": [size, size],
            },
        )
        metadata[image_id] = {"time_id": index, "warp_id": index, "appearance_id": index, "camera_id": 0}

    for split, items in transforms.items():
        _write_json(dnerf / f"transforms_{split}.json", {"camera_angle_x": DNERF_CAMERA_ANGLE_X, "frames": items})
    train_ids = [i for n, i in enumerate(ids) if split_of(n, frames) == "train"]
    test_ids = [i for n, i in enumerate(ids) if split_of(n, frames) == "test"]
    _write_json(
        nerfies / "dataset.json",
        {
            "count": frames,
            "num_exemplars": len(train_ids),
            "ids": ids,
            "train_ids": train_ids,
            "val_ids": test_ids,
        },
    )
    _write_json(nerfies / "metadata.json", metadata)
    _write_json(
        nerfies / "scene.json",
        {"scale": 1.0, "center": [0.0, 0.0, 0.0], "near": CAMERA_RADIUS - 2.0, "far": CAMERA_RADIUS + 2.0},
    )
    points = surface_points(scene_primitives(name, 0.0), POINT_COUNT, rng)
    np.save(nerfies / "points.npy", points.astype(np.float32))
