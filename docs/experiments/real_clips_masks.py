"""Masks of the moving subject for the real-clip benchmark's test views, from the boxes drawn by eye in
real-clips-boxes.json (beside this script): python docs/experiments/real_clips_masks.py OUT writes
OUT/<clip>/<view name>.png (255 inside the box), for `liquidgs eval --run RUN --mask OUT/<clip>`."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

BOXES = Path(__file__).with_name("real-clips-boxes.json")


def write_masks(out: Path) -> None:
    for clip, entry in json.loads(BOXES.read_text())["clips"].items():
        width, height = entry["size"]
        folder = out / clip
        folder.mkdir(parents=True, exist_ok=True)
        for view, (x0, y0, x1, y1) in entry["boxes"].items():
            if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
                raise SystemExit(f"{BOXES}: clips.{clip}.boxes.{view}: box {[x0, y0, x1, y1]} outside {width}x{height}")
            mask = np.zeros((height, width), np.uint8)
            mask[y0:y1, x0:x1] = 255
            Image.fromarray(mask).save(folder / f"{view}.png")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: python docs/experiments/real_clips_masks.py OUT")
    write_masks(Path(sys.argv[1]))
