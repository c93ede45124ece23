"""The inputs of the LPIPS reference comparison: image pairs and seeded backbone weights.

Imported both by tests/lpips_reference.py (run in the PyPI `lpips` package's own environment to
record tests/data/lpips_pypi_reference.json) and by tests/test_lpips_reference.py (our LPIPS,
against that record), so both sides compute on the same arrays. numpy only: no torch, no liquidgs.
The record keeps a checksum of every array, so a numpy release that changed its random streams
is reported as such instead of as an LPIPS mismatch.
"""

from __future__ import annotations

import zlib

import numpy as np

SEED = 0
BACKBONES = ("vgg", "alex", "squeeze")
# normalize=True maps [0, 1] inputs to [-1, 1] (correct use); False feeds them unchanged (the
# D-3DGS reference's quirk). Both are recorded.
NORMALIZE = {"normalized": True, "raw": False}


def image_pairs() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Deterministic [B, H, W, 3] float32 pairs in [0, 1] on 8-bit levels, square and not."""
    rng = np.random.default_rng(SEED)

    def levels(*shape: int) -> np.ndarray:
        return rng.integers(0, 256, size=shape).astype(np.float32) / 255

    pairs = {
        "noise_64": (levels(3, 64, 64, 3), levels(3, 64, 64, 3)),
        # Odd, non-square: exercises the pools' rounding (SqueezeNet's ceil_mode).
        "noise_97x80": (levels(2, 97, 80, 3), levels(2, 97, 80, 3)),
    }
    # A smooth image (red and green ramps) and a copy with faint 8-bit noise: a small distance.
    ramp = np.arange(64, dtype=np.float32) * 4 / 255
    base = np.stack(np.broadcast_arrays(ramp[None, :], ramp[:, None], np.float32(128 / 255)), -1)
    near = np.clip(base + rng.integers(-3, 4, size=base.shape) / 255, 0, 1).astype(np.float32)
    pairs["small_difference"] = (base[None], near[None])
    # A wide structured image and the same pattern moved by two pixels, as a slightly misplaced render.
    y, x = np.mgrid[0:72, 0:122].astype(np.float32)
    pattern = np.stack([np.sin(x / 5) * np.cos(y / 7), np.sin((x + y) / 9), np.cos(x / 11)], -1) * 0.5 + 0.5
    pattern = np.round(pattern * 255) / 255
    pairs["shifted_72x120"] = (pattern[None, :, 2:].astype(np.float32), pattern[None, :, :-2].astype(np.float32))
    return pairs


def seeded_features(shapes: dict[str, list[int]]) -> dict[str, np.ndarray]:
    """Backbone weights for a torchvision ``features.*`` layout: He-normal convolutions and small
    uniform biases, each tensor from its own stream (seeded by SEED and its name), so the result
    does not depend on the order the names come in."""
    weights = {}
    for name, shape in shapes.items():
        rng = np.random.default_rng([SEED, zlib.crc32(name.encode())])
        if name.endswith(".weight"):
            fan_in = int(np.prod(shape[1:]))
            weights[name] = (rng.standard_normal(shape) * np.sqrt(2.0 / fan_in)).astype(np.float32)
        else:
            weights[name] = rng.uniform(-0.05, 0.05, size=shape).astype(np.float32)
    return weights


def checksum(arrays: dict[str, np.ndarray]) -> float:
    """Sum of |x| over all arrays in float64: changes whenever numpy draws other numbers."""
    return float(sum(np.abs(a.astype(np.float64)).sum() for a in arrays.values()))
