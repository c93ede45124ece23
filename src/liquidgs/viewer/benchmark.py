"""The viewer's frame rate without a browser: the render loop's work (render + JPEG) timed."""

from __future__ import annotations

import math
import time

import numpy as np
import torch

from liquidgs.viewer.server import JPEG_QUALITY, Viewer, fit_size

WARMUP_FRAMES = 3


def benchmark_viewer(viewer: Viewer, frames: int = 30) -> dict:
    """Frames per second of `Viewer.render_view` plus JPEG encoding over a time sweep 0 -> 1,
    from the first test camera, at the resting and the moving resolution of a square canvas
    (fps from the mean time per frame; the median is less sensitive to a busy shared CPU)."""
    frame = next(iter(viewer.cameras.values()), None)
    if frame is not None:
        c2w = frame.camera.camera_to_world()
        fov = frame.camera.vertical_fov
    else:
        c2w = np.eye(4)
        c2w[:3, 3] = viewer.centre - np.array([0.0, 0.0, 3.0 * viewer.radius])
        fov = math.radians(50.0)
    record = {
        "scene": viewer.scene_choice.value,
        "device": str(viewer.scenes[0].background.device),
        "torch_threads": torch.get_num_threads(),
        "frames": frames,
        "includes": "render (deformation field + rasterize) and JPEG encoding; no browser",
    }
    for name, side in (("rest", viewer.max_side), ("moving", max(32, viewer.max_side // 2))):
        width, height = fit_size(1.0, side)
        seconds = []
        for i in range(frames + WARMUP_FRAMES):
            viewer.time_slider.value = (i % frames) / max(frames - 1, 1)
            start = time.perf_counter()
            image, _ = viewer.render_view(None, c2w, fov, width, height)
            # What the render loop sends, encoded by viser and broadcast (to no browser here).
            viewer.server.scene.set_background_image(image, format="jpeg", jpeg_quality=JPEG_QUALITY)
            seconds.append(time.perf_counter() - start)
        timed = seconds[WARMUP_FRAMES:]
        mean = sum(timed) / frames
        record[name] = {
            "width": width,
            "height": height,
            "ms_per_frame": 1000 * mean,
            "ms_per_frame_median": 1000 * float(np.median(timed)),
            "fps": 1.0 / mean,
        }
    return record
