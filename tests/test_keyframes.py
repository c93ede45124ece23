"""Keyframes (data.keyframes): which frames COLMAP solves, points tracked between frames, and the frames
between keyframes placed from the points they see, on a textured plane seen by cameras of known poses."""

from __future__ import annotations

import numpy as np
import pytest

from liquidgs.data.keyframes import MIN_KEYFRAMES, keyframe_names, keyframe_step, place_between
from liquidgs.data.optical_flow import import_cv2, track_points
from liquidgs.data.pose_accuracy import rotation_angle_deg
from liquidgs.errors import LiquidGSError
from shared_data import require_module

WIDTH, HEIGHT, FOCAL = 320, 240, 300.0
DEPTH = 3.0  # the cameras' distance from the plane z = 0


def test_the_step_keeps_enough_keyframes_and_short_clips_are_solved_whole():
    assert keyframe_step(150, 3) == 3 and keyframe_step(80, 3) == 3 and keyframe_step(50, 3) == 3
    assert keyframe_step(2 * MIN_KEYFRAMES, 3) == 2  # every 3rd would leave 11 keyframes
    assert keyframe_step(2 * MIN_KEYFRAMES - 1, 3) == 1 and keyframe_step(10, 3) == 1
    assert keyframe_step(500, 1) == 1
    names = [f"{i:06d}.png" for i in range(11)]
    assert keyframe_names(names, 3) == [names[i] for i in (0, 3, 6, 9, 10)]  # the last always a keyframe
    assert keyframe_names(names[:10], 3) == [names[i] for i in (0, 3, 6, 9)]


def texture(size: int = 800, seed: int = 0) -> np.ndarray:
    """Blurred noise: corners everywhere, no repeats."""
    cv2 = import_cv2()
    noise = np.random.default_rng(seed).uniform(0, 255, (size, size)).astype(np.float32)
    blurred = cv2.GaussianBlur(noise, (0, 0), 2.0)
    return cv2.normalize(blurred, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def test_points_are_tracked_to_a_sub_pixel_shift_and_those_that_leave_or_change_are_dropped():
    cv2 = import_cv2()
    a = texture()[:HEIGHT, :WIDTH].copy()
    shift = np.array([2.3, -1.6])
    b = cv2.warpAffine(a, np.array([[1, 0, shift[0]], [0, 1, shift[1]]]), (WIDTH, HEIGHT), flags=cv2.INTER_CUBIC)
    grid = np.stack(np.meshgrid(np.arange(40, 281, 20), np.arange(40, 201, 20)), -1).reshape(-1, 2).astype(float)
    there, kept = track_points(a, b, grid)
    assert kept.all()
    assert np.abs(there - grid - shift).max() < 0.05
    # A point carried out of the image, and one whose surroundings were replaced, are not kept.
    edge = np.array([[WIDTH - 1.5, 120.0]])
    b[100:140, 100:140] = texture(seed=1)[:40, :40]
    there, kept = track_points(a, b, np.concatenate([edge, [[120.0, 120.0]], grid[:1]]))
    assert kept.tolist() == [False, False, True]


def camera_at(x: float, y: float) -> np.ndarray:
    """World -> camera [3, 4] of a camera at (x, y, -DEPTH) looking along +z at the plane."""
    return np.concatenate([np.eye(3), -np.array([[x], [y], [-DEPTH]])], axis=1)


def render_plane(image: np.ndarray, cam_from_world: np.ndarray) -> np.ndarray:
    """The textured plane z = 0 (the texture spanning x, y in [-2, 2]) seen by the camera, pixel centres at
    integers (COLMAP's at +0.5)."""
    cv2 = import_cv2()
    size = image.shape[0]
    texture_to_plane = np.array([[4 / size, 0, -2], [0, 4 / size, -2], [0, 0, 1]])
    intrinsics = np.array([[FOCAL, 0, WIDTH / 2 - 0.5], [0, FOCAL, HEIGHT / 2 - 0.5], [0, 0, 1]])
    homography = intrinsics @ cam_from_world[:, [0, 1, 3]] @ texture_to_plane
    return cv2.warpPerspective(image, homography, (WIDTH, HEIGHT), flags=cv2.INTER_CUBIC)


def plane_clip(folder, pycolmap):
    """Seven frames sliding sideways over the plane, written to `folder`, frame 4 blank (nothing to track
    into), and COLMAP's model of the keyframes 0, 3 and 6 at their true poses, seeing 400 points of the
    plane: (model, names, true world -> camera poses)."""
    cv2 = import_cv2()
    plane = texture()
    truth = [camera_at(0.05 * i, 0.02 * i) for i in range(7)]
    names = [f"{i:06d}.png" for i in range(7)]
    for i, name in enumerate(names):
        frame = np.full((HEIGHT, WIDTH), 128, np.uint8) if i == 4 else render_plane(plane, truth[i])
        cv2.imwrite(str(folder / name), frame)
    model = pycolmap.Reconstruction()
    camera = pycolmap.Camera(model="SIMPLE_RADIAL", width=WIDTH, height=HEIGHT,
                             params=[FOCAL, WIDTH / 2, HEIGHT / 2, 0.0], camera_id=1)  # fmt: skip
    model.add_camera_with_trivial_rig(camera)
    xy = np.random.default_rng(1).uniform(-1.2, 1.2, (400, 2))
    world = np.concatenate([xy, np.zeros((400, 1))], axis=1)
    point_ids = [model.add_point3D(point, pycolmap.Track(), np.zeros(3, np.uint8)) for point in world]
    for image_id, index in enumerate((0, 3, 6), 1):
        pixels = camera.img_from_cam(world @ truth[index][:, :3].T + truth[index][:, 3])
        seen = np.flatnonzero((pixels[:, 0] > 8) & (pixels[:, 0] < WIDTH - 8) & (pixels[:, 1] > 8)
                              & (pixels[:, 1] < HEIGHT - 8))  # fmt: skip
        image = pycolmap.Image(name=names[index], keypoints=pixels[seen], camera_id=1, image_id=image_id)
        model.add_image_with_trivial_frame(image, pycolmap.Rigid3d(truth[index]))
        for point2d, point in enumerate(seen):
            model.add_observation(point_ids[point], pycolmap.TrackElement(image_id, point2d))
    return model, names, truth


def poses(model) -> dict[str, np.ndarray]:
    return {image.name: image.cam_from_world().matrix() for image in model.images.values()}


def test_the_frames_between_keyframes_are_placed_where_they_were_filmed(tmp_path):
    pycolmap = require_module("pycolmap")
    model, names, truth = plane_clip(tmp_path, pycolmap)
    keyframe_poses = poses(model)
    lines = []
    placed = place_between(pycolmap, model, tmp_path, names, lines.append)
    assert placed.placed == [names[i] for i in (1, 2, 5)] and placed.unplaced == [names[4]]
    assert placed.fewest_inliers >= 30 and "3 frames between keyframes placed" in lines[0] and names[4] in lines[0]
    by_name = {image.name: image for image in model.images.values()}
    assert sorted(by_name) == sorted(names[:4] + names[5:])
    for index in (1, 2, 5):
        image = by_name[names[index]]
        pose = image.cam_from_world().matrix()
        assert np.abs(pose[:, 3] - truth[index][:, 3]).max() < 2e-3, (index, pose)
        assert rotation_angle_deg(pose[:, :3] @ truth[index][:, :3].T) < 0.03
        # It joined the model: its inlier observations are points of the model's tracks.
        assert image.num_points3D >= 30 and image.num_points3D == image.num_points2D()
    assert model.compute_mean_reprojection_error() < 0.5
    for name, pose in keyframe_poses.items():  # COLMAP's keyframes are not moved
        np.testing.assert_array_equal(poses(model)[name], pose)
    # Seeded: placing again gives the same poses to the last digit.
    model_again, _, _ = plane_clip(tmp_path, pycolmap)
    place_between(pycolmap, model_again, tmp_path, names, lines.append)
    assert poses(model_again).keys() == poses(model).keys()
    for name, pose in poses(model).items():
        np.testing.assert_array_equal(poses(model_again)[name], pose)


def test_an_unreadable_frame_is_one_line_naming_it(tmp_path):
    pycolmap = require_module("pycolmap")
    model, names, _ = plane_clip(tmp_path, pycolmap)
    (tmp_path / names[2]).write_bytes(b"not a png")
    with pytest.raises(LiquidGSError, match=f"{names[2]}: not an image OpenCV can read"):
        place_between(pycolmap, model, tmp_path, names, lambda line: None)
