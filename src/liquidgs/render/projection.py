"""EWA projection of 3D Gaussians to the image plane, following gsplat 1.5.3's fully fused projection."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

# gsplat's ALPHA_THRESHOLD: fragments (and whole Gaussians) fainter than this are skipped.
ALPHA_THRESHOLD = 1.0 / 255.0
# gsplat's bounding-box extent in standard deviations before the opacity-aware tightening.
MAX_EXTENT_SIGMAS = 3.33
# gsplat's frustum clamp of the covariance's Jacobian: view-space tangents beyond the image's by
# more than this fraction of the half field of view are clamped.
FRUSTUM_MARGIN = 0.3


@dataclass
class Projection:
    """Per-Gaussian screen-space quantities; entries of culled Gaussians are finite but meaningless."""

    means2d: Tensor  # [N, 2] pixel coordinates
    conics: Tensor  # [N, 3] upper triangle (a, b, c) of the inverse 2D covariance
    depths: Tensor  # [N] camera-space z
    radii_xy: Tensor  # [N, 2] int32 bounding-box half extents in pixels, 0 where culled
    visible: Tensor  # [N] bool


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """Rotation matrices [N, 3, 3] from wxyz quaternions of any norm."""
    w, x, y, z = torch.nn.functional.normalize(quats, dim=-1).unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(-1, 3, 3)


def quat_scale_to_covariance(quats: Tensor, scales: Tensor) -> Tensor:
    """World covariances [N, 3, 3] = R S S^T R^T from wxyz quaternions (any norm) and std-devs."""
    half = quat_to_rotmat(quats) * scales[:, None, :]
    return half @ half.transpose(1, 2)


def project_gaussians(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    viewmat: Tensor,
    K: Tensor,
    width: int,
    height: int,
    near_plane: float,
    far_plane: float,
    eps2d: float,
) -> Projection:
    """Project Gaussians with a pinhole camera (OpenCV axes), culling exactly as gsplat does.

    Culled: depth < near_plane or > far_plane (a depth exactly on either plane is kept, as in gsplat's
    kernel: `mean_c.z < near_plane || mean_c.z > far_plane`), 2D determinant <= 0 after the eps2d blur, opacity
    below 1/255, or a bounding box entirely outside the image. Radii use gsplat's opacity-aware
    extent min(3.33, sqrt(2 ln(255 opacity))) per axis, rounded up.
    """
    rotation_w2c, translation_w2c = viewmat[:3, :3], viewmat[:3, 3]
    means_cam = means @ rotation_w2c.T + translation_w2c
    covs_cam = rotation_w2c @ quat_scale_to_covariance(quats, scales) @ rotation_w2c.T
    x, y, z = means_cam.unbind(-1)
    in_depth_range = (z >= near_plane) & (z <= far_plane)
    # Culled Gaussians get a harmless depth so no inf/NaN can leak into gradients through them.
    z_safe = torch.where(in_depth_range, z, torch.ones_like(z))

    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    # gsplat clamps the Jacobian's x/z, y/z to the field of view widened by 30% on each side.
    tan_half_fov_x = 0.5 * width / fx
    tan_half_fov_y = 0.5 * height / fy
    lim_x_pos = (width - cx) / fx + FRUSTUM_MARGIN * tan_half_fov_x
    lim_x_neg = cx / fx + FRUSTUM_MARGIN * tan_half_fov_x
    lim_y_pos = (height - cy) / fy + FRUSTUM_MARGIN * tan_half_fov_y
    lim_y_neg = cy / fy + FRUSTUM_MARGIN * tan_half_fov_y
    tx = z_safe * torch.minimum(torch.maximum(x / z_safe, -lim_x_neg), lim_x_pos)
    ty = z_safe * torch.minimum(torch.maximum(y / z_safe, -lim_y_neg), lim_y_pos)
    zeros = torch.zeros_like(z_safe)
    jacobian = torch.stack(
        [fx / z_safe, zeros, -fx * tx / z_safe**2, zeros, fy / z_safe, -fy * ty / z_safe**2], dim=-1
    ).reshape(-1, 2, 3)
    cov2d = jacobian @ covs_cam @ jacobian.transpose(1, 2)
    cov_a = cov2d[:, 0, 0] + eps2d
    cov_b = cov2d[:, 0, 1]
    cov_c = cov2d[:, 1, 1] + eps2d
    det = cov_a * cov_c - cov_b * cov_b
    positive_det = det > 0
    det_safe = torch.where(positive_det, det, torch.ones_like(det))
    conics = torch.stack([cov_c / det_safe, -cov_b / det_safe, cov_a / det_safe], dim=-1)
    means2d = torch.stack([fx * x / z_safe + cx, fy * y / z_safe + cy], dim=-1)

    with torch.no_grad():
        bright_enough = opacities >= ALPHA_THRESHOLD
        extent = torch.sqrt(2.0 * torch.log(opacities.clamp_min(ALPHA_THRESHOLD) / ALPHA_THRESHOLD))
        extent = extent.clamp_max(MAX_EXTENT_SIGMAS)
        radius_x = torch.ceil(extent * torch.sqrt(cov_a.clamp_min(0)))
        radius_y = torch.ceil(extent * torch.sqrt(cov_c.clamp_min(0)))
        on_screen = (
            (means2d[:, 0] + radius_x > 0)
            & (means2d[:, 0] - radius_x < width)
            & (means2d[:, 1] + radius_y > 0)
            & (means2d[:, 1] - radius_y < height)
        )
        visible = in_depth_range & positive_det & bright_enough & ((radius_x > 0) | (radius_y > 0)) & on_screen
        radii_xy = torch.stack([radius_x, radius_y], dim=-1).to(torch.int32)
        radii_xy = torch.where(visible[:, None], radii_xy, torch.zeros_like(radii_xy))
    return Projection(means2d=means2d, conics=conics, depths=z, radii_xy=radii_xy, visible=visible)
