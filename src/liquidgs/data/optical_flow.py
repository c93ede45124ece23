"""Optical flow between two frames and what is built from it alone: OpenCV's DIS flow, each
direction's forward-backward consistency, flow chained over several frames, and points tracked from
one frame into another (Lucas-Kanade). liquidgs' one owner of optical flow: the scene folder's flow
(data.flow), the motion masks (data.motion_masks), the features COLMAP is kept from (data.capture), the
matches it is given (data.flow_matches) and the frames placed between keyframes (data.keyframes) all
come from here.
"""

from __future__ import annotations

import numpy as np

from liquidgs.errors import LiquidGSError

DIS_PRESET = "medium"
"""DIS's presets: ultrafast, fast, medium. Medium: a few milliseconds a pair at training sizes
(about 200 x 110 for the quick look), and its error on a still background is the lowest."""


def import_cv2():
    """OpenCV, or one line saying how to install it."""
    try:
        import cv2
    except ImportError:
        raise LiquidGSError(
            "optical flow needs OpenCV: pip install opencv-python-headless (part of the colmap extra)"
        ) from None
    return cv2


def read_gray(path) -> np.ndarray:
    """A frame as grey uint8 [H, W], decoded by OpenCV (its grey rounds differently from PIL's "L"), or one
    error naming the file."""
    cv2 = import_cv2()
    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if gray is None:
        raise LiquidGSError(f"{path}: not an image OpenCV can read")
    return gray


def optical_flow(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """DIS flow from image a to image b (uint8 RGB [H, W, 3] or grey [H, W]): float32 [H, W, 2], (dx, dy)
    in pixels."""
    cv2 = import_cv2()
    preset = {"ultrafast": 0, "fast": 1, "medium": 2}[DIS_PRESET]
    dis = cv2.DISOpticalFlow_create(preset)
    gray = [np.ascontiguousarray(image) if image.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(image),
            cv2.COLOR_RGB2GRAY) for image in (a, b)]  # fmt: skip
    return dis.calc(gray[0], gray[1], None).astype(np.float32)


def pixel_grid(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    return np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))


def inside(x: np.ndarray, y: np.ndarray, width: int, height: int) -> np.ndarray:
    """Where pixel positions (x, y) lie inside a width x height image (pixel centres 0 .. size - 1)."""
    return (x >= 0) & (x <= width - 1) & (y >= 0) & (y <= height - 1)


def consistent(forward: np.ndarray, backward: np.ndarray) -> np.ndarray:
    """Where forward flow and the backward flow at its end cancel (Sundaram et al.'s test:
    |f + b|^2 < 0.01 (|f|^2 + |b|^2) + 0.5) and the end lies inside the image: bool [H, W]."""
    cv2 = import_cv2()
    height, width = forward.shape[:2]
    gx, gy = pixel_grid(height, width)
    x, y = gx + forward[..., 0], gy + forward[..., 1]
    back = cv2.remap(backward, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    total = forward + back
    bound = 0.01 * ((forward**2).sum(-1) + (back**2).sum(-1)) + 0.5
    return ((total**2).sum(-1) < bound) & inside(x, y, width, height) & np.isfinite(total).all(-1)


def chain_flow(flows: list[np.ndarray], valid: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The flow of consecutive links (frame 0 -> 1, 1 -> 2, ...: float32 [H, W, 2] each) chained into
    the flow from the first frame to the last, each link read where the chain has reached (bilinear),
    and bool [H, W]: where every link was valid (nearest) at a point inside the image and the end is
    inside it too."""
    cv2 = import_cv2()
    height, width = flows[0].shape[:2]
    gx, gy = pixel_grid(height, width)
    x, y = gx.copy(), gy.copy()
    kept = np.ones((height, width), dtype=bool)
    for flow, link_valid in zip(flows, valid, strict=True):
        reached = cv2.remap(link_valid.astype(np.uint8), x, y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
        kept &= inside(x, y, width, height) & (reached > 0)
        step = cv2.remap(np.ascontiguousarray(flow, dtype=np.float32), x, y, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)  # fmt: skip
        x, y = x + step[..., 0], y + step[..., 1]
    kept &= inside(x, y, width, height)
    return np.stack([x - gx, y - gy], axis=-1), kept


TRACK_WINDOW = 21
"""Pyramidal Lucas-Kanade's window (pixels) and pyramid levels below the image: OpenCV's defaults but
one more level, for the few-frame gaps tracked between keyframes (data.keyframes)."""
TRACK_LEVELS = 3
TRACK_BACK_ERROR = 0.5
"""A point tracked into the other image and back must land within this many pixels of where it started."""


def track_points(a: np.ndarray, b: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points xy [N, 2] of grey image a (uint8 [H, W], pixel centres at integers) tracked into grey image b
    by pyramidal Lucas-Kanade: their positions in b, float64 [N, 2], and bool [N]: tracked both ways, back
    within TRACK_BACK_ERROR pixels of the start, and inside b."""
    cv2 = import_cv2()
    start = np.ascontiguousarray(xy, dtype=np.float32).reshape(-1, 1, 2)
    if not len(start):
        return np.zeros((0, 2)), np.zeros(0, dtype=bool)
    window = dict(winSize=(TRACK_WINDOW, TRACK_WINDOW), maxLevel=TRACK_LEVELS,
                  criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01))  # fmt: skip
    there, found, _ = cv2.calcOpticalFlowPyrLK(a, b, start, None, **window)
    back, found_back, _ = cv2.calcOpticalFlowPyrLK(b, a, there, None, **window)
    there, back = there.reshape(-1, 2).astype(np.float64), back.reshape(-1, 2)
    height, width = b.shape[:2]
    kept = (found[:, 0] == 1) & (found_back[:, 0] == 1) & np.isfinite(there).all(1)
    kept &= np.linalg.norm(back - start.reshape(-1, 2), axis=1) < TRACK_BACK_ERROR
    kept &= inside(there[:, 0], there[:, 1], width, height)
    return there, kept
