"""data.flow_matches: SIFT features matched along the optical flow, on frames whose motion is known."""

from __future__ import annotations

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2", reason="needs opencv-python-headless (the colmap extra)")

from liquidgs.data.flow_matches import (  # noqa: E402
    GUIDE_RADIUS,
    Features,
    colmap_features,
    flow_guided_matches,
    guided_matches,
    mutual_matches,
    sequential_pairs,
)


def sift_features(gray: np.ndarray) -> Features:
    """OpenCV's SIFT of a grey frame, stored and read back as COLMAP's database holds SIFT (keypoints with
    the top-left pixel's centre at 0.5, 0.5; 8-bit descriptors, 512 x the L1-root normalised values)."""
    keypoints, descriptors = cv2.SIFT_create().detectAndCompute(gray, None)
    root = np.sqrt(descriptors / descriptors.sum(1, keepdims=True))
    stored = np.minimum(np.round(512 * root), 255).astype(np.uint8)
    return colmap_features(np.array([k.pt for k in keypoints], np.float32) + 0.5, stored)


def textured(height: int = 180, width: int = 240, seed: int = 0) -> np.ndarray:
    """A grey picture with blobs and edges at many scales (uint8)."""
    rng = np.random.default_rng(seed)
    image = np.zeros((height, width), np.float32)
    for size in (3, 7, 15):
        noise = rng.random((height // size + 2, width // size + 2)).astype(np.float32)
        image += cv2.resize(noise, (width + 2 * size, height + 2 * size), interpolation=cv2.INTER_CUBIC)[
            size : size + height, size : size + width
        ]
    image = (image - image.min()) / (image.max() - image.min())
    return (255 * image).astype(np.uint8)


def shifted(image: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """The picture moved by (dx, dy) pixels (what was at x is at x + dx), its border repeated."""
    warp = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(image, warp, image.shape[::-1], flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def test_features_of_a_moved_picture_match_where_the_flow_puts_them():
    """Guided matches join each feature to the one the known motion carries it to (99% within half a
    pixel, none off by 1.5; coarse blobs are located less finely), and most features find theirs."""
    a_image = textured()
    b_image = shifted(a_image, 5.0, -3.0)
    a, b = sift_features(a_image), sift_features(b_image)
    assert len(a.positions) > 100 and a.descriptors.shape == (len(a.positions), 128)
    assert np.allclose(np.linalg.norm(a.descriptors, axis=1), 1, atol=1e-4)  # RootSIFT: unit vectors
    from scipy.spatial import cKDTree

    predicted = a.positions + np.float32([5.0, -3.0])
    alive = (predicted[:, 0] > 8) & (predicted[:, 0] < 232) & (predicted[:, 1] > 8) & (predicted[:, 1] < 172)
    matches = guided_matches(a, b, predicted, alive, cKDTree(b.positions))
    moved = b.positions[matches[:, 1]] - a.positions[matches[:, 0]]
    assert len(matches) > 0.5 * alive.sum()
    off = np.linalg.norm(moved - [5.0, -3.0], axis=1)
    assert np.quantile(off, 0.99) < 0.5 and off.max() < 1.5, (np.quantile(off, 0.99), off.max())
    # A prediction off by more than the guide radius finds nothing right (a few chance matches at most).
    wrong = guided_matches(a, b, predicted + 3 * GUIDE_RADIUS, alive, cKDTree(b.positions))
    assert len(wrong) < 0.05 * len(matches)


def test_a_match_must_be_mutual_and_clearly_the_best():
    """(query, candidate, distance) triples: q0's best is c0, but c0's best is q1, so q0 stays unmatched;
    q2's best is barely better than its second (ratio above 0.8): unmatched; q3-c3 is clear both ways."""
    query = np.array([0, 0, 1, 2, 2, 3, 3])
    candidate = np.array([0, 1, 0, 2, 3, 3, 1])
    distance = np.array([0.30, 0.90, 0.10, 0.50, 0.55, 0.20, 0.80])
    assert mutual_matches(query, candidate, distance, (4, 4)).tolist() == [[1, 0], [3, 3]]


def test_flow_guided_matches_of_a_panning_clip_follow_the_pan():
    """Five frames, each 3.5 px right of the last: the pairs are COLMAP's quadratic ones, and nearly every
    match of frames k apart moves 3.5k px (DIS flow, measured, not given)."""
    base = textured(200, 260, seed=1)
    frames = [shifted(base, 3.5 * k, 0.0) for k in range(5)]
    features = [sift_features(frame) for frame in frames]
    found = flow_guided_matches(frames, features, overlap=10, threads=2, log=lambda line: None)
    assert set(found) == set(sequential_pairs(5, 10)) == {(0, 1), (0, 2), (0, 4), (1, 2), (1, 3), (2, 3), (2, 4),
                                                           (3, 4)}  # fmt: skip
    for (i, j), matches in found.items():
        moved = features[j].positions[matches[:, 1]] - features[i].positions[matches[:, 0]]
        assert len(matches) > 50, (i, j)
        off = np.linalg.norm(moved - [3.5 * (j - i), 0.0], axis=1)
        assert np.mean(off < 1.0) > 0.99 and np.median(off) < 0.1, (i, j)  # the rest is for verification


def test_features_read_from_colmaps_database_are_unit_rootsift_at_opencvs_pixel_centres():
    keypoints = np.array([[10.5, 20.5, 1, 0, 0, 1], [0.5, 0.5, 1, 0, 0, 1]], np.float32)  # COLMAP's 6 columns
    stored = np.zeros((2, 128), np.uint8)
    stored[0, 0] = 255
    stored[1, :4] = 128
    features = colmap_features(keypoints, stored)
    assert features.positions.tolist() == [[10.0, 20.0], [0.0, 0.0]]
    assert np.allclose(np.linalg.norm(features.descriptors, axis=1), 1) and features.descriptors[1, 0] == 0.5
    empty = colmap_features(np.zeros((0, 6), np.float32), np.zeros((0, 128), np.uint8))
    assert empty.positions.shape == (0, 2) and empty.descriptors.shape == (0, 128)
    a = textured()
    assert len(flow_guided_matches([a, a], [empty, sift_features(a)], 10, 1, lambda line: None)) == 0
