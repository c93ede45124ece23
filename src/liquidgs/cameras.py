"""Pinhole cameras in the rasteriser's conventions: the one camera type of data, render, viewer and training.

A camera is a world->camera matrix [4,4] in OpenCV axes (x right, y down, z forward), pinhole
intrinsics K [3,3] with pixel centres at integer + 0.5, and an image size. This module sits
beside errors/atomic, under data/ and render/, so that both can import it. It also owns the
pinhole focal length of a field of view, the camera centre, look-at matrices and orbits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

DNERF_CAMERA_ANGLE_X = 0.6911112070083618
"""The D-NeRF Blender scenes' horizontal field of view (radians), which the built-in scenes and
the raster benchmark copy."""


def focal_from_fov(fov: float, size: int) -> float:
    """Pinhole focal length in pixels for a full field of view (radians) across `size` pixels."""
    return 0.5 * size / math.tan(0.5 * fov)


def centred_intrinsics(focal: float, width: int, height: int, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """K [3,3] of a square-pixel pinhole with its principal point at the image centre."""
    return torch.tensor([[focal, 0.0, 0.5 * width], [0.0, focal, 0.5 * height], [0.0, 0.0, 1.0]], dtype=dtype)


def camera_centre(viewmat: torch.Tensor) -> torch.Tensor:
    """The camera's position [3] in world coordinates, -R^T t of world->camera [4,4]."""
    rotation, translation = viewmat[:3, :3], viewmat[:3, 3]
    return -rotation.T @ translation


def view_centre(viewmat: torch.Tensor) -> torch.Tensor:
    """The camera centre [3] SH colours are seen from: gsplat takes it from the inverted view
    matrix (not from -R^T t, `camera_centre`), which differs in the last bits."""
    return torch.linalg.inv(viewmat)[:3, 3]


@dataclass(frozen=True, eq=False)
class Camera:
    """One pinhole view: what `rasterize` needs besides the Gaussians."""

    viewmat: torch.Tensor
    """[4,4] world -> camera, OpenCV axes (x right, y down, z forward)."""
    K: torch.Tensor
    """[3,3] pinhole intrinsics; pixel centres at integer + 0.5."""
    width: int
    height: int

    @classmethod
    def from_fov(cls, viewmat: torch.Tensor, vertical_fov: float, width: int, height: int) -> Camera:
        """A camera with square pixels, its principal point at the image centre and this vertical
        field of view (radians)."""
        return cls(viewmat, centred_intrinsics(focal_from_fov(vertical_fov, height), width, height), width, height)

    @classmethod
    def from_camera_to_world(cls, camera_to_world: np.ndarray, vertical_fov: float, width: int, height: int) -> Camera:
        """`from_fov` for a camera-to-world [4,4] (OpenCV axes), as the viewer and camera paths hold it."""
        return cls.from_fov(torch.from_numpy(np.linalg.inv(camera_to_world)).float(), vertical_fov, width, height)

    @property
    def centre(self) -> torch.Tensor:
        return camera_centre(self.viewmat)

    @property
    def vertical_fov(self) -> float:
        """Vertical field of view in radians (the principal point taken at the image centre)."""
        return 2.0 * math.atan(0.5 * self.height / float(self.K[1, 1]))

    def camera_to_world(self) -> np.ndarray:
        """float64 [4,4] camera -> world (OpenCV axes)."""
        return np.linalg.inv(self.viewmat.double().numpy())


def look_at(eye: torch.Tensor, target: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
    """World->camera [4,4] in OpenCV axes (x right, y down, z forward) looking from eye at target."""
    forward = torch.nn.functional.normalize(target - eye, dim=0)
    right = torch.nn.functional.normalize(torch.linalg.cross(forward, up), dim=0)
    down = torch.linalg.cross(forward, right)
    rot = torch.stack([right, down, forward])  # rows: camera axes in world coordinates
    viewmat = torch.eye(4, dtype=eye.dtype)
    viewmat[:3, :3] = rot
    viewmat[:3, 3] = -rot @ eye
    return viewmat


def orbit(viewmats: torch.Tensor, n_frames: int) -> list[torch.Tensor]:
    """A circular path at the cameras' mean height and distance around the point they look at.

    The centre is the least-squares point nearest to all optical axes; 'up' is the mean of
    the cameras' up vectors (-y in OpenCV axes), so it works for Blender and Nerfies scenes.
    """
    viewmats = viewmats.double()
    centers = torch.stack([camera_centre(viewmat) for viewmat in viewmats])
    axes = viewmats[:, 2, :3]  # forward (z) axis of each camera in world coordinates
    # Solve sum_i (I - a_i a_i^T)(p - c_i) = 0 for the point p closest to every axis.
    eye3 = torch.eye(3, dtype=torch.float64)
    projectors = eye3 - axes[:, :, None] * axes[:, None, :]
    target = torch.linalg.lstsq(projectors.sum(0), (projectors @ centers[..., None]).sum(0)).solution[:, 0]
    up = torch.nn.functional.normalize(-viewmats[:, 1, :3].mean(0), dim=0)
    offsets = centers - target
    height = (offsets @ up).mean()
    radius = (offsets - (offsets @ up)[:, None] * up).norm(dim=1).mean()
    # Any unit vector orthogonal to up starts the circle.
    start = torch.nn.functional.normalize(offsets[0] - (offsets[0] @ up) * up, dim=0)
    side = torch.linalg.cross(up, start)
    path = []
    for i in range(n_frames):
        angle = 2.0 * math.pi * i / n_frames
        eye = target + up * height + radius * (math.cos(angle) * start + math.sin(angle) * side)
        path.append(look_at(eye, target, up).float())
    return path
