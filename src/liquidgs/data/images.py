"""Lazy image loading: decode, composite on the background, area-downscale, cache as uint8.

Order of operations: the RGBA image is composited (rgb*a + bg*(1-a)) at its stored
resolution, then area-averaged. Compositing is linear, so this equals averaging the
premultiplied RGBA and compositing afterwards: it is the box-filtered image a camera with
bigger pixels would see, and edges do not get the dark or bright fringes that averaging
straight (non-premultiplied) colours gives. The result is rounded to uint8.

Only uint8 images are kept, in one bounded LRU cache per dataset, so a 200-frame 800x800
scene never holds its float copy in memory.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from pathlib import Path

import numpy as np

from liquidgs.data.validate import decode_image


def composite_and_downscale(rgba: np.ndarray, background: tuple[float, float, float], factor: int) -> np.ndarray:
    """uint8 RGBA [H, W, 4] -> uint8 RGB [H//factor, W//factor, 3], rounded to nearest.

    Integer arithmetic throughout (the background is an 8-bit colour): the composite, 255 x its 8-bit
    value, is at most 255 * 255 and fits uint16; block sums take uint32, rows of blocks first (one
    contiguous pass): 1.6-1.8x faster than summing (rows, columns) of uint32 at once (800x800, factors
    2-8, one thread of the 2-core Xeon). A size that is
    not a multiple of `factor` loses its last partial row/column of blocks; the kept pixel centres stay
    where K/factor puts them.
    """
    if factor == 1 and bool((rgba[..., 3] == 255).all()):
        return np.ascontiguousarray(rgba[..., :3])
    alpha = rgba[..., 3:].astype(np.uint16)
    background_8bit = np.rint(np.asarray(background) * 255.0).astype(np.uint16)
    composite = rgba[..., :3] * alpha
    composite += background_8bit * (255 - alpha)
    if factor > 1:
        height, width = rgba.shape[0] // factor, rgba.shape[1] // factor
        kept = composite[: height * factor, : width * factor]
        rows = kept.reshape(height, factor, width * factor * 3).sum(axis=1, dtype=np.uint32)
        composite = rows.reshape(height, width, factor, 3).sum(axis=2, dtype=np.uint32)
    divisor = 255 * factor * factor  # at factor 1, 65025 + 127 still fits uint16
    return ((composite + divisor // 2) // divisor).astype(np.uint8)


class ImageLoader:
    """Decodes images for one dataset; keeps at most `capacity` of them (0 disables the cache)."""

    def __init__(self, background: tuple[float, float, float], factor: int, capacity: int):
        self.background = background
        self.factor = factor
        self.capacity = capacity
        self._cache: OrderedDict[Path, np.ndarray] = OrderedDict()
        # A trainer may prefetch from a thread; the OrderedDict moves must not interleave.
        self._lock = threading.Lock()

    def load(self, path: Path) -> np.ndarray:
        with self._lock:
            if path in self._cache:
                self._cache.move_to_end(path)
                return self._cache[path]
        image = composite_and_downscale(decode_image(path), self.background, self.factor)
        image.setflags(write=False)  # shared by every caller: nobody may edit the cached copy
        if self.capacity > 0:
            with self._lock:
                self._cache[path] = image
                while len(self._cache) > self.capacity:
                    self._cache.popitem(last=False)
        return image
