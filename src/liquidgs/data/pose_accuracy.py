"""How far registered camera poses are from reference poses (ground truth, or another registration).

A registration fixes poses only up to a similarity (COLMAP's gauge: position, orientation and scale
of the world are free), so the centres are first moved onto the reference by the similarity that
fits them best (Umeyama 1991); what remains is the centre error, as an RMS in the reference's units
and as a share of the reference path's length. Rotations are compared frame to frame (the relative
rotation R_i^T R_j of every pair, against the reference's), which no gauge changes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from liquidgs.data.nerfies import DATASET_FILE, camera_path


def similarity(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R, t) minimising |s R source + t - target|^2 over [N, 3] points (Umeyama 1991)."""
    mean_s, mean_t = source.mean(0), target.mean(0)
    a, b = source - mean_s, target - mean_t
    u, singular, vt = np.linalg.svd(b.T @ a / len(source))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    rotation = u @ d @ vt
    scale = float(np.trace(np.diag(singular) @ d) / max(a.var(0).sum(), 1e-300))
    return scale, rotation, mean_t - scale * rotation @ mean_s


def rotation_angle_deg(rotations: np.ndarray) -> np.ndarray:
    """The angle of each [..., 3, 3] rotation, in degrees."""
    cosines = (np.trace(rotations, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cosines, -1.0, 1.0)))


@dataclass(frozen=True)
class PoseScore:
    frames: int
    centre_rms: float
    """RMS distance of the aligned centres from the reference's, in the reference's units."""
    path_length: float
    """Length of the reference's camera path (centre to centre, in order)."""
    relative_rotation_mean_deg: float
    """Mean, over every pair of frames, of the angle between their relative rotation and the reference's."""
    relative_rotation_max_deg: float

    @property
    def centre_rms_share(self) -> float:
        """centre_rms as a share of the reference path's length."""
        return self.centre_rms / self.path_length if self.path_length > 0 else float("inf")

    def describe(self) -> str:
        return (
            f"{self.frames} frames: centre RMS {self.centre_rms:.4g} ({100 * self.centre_rms_share:.2f}% of the "
            f"path), relative rotation {self.relative_rotation_mean_deg:.3f} deg mean, "
            f"{self.relative_rotation_max_deg:.3f} deg max"
        )


def score_poses(cam_to_world: np.ndarray, reference: np.ndarray) -> PoseScore:
    """Score [N, 4, 4] camera-to-world poses against the reference's [N, 4, 4] (same frames, same order)."""
    if cam_to_world.shape != reference.shape or cam_to_world.ndim != 3 or len(cam_to_world) < 2:
        raise ValueError(f"pose arrays of shape {cam_to_world.shape} and {reference.shape}: need [N >= 2, 4, 4] each")
    centres, true_centres = cam_to_world[:, :3, 3], reference[:, :3, 3]
    scale, rotation, shift = similarity(centres, true_centres)
    moved = centres @ (scale * rotation).T + shift
    rms = float(np.sqrt(np.mean(np.sum((moved - true_centres) ** 2, axis=1))))
    path = float(np.sum(np.linalg.norm(np.diff(true_centres, axis=0), axis=1)))
    ours, truth = cam_to_world[:, :3, :3], reference[:, :3, :3]
    first, second = np.triu_indices(len(ours), k=1)
    relative = np.einsum("nji,njk->nik", ours[first], ours[second])  # R_i^T R_j
    relative_truth = np.einsum("nji,njk->nik", truth[first], truth[second])
    errors = rotation_angle_deg(np.einsum("nij,nkj->nik", relative, relative_truth))
    return PoseScore(len(ours), rms, path, float(errors.mean()), float(errors.max()))


def scene_poses(scene: Path) -> dict[str, np.ndarray]:
    """The registered frames of a Nerfies-layout scene: id -> camera-to-world [4, 4] (OpenCV axes)."""
    ids = json.loads((scene / DATASET_FILE).read_text())["ids"]
    poses = {}
    for image_id in ids:
        camera = json.loads(camera_path(scene, image_id).read_text())
        pose = np.eye(4)
        pose[:3, :3] = np.asarray(camera["orientation"], dtype=np.float64).T  # orientation is world -> camera
        pose[:3, 3] = camera["position"]
        poses[image_id] = pose
    return poses


def score_scenes(scene: Path, reference: Path) -> PoseScore:
    """Score one scene's cameras against another's, on the frames both registered."""
    ours, theirs = scene_poses(scene), scene_poses(reference)
    shared = [image_id for image_id in ours if image_id in theirs]
    return score_poses(np.stack([ours[i] for i in shared]), np.stack([theirs[i] for i in shared]))
