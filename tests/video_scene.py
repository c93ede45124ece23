"""A handheld video of a dynamic scene with known cameras, for the own-video pipeline tests.

The built-in ray caster renders a checkered ball (the moving object) that rolls across the view
and back while it bounces, in front of a static wall and floor with a non-repeating speckle
texture (COLMAP needs texture it can tell apart).
The camera drifts sideways along a smooth arc with handheld-like bob, sway and roll, always
roughly facing the figure. Everything is deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from liquidgs.data.synthetic import Primitive, render_rgba
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


@dataclass
class HandheldVideo:
    path: Path
    images: list[np.ndarray]  # the frames as rendered, uint8 [H, W, 3], before video compression
    cam_to_world: np.ndarray  # [frames, 4, 4], OpenCV axes
    dynamic_masks: list[np.ndarray]  # per frame: True where the moving ball covers the pixel
    K: np.ndarray


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


def render_handheld_video(path: Path, frames: int) -> HandheldVideo:
    K = np.array([[FOCAL, 0.0, WIDTH / 2], [0.0, FOCAL, HEIGHT / 2], [0.0, 0.0, 1.0]])
    poses = camera_path(frames)
    images, masks = [], []
    for index, pose in enumerate(poses):
        ball = moving_ball(index / (frames - 1))
        images.append(render_rgba([ball, *BACKGROUND], K, pose, WIDTH, HEIGHT, supersample=2)[..., :3])
        masks.append(render_rgba([ball], K, pose, WIDTH, HEIGHT, supersample=1)[..., 3] > 0)
    write_video(path, images, fps=FPS)
    return HandheldVideo(path=path, images=images, cam_to_world=poses, dynamic_masks=masks, K=K)
