"""How well the scenes' own motion masks (`data flow`) agree with the boxes drawn by eye around the moving
subject (real-clips-boxes.json, beside this script), on the real-clip benchmark's test views:
python docs/experiments/real_clips_mask_agreement.py SCENES prints, per clip, the share of the
automatic masks' pixels that lie inside the boxes and the share of the boxes they cover (each pooled
over the clip's test views), and the share of pixels masked."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image

BOXES = Path(__file__).with_name("real-clips-boxes.json")


def agreement(scene: Path, entry: dict) -> dict:
    width, height = entry["size"]
    masks = scene / "flow" / f"{entry['downscale']}x" / "masks"
    inside = masked = box_area = total = 0
    for view, (x0, y0, x1, y1) in entry["boxes"].items():
        mask = np.asarray(Image.open(masks / f"{view}.png")) > 0
        if mask.shape != (height, width):
            raise SystemExit(f"{masks / view}.png: {mask.shape[1]}x{mask.shape[0]}, the boxes are {width}x{height}")
        box = np.zeros_like(mask)
        box[y0:y1, x0:x1] = True
        inside += int((mask & box).sum())
        masked += int(mask.sum())
        box_area += int(box.sum())
        total += mask.size
    return {
        "views": len(entry["boxes"]),
        "masked_share": masked / total,
        "inside_boxes": inside / masked if masked else None,
        "boxes_covered": inside / box_area,
    }


def main(scenes: Path) -> None:
    for clip, entry in json.loads(BOXES.read_text())["clips"].items():
        masks = scenes / clip / "flow" / f"{entry['downscale']}x" / "masks"
        if not masks.is_dir():
            print(f"{clip}: no motion masks at {masks} (liquidgs data flow {scenes / clip})")
            continue
        result = agreement(scenes / clip, entry)
        inside = "n/a (nothing masked)" if result["inside_boxes"] is None else f"{100 * result['inside_boxes']:.0f}%"
        print(
            f"{clip}: {result['views']} test views, {100 * result['masked_share']:.1f}% of pixels masked; "
            f"of them inside the boxes {inside}; boxes covered {100 * result['boxes_covered']:.0f}%"
        )


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: python docs/experiments/real_clips_mask_agreement.py SCENES")
    main(Path(sys.argv[1]))
