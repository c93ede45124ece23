"""The one camera type and its formulas, against references written out here."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from liquidgs.cameras import Camera, camera_centre, centred_intrinsics, focal_from_fov, look_at, orbit, view_centre


def random_viewmat(seed: int) -> torch.Tensor:
    """World->camera of a camera at a random place and orientation, float64."""
    rng = np.random.default_rng(seed)
    camera_to_world = np.eye(4)
    camera_to_world[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    camera_to_world[:3, 3] = rng.normal(0.0, 3.0, 3)
    return torch.from_numpy(np.linalg.inv(camera_to_world))


@pytest.mark.parametrize("seed", range(5))
def test_centre_is_where_the_camera_to_world_puts_the_origin(seed):
    viewmat = random_viewmat(seed)
    expected = torch.linalg.inv(viewmat)[:3, 3]
    camera = Camera(viewmat, centred_intrinsics(50.0, 64, 48, torch.float64), 64, 48)
    torch.testing.assert_close(camera.centre, expected, rtol=0, atol=1e-12)
    torch.testing.assert_close(camera_centre(viewmat), expected, rtol=0, atol=1e-12)
    torch.testing.assert_close(view_centre(viewmat), expected, rtol=0, atol=1e-12)
    # The centre maps to the camera-space origin.
    torch.testing.assert_close((viewmat @ torch.cat([camera.centre, torch.ones(1, dtype=torch.float64)]))[:3],
                               torch.zeros(3, dtype=torch.float64), rtol=0, atol=1e-12)  # fmt: skip
    np.testing.assert_allclose(camera.camera_to_world(), torch.linalg.inv(viewmat).numpy(), atol=1e-12)


def test_focal_and_intrinsics_of_a_field_of_view():
    # 90 degrees across 100 pixels: the image edge is 50 px from the centre at 45 degrees.
    assert focal_from_fov(math.pi / 2, 100) == pytest.approx(50.0)
    camera = Camera.from_fov(torch.eye(4), math.radians(60.0), 40, 30)
    focal = 15.0 / math.tan(math.radians(30.0))
    expected = torch.tensor([[focal, 0.0, 20.0], [0.0, focal, 15.0], [0.0, 0.0, 1.0]])
    torch.testing.assert_close(camera.K, expected)
    assert camera.K.dtype == torch.float32 and (camera.width, camera.height) == (40, 30)
    assert camera.vertical_fov == pytest.approx(math.radians(60.0))
    # A point on the top edge of the field of view projects onto the top edge of the image.
    edge = torch.tensor([0.0, -math.tan(math.radians(30.0)), 1.0])
    assert float((camera.K @ edge)[1]) == pytest.approx(0.0, abs=1e-5)


def test_from_camera_to_world_inverts_the_pose():
    viewmat = random_viewmat(7)
    camera = Camera.from_camera_to_world(torch.linalg.inv(viewmat).numpy(), 0.8, 32, 32)
    torch.testing.assert_close(camera.viewmat, viewmat.float(), rtol=0, atol=1e-5)


def test_look_at_and_orbit_look_at_the_target():
    eye, target = torch.tensor([3.0, -2.0, 1.0]), torch.tensor([0.5, 0.0, 0.2])
    viewmat = look_at(eye, target, torch.tensor([0.0, 0.0, 1.0]))
    torch.testing.assert_close(camera_centre(viewmat), eye)
    in_camera = viewmat @ torch.cat([target, torch.ones(1)])
    torch.testing.assert_close(in_camera[:2], torch.zeros(2), rtol=0, atol=1e-6)  # on the optical axis
    assert in_camera[2] > 0  # in front
    ring = [look_at(torch.tensor([4 * math.cos(a), 4 * math.sin(a), 1.0]), torch.zeros(3), torch.tensor([0.0, 0, 1]))
            for a in np.linspace(0, 2 * math.pi, 8, endpoint=False)]  # fmt: skip
    for path_viewmat in orbit(torch.stack(ring), 5):
        torch.testing.assert_close(camera_centre(path_viewmat).norm(), torch.tensor(math.hypot(4.0, 1.0)), atol=1e-4,
                                   rtol=0)  # fmt: skip
        torch.testing.assert_close((path_viewmat @ torch.tensor([0.0, 0, 0, 1]))[:2], torch.zeros(2), atol=1e-4,
                                   rtol=0)  # fmt: skip
