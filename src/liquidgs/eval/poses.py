"""How far estimated cameras are from true ones, as given and after a gauge alignment.

Refining cameras together with the scene leaves a gauge free: moving (and scaling) the whole
world, cameras and Gaussians together, renders the same images. Comparing refined poses with the
true ones raw counts that drift as error; the aligned error first maps the estimated cameras by
the one similarity (scale s, rotation Q, shift t) that best fits them to the true ones, and then
measures what is left. The fit is Umeyama's on the camera centres with the cameras' rotations in
the same cross-covariance (so a near-collinear camera path still fixes Q), the rotations weighted
by the centres' spread so neither term's units dominate.
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
