"""How far estimated cameras are from true ones, as given and after a gauge alignment.

Refining cameras together with the scene leaves a gauge free: moving (and scaling) the whole
world, cameras and Gaussians together, renders the same images. Comparing refined poses with the
true ones raw counts that drift as error; the aligned error first maps the estimated cameras by
the one similarity (scale s, rotation Q, shift t) that best fits them to the true ones, and then
measures what is left. The fit is Umeyama's on the camera centres with the cameras' rotations in
the same cross-covariance (so a near-collinear camera path still fixes Q), the rotations weighted
by the centres' spread so neither term's units dominate.

Rotation and centre errors can mislead on an object-centric capture: turning a camera by a small
angle about its centre and shifting it sideways by that angle times the object's distance move the
object's image alike, so the photos barely tell the two apart and a refined camera may trade one
for the other. The reprojection error says what the images can see: how far (pixels) the scene's
points land from where the true camera puts them, after the same gauge alignment.
"""

from __future__ import annotations

import math

import torch


def _centres_and_rotations(viewmats: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Camera centres [N, 3] and camera->world rotations [N, 3, 3] of world->camera matrices [N, 4, 4]."""
    rotations = viewmats[:, :3, :3].transpose(1, 2)
    return -(rotations @ viewmats[:, :3, 3:]).squeeze(-1), rotations


def _angles_deg(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Angle [N] of the relative rotation of each pair of rotation matrices [N, 3, 3]."""
    return torch.rad2deg(_angles(a.transpose(1, 2) @ b))


def _angles(relative: torch.Tensor) -> torch.Tensor:
    """Rotation angles (radians) of matrices [..., 3, 3], by atan2: arccos of the trace loses small
    angles (1e-4 rad from rounding at float32)."""
    cosine = (relative.diagonal(dim1=-2, dim2=-1).sum(-1) - 1.0) / 2.0
    skew = relative - relative.transpose(-2, -1)
    sine = torch.stack([skew[..., 2, 1], skew[..., 0, 2], skew[..., 1, 0]], dim=-1).norm(dim=-1) / 2.0
    return torch.atan2(sine, cosine)


def gauge_similarity(estimated: torch.Tensor, truth: torch.Tensor) -> tuple[float, torch.Tensor, torch.Tensor]:
    """(s, Q, t) with s Q c + t mapping estimated camera centres c onto the true ones (least squares),
    Q also turning the estimated camera rotations onto the true ones."""
    centres_est, rotations_est = _centres_and_rotations(estimated)
    centres_true, rotations_true = _centres_and_rotations(truth)
    mean_est, mean_true = centres_est.mean(0), centres_true.mean(0)
    spread_est, spread_true = centres_est - mean_est, centres_true - mean_true
    variance = (spread_est**2).sum(-1).mean()
    turned = (rotations_true @ rotations_est.transpose(1, 2)).mean(0)
    covariance = spread_true.T @ spread_est / len(estimated) + variance * turned
    u, _, vt = torch.linalg.svd(covariance)
    flip = torch.ones(3, dtype=covariance.dtype)
    flip[2] = torch.sign(torch.linalg.det(u @ vt))
    rotation = u @ torch.diag(flip) @ vt
    scale = float((spread_true * (spread_est @ rotation.T)).sum() / (spread_est**2).sum().clamp_min(1e-300))
    return scale, rotation, mean_true - scale * rotation @ mean_est


def pose_errors(estimated: torch.Tensor, truth: torch.Tensor) -> dict:
    """Mean rotation error (degrees) and camera-centre error (world units) of world->camera matrices
    [N, 4, 4], raw and after the gauge similarity (its scale reported with it)."""
    estimated, truth = estimated.double().cpu(), truth.double().cpu()
    centres_est, rotations_est = _centres_and_rotations(estimated)
    centres_true, rotations_true = _centres_and_rotations(truth)
    scale, rotation, shift = gauge_similarity(estimated, truth)
    aligned_centres = scale * centres_est @ rotation.T + shift
    aligned_rotations = rotation @ rotations_est
    result = {
        "rotation_deg": float(_angles_deg(rotations_est, rotations_true).mean()),
        "translation": float((centres_est - centres_true).norm(dim=-1).mean()),
        "aligned_rotation_deg": float(_angles_deg(aligned_rotations, rotations_true).mean()),
        "aligned_translation": float((aligned_centres - centres_true).norm(dim=-1).mean()),
        "gauge_scale": scale,
        "gauge_rotation_deg": math.degrees(float(_angles(rotation))),
    }
    return result


def reprojection_error(
    estimated: torch.Tensor, truth: torch.Tensor, intrinsics: torch.Tensor, points: torch.Tensor
) -> float | None:
    """Mean distance (pixels) between the scene points [P, 3] (true world) projected by each true camera
    and by the estimated one after the gauge similarity; world->camera matrices [N, 4, 4], intrinsics
    [N, 3, 3]. Points behind either camera are left out; None when no point is in front of both."""
    estimated, truth = estimated.double().cpu(), truth.double().cpu()
    intrinsics, points = intrinsics.double().cpu(), points.double().cpu()
    scale, rotation, shift = gauge_similarity(estimated, truth)
    centres_est, rotations_est = _centres_and_rotations(estimated)
    centres_true, rotations_true = _centres_and_rotations(truth)
    centres_est, rotations_est = scale * centres_est @ rotation.T + shift, rotation @ rotations_est
    distances = []
    for i in range(len(truth)):
        in_true = (points - centres_true[i]) @ rotations_true[i]  # camera axes: R^T (x - c), row-wise
        in_est = (points - centres_est[i]) @ rotations_est[i]
        seen = (in_true[:, 2] > 1e-6) & (in_est[:, 2] > 1e-6)
        pixels_true, pixels_est = (x[seen] @ intrinsics[i].T for x in (in_true, in_est))
        offset = pixels_true[:, :2] / pixels_true[:, 2:] - pixels_est[:, :2] / pixels_est[:, 2:]
        distances.append(offset.norm(dim=-1))
    distances = torch.cat(distances)
    return float(distances.mean()) if len(distances) else None


def pose_recovery(
    given: torch.Tensor,
    refined: torch.Tensor,
    truth: torch.Tensor,
    intrinsics: torch.Tensor,
    points: torch.Tensor | None,
) -> dict:
    """How far camera refinement brought cameras made noisy on purpose (the stress tests' pose noise)
    back to the true ones: pose_errors (and, with the scene's points, the reprojection error in
    pixels) of the cameras trained from (`given`) and of the refined ones (world->camera [N, 4, 4])."""

    def errors(estimated: torch.Tensor) -> dict:
        found = {name: round(value, 6) for name, value in pose_errors(estimated, truth).items()}
        pixels = reprojection_error(estimated, truth, intrinsics, points) if points is not None else None
        if pixels is not None:
            found["reprojection_px"] = round(pixels, 4)
        return found

    return {"before": errors(given), "after": errors(refined)}
