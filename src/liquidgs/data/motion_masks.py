"""Motion masks from optical flow: the pixels whose flow the cameras' motion cannot explain.

A frame's mask is made of the textured pixels (MIN_TEXTURE) whose flow to the train frames
FRAME_STEP train frames before and after it misses the cameras' motion by more than
MOTION_THRESHOLD_PX, consistent in either direction, then cleaned (clean_mask). Where the camera
moved enough for parallax to show (more than PARALLAX_PX at the scene's median depth) the miss is the
Sampson distance of the flow's end from its epipolar line; where it only turned (or stood still), the
distance from where the rotation's homography puts the pixel. MoSca's weight-free motion mask, with
no network. What it cannot see: motion along the epipolar line (a subject moving the way the camera
slides), and motion on textureless surfaces.

Before any cameras exist (two_view_motion_masks, for keeping COLMAP's features off moving things),
the same masks are made from frames alone: the cameras' motion is replaced by the dominant two-view
geometry of each pair, fitted to the flow by RANSAC (a fundamental matrix, or a homography where one
explains the flow), so what moves is what the pair's dominant motion does not explain.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from liquidgs.cameras import Camera
from liquidgs.data.optical_flow import consistent, import_cv2, optical_flow, pixel_grid

MOTION_THRESHOLD_PX = 1.0
"""A pixel moves where the cameras' motion misses its flow by more than this (training pixels)."""
PARALLAX_PX = 0.5
"""Below this parallax (focal x baseline / median depth, pixels) a pair is treated as a turn."""
MIN_REGION_SHARE = 0.001
"""A motion region smaller than this share of the image is speckle, not a moving subject."""
MIN_TEXTURE = 2e-4
"""Flow is only evidence where the image has texture: the smaller eigenvalue of the structure tensor
(5 x 5 window, grey levels in [0, 1]) at least this. On a blank wall DIS returns a smooth guess that
is consistent both ways and still wrong (measured on the cat clip: whole patches of its wall)."""
FRAME_STEP = 3
"""A frame's mask compares it with the train frames this many train frames before and after it:
between neighbouring frames a slow subject (the cat's head) moves less than the cameras' error."""
GEOMETRY_SAMPLE_STEP = 4
"""Before cameras exist, the two-view geometry is fitted to the flow at every 4th pixel both ways."""
MIN_GEOMETRY_SAMPLES = 16
HOMOGRAPHY_SHARE = 0.9
"""A homography that explains this share of a pair's flow is its geometry (a fundamental matrix is
then ill-posed: a turn, a still camera, a flat scene)."""


Log = Callable[[str], None]


def _rotation_translation(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    viewmat = camera.viewmat.double().numpy()
    return viewmat[:3, :3], viewmat[:3, 3]


def median_depth(camera: Camera, points: np.ndarray | None) -> float | None:
    """The median depth of the scene's points in front of `camera`; None without points."""
    if points is None or len(points) == 0:
        return None
    rotation, translation = _rotation_translation(camera)
    depth = points @ rotation[2] + translation[2]
    depth = depth[depth > 0]
    return float(np.median(depth)) if len(depth) else None


def camera_motion_error(flow: np.ndarray, cam_a: Camera, cam_b: Camera, depth: float | None) -> np.ndarray:
    """How far, in pixels of b, each pixel's flow from a to b lands from where the cameras' motion
    allows a still point to land: float32 [H, W] (see the module's docstring)."""
    rot_a, t_a = _rotation_translation(cam_a)
    rot_b, t_b = _rotation_translation(cam_b)
    rotation = rot_b @ rot_a.T  # a's camera frame -> b's
    translation = t_b - rotation @ t_a
    k_a, k_b = cam_a.K.double().numpy(), cam_b.K.double().numpy()
    x_a, x_b = flow_ends(flow)
    baseline = float(np.linalg.norm(translation))
    parallax = np.inf if depth is None else float(k_b[0, 0]) * baseline / depth
    if baseline == 0.0 or parallax < PARALLAX_PX:  # a turn: the infinite homography moves still points
        return homography_distance(x_a, x_b, k_b @ rotation @ np.linalg.inv(k_a))
    skew = np.array([[0.0, -translation[2], translation[1]], [translation[2], 0.0, -translation[0]],
                     [-translation[1], translation[0], 0.0]])  # fmt: skip
    fundamental = np.linalg.inv(k_b).T @ skew @ rotation @ np.linalg.inv(k_a)
    return sampson_distance(x_a, x_b, fundamental)


def flow_ends(flow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Homogeneous pixel centres x_a [H, W, 3] (float64) and where the flow from a takes them, x_b."""
    gx, gy = pixel_grid(*flow.shape[:2])
    x_a = np.stack([gx + 0.5, gy + 0.5, np.ones_like(gx)], axis=-1).astype(np.float64)
    x_b = x_a.copy()
    x_b[..., :2] += flow
    return x_a, x_b


def homography_distance(x_a: np.ndarray, x_b: np.ndarray, homography: np.ndarray) -> np.ndarray:
    """How far (pixels) each x_b lands from where `homography` puts its x_a: float32 [...]."""
    predicted = x_a @ homography.T
    predicted = predicted[..., :2] / predicted[..., 2:3]
    return np.linalg.norm(x_b[..., :2] - predicted, axis=-1).astype(np.float32)


def sampson_distance(x_a: np.ndarray, x_b: np.ndarray, fundamental: np.ndarray) -> np.ndarray:
    """The Sampson distance (pixels) of homogeneous pixel pairs x_a -> x_b [..., 3] from the epipolar
    geometry `fundamental` (x_b^T F x_a = 0): float32 [...]."""
    line_b = x_a @ fundamental.T  # F x_a: the epipolar line in b
    line_a = x_b @ fundamental  # F^T x_b
    residual = (x_b * line_b).sum(-1)
    norm = line_b[..., 0] ** 2 + line_b[..., 1] ** 2 + line_a[..., 0] ** 2 + line_a[..., 1] ** 2
    return np.sqrt(residual**2 / np.maximum(norm, 1e-12)).astype(np.float32)


def two_view_error(flow: np.ndarray, valid: np.ndarray) -> np.ndarray | None:
    """How far, in pixels of b, each pixel's flow from a to b lands from the dominant two-view geometry
    of the pair, with no cameras: a homography where one explains HOMOGRAPHY_SHARE of the flow (a turn,
    a still camera, a flat scene), else a fundamental matrix; each fitted by RANSAC (at
    MOTION_THRESHOLD_PX) to the `valid` flow every GEOMETRY_SAMPLE_STEP pixels. float32 [H, W], or
    None when too few valid flow vectors are left to fit either."""
    cv2 = import_cv2()
    x_a, x_b = flow_ends(flow)
    sample = np.zeros_like(valid)
    sample[::GEOMETRY_SAMPLE_STEP, ::GEOMETRY_SAMPLE_STEP] = True
    sample &= valid
    if sample.sum() < MIN_GEOMETRY_SAMPLES:
        return None
    from_a, to_b = x_a[sample][:, :2], x_b[sample][:, :2]
    homography, inliers = cv2.findHomography(from_a, to_b, cv2.RANSAC, MOTION_THRESHOLD_PX)
    if homography is not None and inliers.mean() >= HOMOGRAPHY_SHARE:
        return homography_distance(x_a, x_b, homography)
    fundamental, _ = cv2.findFundamentalMat(from_a, to_b, cv2.FM_RANSAC, MOTION_THRESHOLD_PX, 0.999)
    if fundamental is None or fundamental.shape != (3, 3):
        return None
    return sampson_distance(x_a, x_b, fundamental)


def two_view_motion_masks(images: list[np.ndarray], log: Log | None = None) -> list[np.ndarray]:
    """Motion masks of frames in time order (uint8 RGB [H, W, 3], one size) before any cameras exist,
    for keeping features off moving things: as the scene's masks (motion_mask over the textured
    pixels, the frames FRAME_STEP before and after), with two_view_error in place of the cameras'
    motion. bool [H, W] per frame, True where moving."""
    flows: dict[tuple[int, int], np.ndarray] = {}

    def flow_of(a: int, b: int) -> np.ndarray:
        if (a, b) not in flows:
            flows[(a, b)] = optical_flow(images[a], images[b])
        return flows[(a, b)]

    last = len(images) - 1
    masks = []
    for index, image in enumerate(images):
        neighbours = sorted({max(0, index - FRAME_STEP), min(last, index + FRAME_STEP)} - {index})
        errors = []
        for other in neighbours:
            forward, backward = flow_of(index, other), flow_of(other, index)
            valid = consistent(forward, backward)
            error = two_view_error(forward, valid & textured(image))
            if error is not None:
                errors.append((error, valid))
        masks.append(motion_mask(errors, textured(image)))
        for other in neighbours:
            if other < index:  # no later frame needs this pair again
                flows.pop((index, other), None)
                flows.pop((other, index), None)
        if log is not None and ((index + 1) % 25 == 0 or index == last):
            log(f"feature masks: {index + 1}/{len(images)} frames")
    return masks


def textured(image: np.ndarray) -> np.ndarray:
    """Where `image` (uint8 RGB) has the texture flow needs (MIN_TEXTURE): bool [H, W]."""
    cv2 = import_cv2()
    gray = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
    return cv2.cornerMinEigenVal(gray, 5) >= MIN_TEXTURE


def clean_mask(mask: np.ndarray) -> np.ndarray:
    """`mask` without speckle and with its gaps filled: a 3x3 opening, a 7x7 closing (textureless
    pixels between moving ones), then regions under MIN_REGION_SHARE of the image removed."""
    cv2 = import_cv2()
    opened = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    closed = cv2.morphologyEx(opened, cv2.MORPH_CLOSE, np.ones((7, 7), np.uint8))
    count, labels, stats, _ = cv2.connectedComponentsWithStats(closed, connectivity=8)
    keep = np.zeros(count, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= MIN_REGION_SHARE * mask.size
    return keep[labels]


def motion_mask(errors: list[tuple[np.ndarray, np.ndarray]], evidence: np.ndarray) -> np.ndarray:
    """Moving where any neighbour's consistent flow misses the cameras' motion by more than the
    threshold, among the pixels where flow is `evidence` (textured): `errors` is [(error [H, W],
    consistent [H, W])] per neighbour."""
    moving = np.zeros(evidence.shape, bool)
    for error, valid in errors:
        moving |= valid & evidence & (error > MOTION_THRESHOLD_PX)
    return clean_mask(moving)
