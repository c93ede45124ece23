"""A handheld video of a dynamic scene with known cameras, for the own-video pipeline tests.

The built-in ray caster renders a checkered ball (the moving object) that rolls across the view
and back while it bounces, in front of a static wall and floor with a non-repeating speckle
texture (COLMAP needs texture it can tell apart).
The camera drifts sideways along a smooth arc with handheld-like bob, sway and roll, always
roughly facing the figure. Everything is deterministic.

A `Lens` renders the same video through a distorting lens (OpenCV's model, which is Nerfies'
and, with k1 alone, COLMAP's SIMPLE_RADIAL): each ray leaves through the undistorted position
of its pixel, found by Newton's method here, independent of COLMAP's own inverse.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from liquidgs.data.synthetic import Primitive, cast_rays, render_rgba
from liquidgs.media import write_video

WIDTH, HEIGHT = 200, 152
FOCAL = 190.0
FPS = 12
BACKGROUND = [
    Primitive("wall", "box", (9.0, 0.2, 3.0), ((0.15, 0.2, 0.3), (0.95, 0.9, 0.8)), "speckle", 0.16,
              np.eye(3), np.array([0.0, 2.6, 0.6])),
    Primitive("floor", "box", (9.0, 3.5, 0.2), ((0.3, 0.2, 0.1), (0.9, 0.95, 0.7)), "speckle", 0.13,
              np.eye(3), np.array([0.0, 0.0, -1.35])),
]  # fmt: skip


def moving_ball(time: float) -> Primitive:
    """Across and back (x from -1.2 to 1.2 and back), two bounces, rolling as it goes."""
    x = -1.2 + 2.4 * (1.0 - abs(1.0 - 2.0 * time))
    z = -0.7 + 0.6 * abs(math.sin(2.0 * math.pi * time))
    cos, sin = math.cos(x / 0.45), math.sin(x / 0.45)  # rolling: turned by distance / radius about y
    rotation = np.array([[cos, 0.0, sin], [0.0, 1.0, 0.0], [-sin, 0.0, cos]])
    return Primitive("ball", "sphere", (0.45,), ((0.95, 0.85, 0.1), (0.1, 0.1, 0.5)), "checker", 0.14,
                     rotation, np.array([x, 0.0, z]))  # fmt: skip


@dataclass(frozen=True)
class Lens:
    """Distortion of normalised image coordinates: radial k1, k2, k3 and tangential p1, p2."""

    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    def distort(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        return (
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + 2.0 * self.p2 * x * y + self.p1 * (r2 + 2.0 * y * y),
        )

    def undistort(self, xd: np.ndarray, yd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The (x, y) that distort() maps to (xd, yd): Newton's method with a numerical Jacobian."""
        x, y = xd.copy(), yd.copy()
        step = 1e-7
        for _ in range(20):
            fx, fy = self.distort(x, y)
            ex, ey = fx - xd, fy - yd
            ax, ay = self.distort(x + step, y)
            bx, by = self.distort(x, y + step)
            j11, j21, j12, j22 = (ax - fx) / step, (ay - fy) / step, (bx - fx) / step, (by - fy) / step
            det = j11 * j22 - j12 * j21
            x, y = x - (j22 * ex - j12 * ey) / det, y - (j11 * ey - j21 * ex) / det
        fx, fy = self.distort(x, y)
        assert max(np.abs(fx - xd).max(), np.abs(fy - yd).max()) < 1e-9, "lens too strong to invert here"
        return x, y


def render_through_lens(prims: list[Primitive], K: np.ndarray, cam_to_world: np.ndarray, width: int, height: int,
                        lens: Lens, supersample: int = 2) -> np.ndarray:  # fmt: skip
    """render_rgba's image (uint8 RGBA, pixel centres at i + 0.5) seen through `lens`."""
    if lens == Lens():
        return render_rgba(prims, K, cam_to_world, width, height, supersample=supersample)
    rays = _lens_rays(lens, tuple(K.ravel()), width, height, supersample)
    dirs = rays @ cam_to_world[:3, :3].T
    colors, hit = cast_rays(prims, cam_to_world[:3, 3], dirs / np.linalg.norm(dirs, axis=1, keepdims=True))
    samples = np.concatenate([colors * (hit >= 0)[:, None], (hit >= 0)[:, None]], axis=1)
    rgba = samples.reshape(height, supersample, width, supersample, 4).mean(axis=(1, 3))
    alpha = rgba[..., 3:]
    rgb = np.divide(rgba[..., :3], alpha, out=np.zeros_like(rgba[..., :3]), where=alpha > 0)
    return np.rint(np.concatenate([rgb, alpha], axis=-1) * 255.0).clip(0, 255).astype(np.uint8)


@functools.lru_cache(maxsize=8)
def _lens_rays(lens: Lens, K: tuple[float, ...], width: int, height: int, supersample: int) -> np.ndarray:
    """[height * s * width * s, 3] camera-frame rays through the sample points (row-major, as
    render_rgba orders them); the same for every frame of a video, so computed once."""
    fx, _, cx, _, fy, cy = K[:6]
    offsets = (np.arange(supersample) + 0.5) / supersample
    u, v = np.meshgrid((np.arange(width)[:, None] + offsets).ravel(), (np.arange(height)[:, None] + offsets).ravel())
    x, y = lens.undistort((u - cx) / fx, (v - cy) / fy)
    return np.stack([x, y, np.ones_like(x)], axis=-1).reshape(-1, 3)


def sweeping_camera(frames: int, baseline: float, pan_degrees: float) -> list[np.ndarray]:
    """Camera-to-world poses of a camera 4.2 in front of the wall that slides `baseline` sideways
    (along x, evenly) while it pans `pan_degrees` (evenly, centred on the wall); 0 is a camera
    turning in place."""
    poses = []
    for index in range(frames):
        s = index / (frames - 1)
        yaw = math.radians(pan_degrees * (s - 0.5))
        eye = np.array([baseline * (s - 0.5), -4.2, 0.4])
        forward = np.array([math.sin(yaw), math.cos(yaw), -0.05])
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        pose = np.eye(4)
        pose[:3, :3] = np.stack([right, np.cross(forward, right), forward], axis=1)
        pose[:3, 3] = eye
        poses.append(pose)
    return poses


def scene_at(time: float) -> list[Primitive]:
    return [moving_ball(time), *BACKGROUND]


@dataclass
class HandheldVideo:
    path: Path
    images: list[np.ndarray]  # the frames as rendered, uint8 [H, W, 3], before video compression
    cam_to_world: np.ndarray  # [frames, 4, 4], OpenCV axes
    dynamic_masks: list[np.ndarray]  # per frame: True where the moving ball covers the pixel
    K: np.ndarray
    lens: Lens


def camera_path(frames: int) -> np.ndarray:
    """[frames, 4, 4] camera-to-world along a 60-degree arc of radius 4.2, with handheld wobble."""
    poses = []
    for index in range(frames):
        s = index / (frames - 1)
        azimuth = math.radians(-120.0 + 60.0 * s)  # around -y, the side facing the wall
        eye = np.array([4.2 * math.cos(azimuth), 4.2 * math.sin(azimuth), 0.4])
        eye += np.array([0.05 * math.sin(7.0 * s), 0.04 * math.sin(5.0 * s + 1.0), 0.08 * math.sin(9.0 * s)])
        target = np.array([0.1 * math.sin(4.0 * s), 0.0, 0.2 + 0.05 * math.sin(6.0 * s)])
        forward = (target - eye) / np.linalg.norm(target - eye)
        roll = 0.04 * math.sin(8.0 * s + 0.5)
        up = np.array([math.sin(roll), 0.0, math.cos(roll)])
        right = np.cross(forward, up)
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        pose = np.eye(4)
        pose[:3, :3] = np.stack([right, down, forward], axis=1)
        pose[:3, 3] = eye
        poses.append(pose)
    return np.stack(poses)


def render_handheld_video(path: Path, frames: int, lens: Lens = Lens()) -> HandheldVideo:
    K = np.array([[FOCAL, 0.0, WIDTH / 2], [0.0, FOCAL, HEIGHT / 2], [0.0, 0.0, 1.0]])
    poses = camera_path(frames)
    images, masks = [], []
    for index, pose in enumerate(poses):
        prims = scene_at(index / (frames - 1))
        images.append(render_through_lens(prims, K, pose, WIDTH, HEIGHT, lens, supersample=2)[..., :3])
        masks.append(render_through_lens(prims[:1], K, pose, WIDTH, HEIGHT, lens, supersample=1)[..., 3] > 0)
    write_video(path, images, fps=FPS)
    return HandheldVideo(path=path, images=images, cam_to_world=poses, dynamic_masks=masks, K=K, lens=lens)
