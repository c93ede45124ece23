"""Optical flow, motion masks and the scene folder's flow (data.optical_flow, data.motion_masks, data.flow)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from liquidgs.cameras import Camera
from liquidgs.data import flow, motion_masks, optical_flow
from liquidgs.errors import LiquidGSError
from shared_data import require_module

WIDTH, HEIGHT, FOCAL, DEPTH = 96, 64, 80.0, 4.0


@pytest.fixture(autouse=True, scope="module")
def _cv2():
    require_module("cv2")


def camera(rotation: np.ndarray, centre: np.ndarray) -> Camera:
    viewmat = np.eye(4)
    viewmat[:3, :3] = rotation
    viewmat[:3, 3] = -rotation @ centre
    K = np.array([[FOCAL, 0, WIDTH / 2], [0, FOCAL, HEIGHT / 2], [0, 0, 1]])
    return Camera(torch.from_numpy(viewmat).float(), torch.from_numpy(K).float(), WIDTH, HEIGHT)


def turn_y(degrees: float) -> np.ndarray:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def still_flow(a: Camera, b: Camera) -> np.ndarray:
    """The flow a still wall at depth DEPTH in front of camera a makes from a to b."""
    gx, gy = np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5)
    k = a.K.double().numpy()
    rays = np.stack([(gx - k[0, 2]) / k[0, 0], (gy - k[1, 2]) / k[1, 1], np.ones_like(gx)], axis=-1)
    view_a, view_b = a.viewmat.double().numpy(), b.viewmat.double().numpy()
    world = (rays * DEPTH - view_a[:3, 3]) @ view_a[:3, :3]  # camera a -> world
    in_b = world @ view_b[:3, :3].T + view_b[:3, 3]
    projected = in_b @ b.K.double().numpy().T
    return (projected[..., :2] / projected[..., 2:3] - np.stack([gx, gy], axis=-1)).astype(np.float32)


@pytest.mark.parametrize(
    ("move", "what"),
    [((np.eye(3), np.array([0.3, 0.05, 0.0])), "a step sideways: the epipolar (Sampson) distance"),
     ((turn_y(3.0), np.zeros(3)), "a turn in place: the rotation's homography")],
)  # fmt: skip
def test_a_still_pixel_is_explained_by_the_cameras_and_a_moving_one_is_not(move, what):
    a, b = camera(np.eye(3), np.zeros(3)), camera(*move)
    motion = still_flow(a, b)
    error = motion_masks.camera_motion_error(motion, a, b, DEPTH)
    assert error.max() < 0.01, what
    moved = motion.copy()
    moved[20:40, 30:60] += np.array([0.4, 2.0], np.float32)  # off the epipolar line (nearly vertical to it)
    error = motion_masks.camera_motion_error(moved, a, b, DEPTH)
    assert error[20:40, 30:60].min() > 1.0 and np.delete(error, np.s_[20:40], axis=0).max() < 0.01, what


def textured_image(shift: float = 0.0) -> np.ndarray:
    rng = np.random.default_rng(3)
    base = rng.random((HEIGHT // 4 + 2, WIDTH // 4 + 2, 3))
    import cv2

    big = cv2.resize(base, (WIDTH * 4 + 8 * 4, HEIGHT * 4 + 8 * 4), interpolation=cv2.INTER_CUBIC)
    matrix = np.float32([[1, 0, shift], [0, 1, 0]])  # content moves right
    moved = cv2.warpAffine(big, matrix, (big.shape[1], big.shape[0]), flags=cv2.INTER_CUBIC)
    return (np.clip(cv2.resize(moved, (WIDTH, HEIGHT), interpolation=cv2.INTER_AREA), 0, 1) * 255).astype(np.uint8)


def test_flow_of_a_shifted_image_is_the_shift_and_consistent_both_ways():
    a, b = textured_image(), textured_image(shift=8.0)  # 2 px at the image's size
    forward, backward = optical_flow.optical_flow(a, b), optical_flow.optical_flow(b, a)
    inner = np.s_[8:-8, 8:-8]
    assert np.median(forward[inner][..., 0]) == pytest.approx(2.0, abs=0.2)
    assert np.abs(np.median(forward[inner][..., 1])) < 0.1
    ok = optical_flow.consistent(forward, backward)
    assert ok[inner].mean() > 0.95
    assert not ok[:, -1].any()  # the last column lands outside the image
    broken = backward.copy()
    broken[10:30, 10:30] = np.array([3.0, -3.0], np.float32)  # the way back disagrees there
    assert optical_flow.consistent(forward, broken)[12:28, 12:26].mean() < 0.05


def test_chained_flow_follows_each_link_from_where_the_last_one_ended():
    """Three links: +2 px in y everywhere; then a shear, +y/8 px in x, read where the first link
    ended (y + 2, not the y the chain started at); then +1 px in x. A link that is invalid where the
    chain reaches it, or a chain that leaves the image, cuts the track."""
    gx, gy = np.meshgrid(np.arange(WIDTH, dtype=np.float32), np.arange(HEIGHT, dtype=np.float32))
    down = np.stack([np.zeros_like(gx), np.full_like(gx, 2.0)], axis=-1)
    shear = np.stack([gy / 8, np.zeros_like(gx)], axis=-1)
    right = np.stack([np.ones_like(gx), np.zeros_like(gx)], axis=-1)
    valid = [np.ones((HEIGHT, WIDTH), bool) for _ in range(3)]
    valid[1][20:30, 40:50] = False  # where the shear's flow cannot be trusted
    chained, kept = optical_flow.chain_flow([down, shear, right], valid)
    inside = np.s_[:-2]  # the rows whose chain stays in the image
    assert np.allclose(chained[inside][..., 0], (gy[inside] + 2) / 8 + 1) and np.allclose(chained[..., 1], 2.0)
    assert not kept[18:28, 40:50].any() and kept[28:30, 40:50].all()  # cut where the chain reached the hole
    assert not kept[-2:].any() and not kept[:, -2:].any()  # ends below or right of the image
    assert kept[:18, : WIDTH - 10].all() and kept[30:-2, : WIDTH - 10].all()  # elsewhere every link held


def test_a_mask_keeps_a_moving_region_and_drops_speckle_and_untextured_pixels():
    error = np.zeros((HEIGHT, WIDTH), np.float32)
    error[10:30, 10:30] = 5.0  # a moving subject
    error[50, 80] = error[5, 70] = 5.0  # speckle
    valid = np.ones_like(error, bool)
    textured = np.ones_like(valid)
    mask = motion_masks.motion_mask([(error, valid)], textured)
    assert mask[12:28, 12:28].all() and not mask[50, 80] and not mask[5, 70] and mask.sum() < 30 * 30
    assert not motion_masks.motion_mask([(error, valid)], np.zeros_like(valid)).any()  # a blank wall is no evidence
    assert not motion_masks.motion_mask([(error, np.zeros_like(valid))], textured).any()  # nor inconsistent flow


def test_a_broken_track_is_one_line_naming_its_file(flow_capture, tmp_path):
    scene = Path(shutil.copytree(flow_capture, tmp_path / "scene"))
    folder = scene / "flow" / "1x"
    record = json.loads((folder / "flow.json").read_text())
    first, last = record["tracks"][0]
    track = folder / "pairs" / f"{first}--{last}.npz"
    track.write_bytes(b"not a zip")
    problems = flow.check_flow(scene, 1)
    assert len(problems) == 1 and problems[0].startswith(f"{track}: unreadable flow")
    (folder / "flow.json").write_text(json.dumps({**record, "tracks": "all of them"}))
    assert flow.check_flow(scene, 1) == [f"{folder / 'flow.json'}: field 'tracks': not a list of pairs"]
    (folder / "flow.json").write_text(json.dumps({key: value for key, value in record.items() if key != "track_step"}))
    no_step = f"{folder / 'flow.json'}: field 'track_step': not the number of pairs each track chains"
    assert flow.check_flow(scene, 1) == [no_step]
    with pytest.raises(LiquidGSError, match="field 'track_step'"):  # data check: one line, not a KeyError
        flow.check_scene_flow(scene)
