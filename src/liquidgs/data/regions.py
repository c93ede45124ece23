"""Regions of a test view the evaluation can score separately: the moving pixels and the foreground.

- moving (built-in synthetic scenes only, exact): the pixels whose ground truth changes between
  the neighbouring frame times, the scene rendered again from the same camera
  (synthetic.moving_mask). Real captures have no such mask: each test view of a D-NeRF scene is
  one camera at one time.
- foreground (any RGBA image, model-independent): the pixels the object covers at all (alpha > 0
  anywhere in the block a downscaled pixel averages). It includes the parts that do not move.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from liquidgs.data.scene import Frame
from liquidgs.data.synthetic import moving_mask
from liquidgs.data.validate import decode_image
from liquidgs.errors import DataError


def moving_region(scene: str, frame: Frame, step: float) -> np.ndarray:
    """bool [H,W]: the pixels of `frame` (a view of built-in scene `scene`) whose ground truth
    changes between frame.time -+ step, seen from the same camera."""
    camera = frame.camera
    K = camera.K.double().numpy()
    return moving_mask(scene, K, camera.camera_to_world(), camera.width, camera.height, frame.time, step)


def frame_step(frames: Iterable[Frame]) -> float:
    """The time between neighbouring frames of a scene (the smallest gap between distinct times)."""
    frames = list(frames)
    times = np.unique(np.round([frame.time for frame in frames], 9))
    if len(times) < 2:
        where = frames[0].image_path.parent if frames else "."
        raise DataError(where, "fewer than two distinct frame times, so no time step between frames")
    return float(np.diff(times).min())


def foreground_region(frame: Frame) -> np.ndarray:
    """bool [H,W]: the pixels of `frame` whose stored image has alpha > 0 anywhere in the block
    the (area-averaging) downscale merges into them; an image without alpha is all foreground."""
    rgba = decode_image(frame.image_path)
    width, height = frame.camera.width, frame.camera.height
    factor = rgba.shape[1] // width
    if factor < 1 or (rgba.shape[0] // factor, rgba.shape[1] // factor) != (height, width):
        raise DataError(frame.image_path, f"{rgba.shape[1]}x{rgba.shape[0]} is not a whole multiple of the "
                        f"view's {width}x{height}")  # fmt: skip
    alpha = rgba[: height * factor, : width * factor, 3]
    return alpha.reshape(height, factor, width, factor).max(axis=(1, 3)) > 0
