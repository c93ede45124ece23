"""Synthetic scenes: both layouts agree, projections land where the renderer drew, presets."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from liquidgs.data import (
    DEFAULT_SYNTHETIC_SCENE,
    SYNTHETIC_SCENES,
    DataConfig,
    generate_synthetic,
    load_dataset,
)
from liquidgs.data.dnerf import SCENE_BOUND
from liquidgs.data.synthetic import scene_primitives, surface_points
from liquidgs.errors import ConfigError

SIZE, FRAMES = 64, 24


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    return generate_synthetic(DEFAULT_SYNTHETIC_SCENE, tmp_path_factory.mktemp("synth"), size=SIZE, frames=FRAMES)


def test_default_scene_is_listed():
    assert DEFAULT_SYNTHETIC_SCENE in SYNTHETIC_SCENES and len(SYNTHETIC_SCENES) >= 2


def test_both_layouts_give_the_same_cameras_times_and_images(scene_dir):
    dnerf = load_dataset(DataConfig(path=scene_dir / "dnerf"))
    nerfies = load_dataset(DataConfig(path=scene_dir / "nerfies"))
    assert (dnerf.format, nerfies.format) == ("dnerf", "nerfies")
    assert len(dnerf.train) + len(dnerf.test) + len(dnerf.splits["val"]) == FRAMES
    for split in ("train", "test"):
        assert len(dnerf.splits[split]) == len(nerfies.splits[split]) > 0
        for a, b in zip(dnerf.splits[split], nerfies.splits[split]):
            assert a.time == b.time
            assert (a.camera.width, a.camera.height) == (b.camera.width, b.camera.height) == (SIZE, SIZE)
            torch.testing.assert_close(a.camera.K, b.camera.K)
            torch.testing.assert_close(a.camera.viewmat, b.camera.viewmat, atol=1e-5, rtol=0)
            torch.testing.assert_close(a.image(), b.image(), atol=0, rtol=0)
    assert dnerf.camera_extent == pytest.approx(nerfies.camera_extent, rel=1e-5)
    # Test frames are interleaved in time between training frames.
    assert min(f.time for f in dnerf.train) == 0.0 and max(f.time for f in dnerf.train) == 1.0
    assert 0.0 < min(f.time for f in dnerf.test) < max(f.time for f in dnerf.test) < 1.0


@pytest.mark.parametrize("layout", ["dnerf", "nerfies"])
def test_head_centre_projects_onto_the_rendered_head(scene_dir, layout):
    ds = load_dataset(DataConfig(path=scene_dir / layout))
    # At times 0 and 1 the arms hang down, so nothing hides the head from any camera.
    for frame in (ds.train[0], ds.train[-1]):
        head = next(p for p in scene_primitives(DEFAULT_SYNTHETIC_SCENE, frame.time) if p.name == "head")
        point = frame.camera.viewmat @ torch.tensor([*head.translation, 1.0], dtype=torch.float32)
        u, v = ((frame.camera.K @ point[:3]) / point[2])[:2].tolist()
        # Pixel (i, j) covers [i, i+1) x [j, j+1): its centre is at (i + 0.5, j + 0.5).
        pixel = frame.image()[int(v), int(u)].numpy()
        # Shading scales the colour; its chromaticity is the head's magenta.
        expected = np.asarray(head.colors[0]) / sum(head.colors[0])
        np.testing.assert_allclose(pixel / pixel.sum(), expected, atol=0.04)
        # Its projected radius is ~r*f/z pixels: a step of twice that lands on the background.
        radius = head.size[0] * float(frame.camera.K[0, 0]) / float(point[2])
        outside = frame.image()[int(v), min(int(u + 2.2 * radius), SIZE - 1)]
        assert not torch.allclose(outside, frame.image()[int(v), int(u)], atol=0.05)


@pytest.mark.parametrize("name", SYNTHETIC_SCENES)
def test_scene_stays_inside_the_initialisation_box(name):
    rng = np.random.default_rng(0)
    for time in np.linspace(0.0, 1.0, 41):
        points = surface_points(scene_primitives(name, float(time)), 2000, rng)
        assert np.abs(points).max() <= SCENE_BOUND


def test_generation_is_deterministic_by_seed(tmp_path):
    paths = [
        generate_synthetic("spinner", tmp_path / str(i), size=16, frames=8, seed=s) for i, s in enumerate((3, 3, 4))
    ]
    frames = [json.loads((p / "dnerf" / "transforms_train.json").read_text())["frames"] for p in paths]
    assert frames[0] == frames[1] != frames[2]
    png = "dnerf/train/r_001.png"
    assert (paths[0] / png).read_bytes() == (paths[1] / png).read_bytes()
    np.testing.assert_array_equal(np.load(paths[0] / "nerfies/points.npy"), np.load(paths[1] / "nerfies/points.npy"))


def test_unknown_scene_and_bad_sizes_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="unknown synthetic scene 'nope'"):
        generate_synthetic("nope", tmp_path)
    with pytest.raises(ConfigError, match="frames >= 8"):
        generate_synthetic(DEFAULT_SYNTHETIC_SCENE, tmp_path, frames=3)


def test_nerfies_points_and_cameras_move_into_the_scene_frame(scene_dir, tmp_path):
    root = tmp_path / "scene"
    shutil.copytree(scene_dir / "nerfies", root)
    center, scale = np.array([0.1, -0.2, 0.3]), 2.0
    (root / "scene.json").write_text(json.dumps({"scale": scale, "center": center.tolist()}))
    ds = load_dataset(DataConfig(path=root))
    raw = np.load(root / "points.npy")
    assert ds.points.dtype == torch.float32 and ds.points.shape == (len(raw), 3)
    np.testing.assert_allclose(ds.points.numpy(), (raw - center) * scale, rtol=1e-6, atol=1e-6)
    assert ds.point_colors is None
    position = json.loads((root / "camera" / f"{ds.train[0].name}.json").read_text())["position"]
    np.testing.assert_allclose(ds.train[0].camera.centre.numpy(), (np.array(position) - center) * scale, atol=1e-5)


def test_interp_preset_takes_every_fourth_id_at_half_resolution(scene_dir):
    ds = load_dataset(DataConfig(path=scene_dir / "nerfies", split="interp"))
    ids = json.loads((scene_dir / "nerfies" / "dataset.json").read_text())["ids"]
    assert [f.name for f in ds.train] == ids[::4] and [f.name for f in ds.test] == ids[2::4]
    # Only rgb/1x exists: the 1/2 images are area-averaged from it, intrinsics halved.
    full = load_dataset(DataConfig(path=scene_dir / "nerfies", split="interp", downscale=1))
    half, one = ds.train[1], full.train[1]
    assert (half.camera.width, half.camera.height) == (SIZE // 2, SIZE // 2)
    torch.testing.assert_close(half.camera.K[:2], one.camera.K[:2] / 2)
    expected = one.image().reshape(SIZE // 2, 2, SIZE // 2, 2, 3).mean(dim=(1, 3))
    # `expected` was rounded to 8 bits before averaging, `half` only after: 1 level apart at most.
    torch.testing.assert_close(half.image(), expected, atol=1.01 / 255, rtol=0)


def test_vrig_preset_reads_quarter_resolution(scene_dir):
    ds = load_dataset(DataConfig(path=scene_dir / "nerfies", split="vrig"))
    assert (ds.train[0].camera.width, ds.train[0].camera.height) == (SIZE // 4, SIZE // 4)
    assert ds.kind == "real"


def test_split_presets_are_rejected_for_dnerf(scene_dir):
    with pytest.raises(ConfigError, match="Nerfies preset"):
        load_dataset(DataConfig(path=scene_dir / "dnerf", split="vrig"))


def test_moving_mask_marks_where_the_ground_truth_moves():
    from liquidgs.cameras import DNERF_CAMERA_ANGLE_X as CAMERA_ANGLE_X
    from liquidgs.data.synthetic import moving_mask, orbit_camera

    size = 48
    focal = 0.5 * size / np.tan(0.5 * CAMERA_ANGLE_X)
    K = np.array([[focal, 0.0, size / 2], [0.0, focal, size / 2], [0.0, 0.0, 1.0]])
    cam_to_world = orbit_camera(np.random.default_rng(3))
    moving = moving_mask("puppet", K, cam_to_world, size, size, 0.35, 1 / 79)
    assert moving.shape == (size, size) and 0 < moving.mean() < 0.2  # the limbs, not the frame
    assert not moving_mask("puppet", K, cam_to_world, size, size, 0.35, 0.0).any()  # no time step, no motion
    # Slow rigid motion moves fewer pixels per frame than the puppet's swinging limbs.
    assert moving_mask("spinner", K, cam_to_world, size, size, 0.35, 1 / 79).mean() < moving.mean()
    # The still scene is the control: nothing in it moves at any time.
    assert not any(moving_mask("still", K, cam_to_world, size, size, t, 1 / 79).any() for t in (0.0, 0.35, 0.9))
