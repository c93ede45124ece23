"""Matching along the optical flow (`--matcher flow`): COLMAP's SIFT features matched between the frame
pairs of its sequential pairing (each frame with the 1st, 2nd, 4th, ... frame after it), each feature
carried through the DIS flow between consecutive frames (data.optical_flow) and compared only with the
features within GUIDE_RADIUS of where it lands; a match is the best by descriptor both ways (mutual) and
clearly better than the second best (RATIO). COLMAP then verifies the pairs (VERIFY_MAX_ERROR) and maps.

Measured on New Tsukuba and the rendered test clip (docs/results/registration.md): what it gives against
COLMAP's own sequential matching is there; it is not the default.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from liquidgs.data.optical_flow import import_cv2, optical_flow

RATIO = 0.8
"""A match's descriptor distance is under this share of the second best's (Lowe's ratio test)."""
GUIDE_RADIUS = 16.0
"""Pixels around the flow's prediction within which a feature's match is looked for."""
GUIDE_CANDIDATES = 8
"""The features nearest the prediction compared by descriptor (within GUIDE_RADIUS). Comparing more for the
ratio test (32 within 48 px, or 400 within the frame; OpenCV's SIFT, 1.5 px in verification) did not bring
the poses nearer the truth on New Tsukuba."""
MIN_MATCHES = 15
"""A pair with fewer matches is not written (COLMAP's own minimum for verification)."""
VERIFY_MAX_ERROR = 1.0
"""Pixels: RANSAC's inlier threshold in COLMAP's geometric verification of these matches (its default 4).
Matches found near the flow's prediction include some that fit the pair's epipolar geometry to a pixel or
two and are wrong, which COLMAP's matcher, comparing each feature with the whole frame, does not find.
Measured with OpenCV's SIFT features on New Tsukuba (the relative rotation to the truth, mean degrees):
1.0 px 0.144 (three RANSAC seeds), 1.5 px 0.186 (three), 2 px 0.243, 4 px 0.253 (one each)."""

Log = Callable[[str], None]


@dataclass
class Features:
    """One frame's SIFT features: float32 [N, 2] pixel positions (the top-left pixel's centre at 0, 0) and
    float32 [N, 128] RootSIFT descriptors (unit length)."""

    positions: np.ndarray
    descriptors: np.ndarray


def colmap_features(keypoints: np.ndarray, descriptors: np.ndarray) -> Features:
    """Features from COLMAP's database: keypoints [N, >= 2] (the top-left pixel's centre at 0.5, 0.5) and
    its 8-bit SIFT descriptors [N, 128] (512 x the L1-root normalised values, capped at 255)."""
    unit = descriptors.astype(np.float32)
    unit /= np.maximum(np.linalg.norm(unit, axis=1, keepdims=True), 1e-12)
    return Features(np.ascontiguousarray(keypoints[:, :2], dtype=np.float32) - 0.5, unit.reshape(-1, 128))


def sequential_pairs(count: int, overlap: int) -> list[tuple[int, int]]:
    """COLMAP's quadratic sequential pairs: each frame with the 2^0 .. 2^(overlap - 1)-th frame after it."""
    return [(i, i + (1 << k)) for i in range(count) for k in range(overlap) if i + (1 << k) < count]


def _best(key: np.ndarray, other: np.ndarray, distance: np.ndarray, size: int) -> np.ndarray:
    """int [size]: for each key value, the `other` of its smallest distance where that is under RATIO x its
    second smallest (or it has one only); -1 elsewhere."""
    order = np.lexsort((distance, key))
    key, other, distance = key[order], other[order], distance[order]
    first = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    has_second = np.r_[first[1:], len(key)] - first > 1
    second = np.where(has_second, distance[np.minimum(first + 1, len(distance) - 1)], np.inf)
    clear = distance[first] < RATIO * second
    best = np.full(size, -1)
    best[key[first][clear]] = other[first][clear]
    return best


def mutual_matches(query: np.ndarray, candidate: np.ndarray, distance: np.ndarray,
                   sizes: tuple[int, int]) -> np.ndarray:  # fmt: skip
    """uint32 [M, 2] (query, candidate) pairs from candidate pairs (int arrays) and their descriptor distances:
    each the best of its query's candidates and of its candidate's queries, by RATIO over the second best of
    each. `sizes`: the feature counts of the two frames."""
    forward = _best(query, candidate, distance, sizes[0])
    backward = _best(candidate, query, distance, sizes[1])
    matched = np.flatnonzero(forward >= 0)
    matched = matched[backward[forward[matched]] == matched]
    return np.stack([matched, forward[matched]], axis=1).astype(np.uint32)


def guided_matches(a: Features, b: Features, predicted: np.ndarray, alive: np.ndarray, tree) -> np.ndarray:
    """Matches between a and b, each feature of a compared with b's features (`tree`: a KD-tree of their
    positions) nearest `predicted` (its position carried through the flow; where `alive`)."""
    index = np.flatnonzero(alive)
    if len(index) == 0 or len(b.positions) == 0:
        return np.zeros((0, 2), np.uint32)
    k = min(GUIDE_CANDIDATES, len(b.positions))
    distances, nearest = tree.query(predicted[index], k=k, distance_upper_bound=GUIDE_RADIUS)
    distances, nearest = distances.reshape(len(index), k), nearest.reshape(len(index), k)
    found = np.isfinite(distances)
    query = np.repeat(index, k).reshape(-1, k)[found]
    candidate = nearest[found]
    if len(query) == 0:
        return np.zeros((0, 2), np.uint32)
    distance = np.linalg.norm(a.descriptors[query] - b.descriptors[candidate], axis=1)
    return mutual_matches(query, candidate, distance, (len(a.positions), len(b.positions)))


def carry(positions: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Positions moved by the flow read at them (bilinear); NaN where they have left the image."""
    if len(positions) == 0:
        return positions
    cv2 = import_cv2()
    x, y = positions[:, :1].astype(np.float32), positions[:, 1:].astype(np.float32)
    step = cv2.remap(flow, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(np.nan, np.nan))
    return positions + step.reshape(-1, 2)


def flow_guided_matches(gray: Sequence[np.ndarray], features: Sequence[Features], overlap: int, threads: int,
                        log: Log) -> dict[tuple[int, int], np.ndarray]:  # fmt: skip
    """Matches of every pair sequential_pairs gives (frames in time order): {(i, j): uint32 [M, 2] feature
    indices}, pairs with fewer than MIN_MATCHES left out (as are pairs the flow carries fewer features to)."""
    from scipy.spatial import cKDTree

    count = len(gray)
    flows = []
    with opencv_threads(workers(threads)):
        for i in range(count - 1):
            flows.append(optical_flow(gray[i], gray[i + 1]))
            if (i + 1) % 50 == 0:
                log(f"matching: optical flow of {i + 1} of {count - 1} neighbouring frame pairs ...")
    trees = [cKDTree(frame.positions) if len(frame.positions) else None for frame in features]
    targets: dict[int, list[int]] = {}
    for i, j in sequential_pairs(count, overlap):
        targets.setdefault(i, []).append(j)

    def along_flow(i: int) -> dict[tuple[int, int], np.ndarray]:
        found = {}
        positions = features[i].positions.copy()
        for j in range(i + 1, max(targets[i]) + 1):
            positions = carry(positions, flows[j - 1])
            alive = np.isfinite(positions).all(1)
            if alive.sum() < MIN_MATCHES:
                break
            if j in targets[i] and trees[j] is not None:
                matches = guided_matches(features[i], features[j], positions, alive, trees[j])
                if len(matches) >= MIN_MATCHES:
                    found[(i, j)] = matches
        return found

    with opencv_threads(1), ThreadPoolExecutor(workers(threads)) as pool:
        return {pair: matches for found in pool.map(along_flow, targets) for pair, matches in found.items()}


def workers(threads: int) -> int:
    """The thread count `threads` asks for (-1: every core)."""
    return (os.cpu_count() or 1) if threads <= 0 else threads


@contextmanager
def opencv_threads(count: int) -> Iterator[None]:
    """OpenCV's own worker threads set to `count` for the block (DIS flow runs in parallel inside one call)."""
    cv2 = import_cv2()
    before = cv2.getNumThreads()
    cv2.setNumThreads(count)
    try:
        yield
    finally:
        cv2.setNumThreads(before)
