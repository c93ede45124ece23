"""The four shared D-NeRF scenes: split sizes, intrinsics, camera axes, downscaling, caching."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from liquidgs.data import DataConfig, load_dataset
from liquidgs.data.images import composite_and_downscale
from shared_data import DNERF_ROOT, require_shared

COUNTS = {
    "bouncingballs": (150, 20, 20),
    "hellwarrior": (100, 20, 20),
    "lego": (50, 11, 20),
    "standup": (150, 20, 20),
}


@pytest.fixture(autouse=True)
def shared_scenes():
    """Every test here reads the four D-NeRF scenes in ../shared/data/dnerf."""
    for scene in COUNTS:
        require_shared(DNERF_ROOT / scene / "transforms_train.json")


@pytest.mark.parametrize("scene", sorted(COUNTS))
def test_shared_scene_loads_with_counts_sizes_and_intrinsics(scene):
    ds = load_dataset(DataConfig(path=DNERF_ROOT / scene, downscale=8))
    assert (ds.format, ds.kind, ds.scene_name) == ("dnerf", "synthetic", scene)
    assert tuple(len(ds.splits[name]) for name in ("train", "val", "test")) == COUNTS[scene]
    angle_x = json.loads((DNERF_ROOT / scene / "transforms_train.json").read_text())["camera_angle_x"]
    focal = 0.5 * 100 / math.tan(0.5 * angle_x)
    expected_K = torch.tensor([[focal, 0, 50], [0, focal, 50], [0, 0, 1]], dtype=torch.float32)
    for frame in ds.train + ds.splits["val"] + ds.test:
        assert (frame.camera.width, frame.camera.height) == (100, 100)
        torch.testing.assert_close(frame.camera.K, expected_K)
        assert 0.0 <= frame.time <= 1.0
        # The D-NeRF cameras look at the origin: in OpenCV axes it is in front (z > 0), at the centre.
        point = frame.camera.viewmat @ torch.tensor([0.0, 0.0, 0.0, 1.0])
        assert point[2] > 0
        pixel = (frame.camera.K @ point[:3])[:2] / point[2]
        torch.testing.assert_close(pixel, torch.tensor([50.0, 50.0]), atol=1e-3, rtol=0)
    assert 4.0 < ds.camera_extent < 6.0  # cameras on a sphere of radius ~4
    assert ds.points is None and ds.point_colors is None


def test_lego_val_as_test_uses_the_val_frames():
    ds = load_dataset(DataConfig(path=DNERF_ROOT / "lego", downscale=8, val_as_test=True))
    assert len(ds.test) == 11
    assert [f.image_path for f in ds.test] == [f.image_path for f in ds.splits["val"]]


@pytest.mark.parametrize("background", ["black", "white"])
def test_downscaled_image_is_area_average_of_the_composited_image(background):
    ds = load_dataset(DataConfig(path=DNERF_ROOT / "hellwarrior", downscale=4, background=background))
    frame = ds.train[7]
    rgba = np.asarray(Image.open(frame.image_path), dtype=np.float64) / 255.0
    bg = 1.0 if background == "white" else 0.0
    full = rgba[..., :3] * rgba[..., 3:] + bg * (1.0 - rgba[..., 3:])
    expected = full.reshape(200, 4, 200, 4, 3).mean(axis=(1, 3))
    image = frame.image()
    assert image.dtype == torch.float32 and image.shape == (200, 200, 3)
    np.testing.assert_allclose(image.numpy(), expected, atol=0.51 / 255)
    assert ds.background == (bg, bg, bg)


@pytest.mark.parametrize("factor", [1, 2, 3, 8])
def test_composite_and_downscale_rounds_the_exact_block_mean(factor):
    """The fast integer path against int64 arithmetic on random pixels, odd sizes and a grey
    background: the nearest 8-bit value to the block mean of the composite, exactly."""
    rng = np.random.default_rng(factor)
    rgba = rng.integers(0, 256, size=(8 * factor + factor - 1, 5 * factor + 1, 4), dtype=np.uint8)
    rgba[0, 0, 3], rgba[0, 1, 3] = 0, 255  # the extremes of coverage
    background = (0.5, 1.0, 0.0)
    wide = rgba.astype(np.int64)
    background_8bit = np.rint(np.asarray(background) * 255).astype(np.int64)
    composite = wide[..., :3] * wide[..., 3:] + background_8bit * (255 - wide[..., 3:])
    height, width = rgba.shape[0] // factor, rgba.shape[1] // factor
    blocks = composite[: height * factor, : width * factor].reshape(height, factor, width, factor, 3).sum(axis=(1, 3))
    divisor = 255 * factor * factor
    expected = (blocks + divisor // 2) // divisor
    np.testing.assert_array_equal(composite_and_downscale(rgba, background, factor), expected.astype(np.uint8))


def test_image_cache_is_bounded_lru():
    ds = load_dataset(DataConfig(path=DNERF_ROOT / "lego", downscale=8, cache_images=2))
    first, second, third = ds.train[:3]
    image = first.image_uint8()
    assert image.dtype == np.uint8 and not image.flags.writeable
    assert first.image_uint8() is image  # served from the cache
    second.image_uint8()
    third.image_uint8()  # evicts `first`, the least recently used
    assert first.image_uint8() is not image
    np.testing.assert_array_equal(first.image_uint8(), image)
