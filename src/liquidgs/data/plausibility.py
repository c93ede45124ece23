"""Warnings about a camera solve that passed COLMAP's own checks but does not look like a phone's video.

- The lens: a phone's cameras have a focal length of FOCAL_SHARE_BOUNDS times the image's longer side
  (ultra-wide about 0.5, main 0.7-1.0, telephoto 2-3), and phone video reaches us already corrected
  for most of its distortion, so SIMPLE_RADIAL's k1 stays small (MAX_ABS_K1). A fit outside these
  is what COLMAP gives when focal length and distortion trade off on a clip with little parallax.
- The camera path: a step between neighbouring registered frames JUMP_FACTOR times the median step
  (a handheld camera moves smoothly; a jump is a frame placed on the wrong side of the scene).
- Frames that see fewer than MIN_POINTS_PER_FRAME triangulated points: their pose rests on little.
"""

from __future__ import annotations

import numpy as np

FOCAL_SHARE_BOUNDS = (0.5, 3.0)
MAX_ABS_K1 = 0.25
JUMP_FACTOR = 5.0
MIN_POINTS_PER_FRAME = 30
"""COLMAP's own default for registering a frame (abs_pose_min_num_inliers); colmap.check_model refuses a
model whose median frame sees fewer."""


def _frames(names: list[str], limit: int = 8) -> str:
    shown = ", ".join(names[:limit])
    return shown + (f" and {len(names) - limit} more" if len(names) > limit else "")


def lens_warnings(model_name: str, params: list[float], width: int, height: int) -> list[str]:
    """A SIMPLE_RADIAL (f, cx, cy, k) camera's focal length and distortion against a phone's."""
    warnings = []
    focal, k1 = float(params[0]), float(params[3]) if model_name == "SIMPLE_RADIAL" else 0.0
    share = focal / max(width, height)
    low, high = FOCAL_SHARE_BOUNDS
    if not low <= share <= high:
        warnings.append(
            f"focal length {focal:.0f} px is {share:.2f}x the longer side of {max(width, height)} px "
            f"(a phone's: {low}-{high}x); the clip may have too little parallax to fix the lens: "
            "move the camera sideways more, or film longer"
        )
    if abs(k1) > MAX_ABS_K1:
        warnings.append(
            f"radial distortion k1 {k1:+.3f} is beyond a phone's (|k1| at most {MAX_ABS_K1}); focal length and "
            "distortion trade off on this clip: move the camera sideways more, or film longer"
        )
    return warnings


def path_warnings(names: list[str], centres: np.ndarray) -> list[str]:
    """Jumps in the camera path of frames `names` (in time order) with centres [N, 3]."""
    if len(names) < 3:
        return []
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    typical = float(np.median(steps))
    if typical <= 0.0:
        return []
    jumps = [f"{names[n]}->{names[n + 1]}" for n in np.flatnonzero(steps > JUMP_FACTOR * typical)]
    if not jumps:
        return []
    return [
        f"the camera path jumps (a step over {JUMP_FACTOR:g}x the median) between frames {_frames(jumps)}: "
        "a frame placed wrongly, or a cut; check them, film without fast turns, or sample more frames (--frames)"
    ]


def points_warnings(names: list[str], points_seen: list[int]) -> list[str]:
    """Frames `names` that see too few triangulated points (points_seen, per frame)."""
    weak = [name for name, count in zip(names, points_seen) if count < MIN_POINTS_PER_FRAME]
    if not weak:
        return []
    return [
        f"{len(weak)} frame(s) see fewer than {MIN_POINTS_PER_FRAME} triangulated points, so their cameras "
        f"rest on little: {_frames(weak)}; film more textured static background there, or mask what moves"
    ]


def model_warnings(model) -> list[str]:
    """Every warning about a pycolmap Reconstruction whose frames are named in time order."""
    images = sorted((image for image in model.images.values() if image.has_pose), key=lambda image: image.name)
    warnings = []
    for camera in model.cameras.values():
        warnings += lens_warnings(camera.model_name, list(camera.params), camera.width, camera.height)
    names = [image.name.rsplit(".", 1)[0] for image in images]
    centres = np.array([image.projection_center() for image in images]).reshape(-1, 3)
    warnings += path_warnings(names, centres)
    warnings += points_warnings(names, [image.num_points3D for image in images])
    return warnings
