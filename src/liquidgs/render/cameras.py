"""Camera helpers: pinhole intrinsics from a field of view, look-at view matrices and orbits
fitted to a set of cameras."""

from __future__ import annotations

import math

import torch


def pinhole_intrinsics(vertical_fov_degrees: float, width: int, height: int) -> torch.Tensor:
    """K [3,3] of a pinhole with this vertical field of view, principal point at the image centre."""
    focal = 0.5 * height / math.tan(0.5 * math.radians(vertical_fov_degrees))
    return torch.tensor([[focal, 0.0, 0.5 * width], [0.0, focal, 0.5 * height], [0.0, 0.0, 1.0]])


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


def camera_centers(viewmats: torch.Tensor) -> torch.Tensor:
    rot, trans = viewmats[:, :3, :3], viewmats[:, :3, 3]
    return -(rot.transpose(1, 2) @ trans[..., None])[..., 0]


def view_centre(viewmat: torch.Tensor) -> torch.Tensor:
    """The camera centre [3] SH colours are seen from: gsplat takes it from the inverted view
    matrix (not from -R^T t), which differs in the last bits."""
    return torch.linalg.inv(viewmat)[:3, 3]


def orbit(viewmats: torch.Tensor, n_frames: int) -> list[torch.Tensor]:
    """A circular path at the cameras' mean height and distance around the point they look at.

    The centre is the least-squares point nearest to all optical axes; 'up' is the mean of
    the cameras' up vectors (-y in OpenCV axes), so it works for Blender and Nerfies scenes.
    """
    viewmats = viewmats.double()
    centers = camera_centers(viewmats)
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
