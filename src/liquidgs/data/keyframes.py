"""A video's cameras from its keyframes: COLMAP solves every KEYFRAME_EVERY-th frame, and every other
frame is placed from the keyframes on either side of it.

SIFT at COLMAP's doubled first octave, matching and mapping each cost time in proportion to the frames
(mapping more than that), while the frames between two keyframes a few frames apart add little geometry.
A frame between keyframes is placed by the points the keyframes see: each keyframe observation of a
triangulated point is tracked into the frame by Lucas-Kanade (data.optical_flow.track_points, checked
forwards and back), and the frame's pose is COLMAP's robust absolute pose (LO-RANSAC, then refined) from
those 2D-3D pairs, seeded. The placed frame joins the model with its inlier observations, so everything
after the solve (undistortion, the scene's files, the plausibility warnings, COLMAP's model on disk)
sees it as any other frame; the keyframes' poses and points are COLMAP's and are not moved.

Measured on New Tsukuba (150 frames, 640x480, known cameras; docs/results/registration.md): every 3rd
frame solved and 100 placed, the poses as near the truth as every frame solved.
"""

from __future__ import annotations

import bisect
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from liquidgs.data.optical_flow import read_gray, track_points
from liquidgs.data.plausibility import MIN_POINTS_PER_FRAME

KEYFRAME_EVERY = 3
"""COLMAP solves every this-th frame (and the last); 1 solves every frame with COLMAP."""
MIN_KEYFRAMES = 16
"""Fewer keyframes than this and the step is made smaller (clips under twice this are solved whole): on the
rendered test clip (32 frames, 200x152, known cameras) every 3rd frame (12 keyframes) left the poses twice as
far from the truth as every frame solved, every 2nd (16) as near (docs/results/registration.md)."""
PLACING_MAX_ERROR = 2.0
"""RANSAC's inlier threshold (pixels) for a placed frame's pose: tracked points land within a pixel."""
MIN_INLIERS = MIN_POINTS_PER_FRAME
"""A frame is placed only on at least this many inlier points (COLMAP's own bar for registering a frame)."""
MAX_UNPLACED_SHARE = 0.1
"""When more of the frames between keyframes than this cannot be placed, every frame is solved by COLMAP."""
SEED = 0

Log = Callable[[str], None]


def keyframe_step(count: int, every: int) -> int:
    """The step between keyframes for a clip of `count` frames: `every`, or less where that would leave fewer
    than MIN_KEYFRAMES keyframes; 1 (every frame solved by COLMAP) for clips under 2 x MIN_KEYFRAMES."""
    return max(1, min(every, count // MIN_KEYFRAMES))


def keyframe_names(names: list[str], step: int) -> list[str]:
    """Every `step`-th of `names` (in time order) from the first, and the last, so that every other frame
    lies between two keyframes."""
    keys = names[::step]
    return keys if keys[-1] == names[-1] else [*keys, names[-1]]


@dataclass(frozen=True)
class Placed:
    """What placing the frames between keyframes did."""

    placed: list[str]
    unplaced: list[str]
    """Frames with too few tracked points or no pose: left out of the model."""
    fewest_inliers: int
    """The fewest inlier points any placed frame rests on (0 when none was placed)."""
    seconds: float

    def record(self, every: int, keyframes: int) -> dict:
        """capture.json's record."""
        return {"every": every, "keyframes": keyframes, "placed": len(self.placed), "unplaced": self.unplaced,
                "fewest_inliers": self.fewest_inliers, "seconds": round(self.seconds, 2)}  # fmt: skip


def place_between(pycolmap, model, frames_dir: Path, names: list[str], log: Log) -> Placed:
    """Add to `model` (COLMAP's, one shared camera, frames named `names` in time order) every frame of `names`
    it does not hold, each placed from the nearest registered frames before and after it."""
    started = time.perf_counter()
    by_name = {image.name: image for image in model.images.values() if image.has_pose}
    anchors = [i for i, name in enumerate(names) if name in by_name]
    seen = {name: _observations(model, by_name[name]) for name in by_name}
    keyframes_read: dict[str, np.ndarray] = {}  # only those either side of the frame being placed

    camera = model.cameras[next(iter(by_name.values())).camera_id]
    estimation = pycolmap.AbsolutePoseEstimationOptions()
    estimation.ransac.max_error = PLACING_MAX_ERROR
    estimation.ransac.random_seed = SEED
    next_id = max([*model.images, *model.frames]) + 1
    placed, unplaced, fewest = [], [], None
    for index, name in enumerate(names):
        if name in by_name:
            continue
        at = bisect.bisect(anchors, index)
        # The nearer keyframe first: a point both see is taken from it.
        sources = sorted(anchors[max(at - 1, 0) : at + 1], key=lambda i: abs(i - index))
        keyframes_read = {names[i]: keyframes_read.get(names[i]) for i in sources}  # frames are visited in order
        points: dict[int, np.ndarray] = {}
        frame = read_gray(frames_dir / name)
        for source in sources:
            xy, ids = seen[names[source]]
            if keyframes_read[names[source]] is None:
                keyframes_read[names[source]] = read_gray(frames_dir / names[source])
            # COLMAP's pixel centres are at +0.5, OpenCV's at 0.
            there, kept = track_points(keyframes_read[names[source]], frame, xy - 0.5)
            for point_id, position in zip(ids[kept], there[kept] + 0.5):
                points.setdefault(int(point_id), position)
        pose = None
        if len(points) >= MIN_INLIERS:
            ids = np.fromiter(points, dtype=np.int64)
            xy = np.array([points[i] for i in ids])
            xyz = np.array([model.points3D[int(i)].xyz for i in ids])
            pose = pycolmap.estimate_and_refine_absolute_pose(xy, xyz, camera, estimation)
        if pose is None or int(pose["num_inliers"]) < MIN_INLIERS:
            unplaced.append(name)
            continue
        inliers = np.asarray(pose["inlier_mask"], dtype=bool)
        image = pycolmap.Image(name=name, keypoints=xy[inliers], camera_id=camera.camera_id, image_id=next_id)
        model.add_image_with_trivial_frame(image, pose["cam_from_world"])
        for point2d, point_id in enumerate(ids[inliers]):
            model.add_observation(int(point_id), pycolmap.TrackElement(next_id, point2d))
        next_id += 1
        placed.append(name)
        fewest = int(inliers.sum()) if fewest is None else min(fewest, int(inliers.sum()))
    result = Placed(placed, unplaced, fewest or 0, time.perf_counter() - started)
    missing = f"; {len(unplaced)} could not be: {', '.join(unplaced[:8])}" if unplaced else ""
    log(f"placing: {len(placed)} frames between keyframes placed from the points they see (each on at least "
        f"{result.fewest_inliers} points, {result.seconds:.1f} s){missing}")  # fmt: skip
    return result


def _observations(model, image) -> tuple[np.ndarray, np.ndarray]:
    """A registered frame's keypoints that see a triangulated point: xy [N, 2] (COLMAP's pixels) and the
    points' ids [N]."""
    points = [point for point in image.points2D if point.has_point3D()]
    xy = np.array([point.xy for point in points], dtype=np.float64).reshape(-1, 2)
    return xy, np.array([point.point3D_id for point in points], dtype=np.int64)
