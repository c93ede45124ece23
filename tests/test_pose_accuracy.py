"""The pose scorer: ~0 for the reference moved by any similarity, and the error put in for perturbed poses."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from liquidgs.data.pose_accuracy import score_poses
from video_scene import camera_path


def similarity_copy(poses: np.ndarray, scale: float, seed: int) -> np.ndarray:
    """The same cameras in another gauge: x' = s R x + t applied to the world."""
    rng = np.random.default_rng(seed)
    rotation = Rotation.random(random_state=seed).as_matrix()
    shift = rng.normal(size=3) * 10.0
    moved = poses.copy()
    moved[:, :3, :3] = rotation @ poses[:, :3, :3]
    moved[:, :3, 3] = scale * poses[:, :3, 3] @ rotation.T + shift
    return moved


@pytest.mark.parametrize("scale", [0.01, 1.0, 37.0])
def test_a_similarity_transformed_copy_scores_zero(scale):
    truth = camera_path(40)
    score = score_poses(similarity_copy(truth, scale, seed=3), truth)
    assert score.frames == 40
    assert score.centre_rms < 1e-9 * score.path_length
    assert score.relative_rotation_max_deg < 1e-5


def test_perturbed_poses_score_the_error_put_in():
    truth = camera_path(40)
    rng = np.random.default_rng(0)
    noisy = truth.copy()
    noise = rng.normal(size=(40, 3))
    noise *= 0.01 / np.sqrt(np.mean(np.sum(noise**2, axis=1)))  # centre RMS of exactly 0.01
    noisy[:, :3, 3] += noise
    turned = Rotation.from_rotvec(np.array([0.0, 0.0, np.radians(2.0)])).as_matrix()
    noisy[7, :3, :3] = noisy[7, :3, :3] @ turned  # one camera turned by 2 degrees
    score = score_poses(similarity_copy(noisy, 5.0, seed=1), truth)
    # The similarity fit absorbs a little of the noise: at most the RMS put in, most of it left.
    assert 0.008 < score.centre_rms <= 0.0100001, score
    # Frame 7 is 2 degrees off in its 39 pairs, of the 780: mean 0.1, max 2.
    assert score.relative_rotation_max_deg == pytest.approx(2.0, abs=1e-6)
    assert score.relative_rotation_mean_deg == pytest.approx(2.0 * 39 / 780, abs=1e-6)


def test_mismatched_pose_arrays_are_refused():
    with pytest.raises(ValueError, match="need"):
        score_poses(camera_path(5), camera_path(6))
