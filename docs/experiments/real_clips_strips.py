"""The real-clip benchmark's pictures: per clip, one row per test view, ground truth | static | MLP |
CfC | HexPlane, each run rendered from the test camera as given (the runs' own test split).

    python docs/experiments/real_clips_strips.py EXPERIMENT_DIR OUT_DIR

EXPERIMENT_DIR is `liquidgs experiment run docs/experiments/real-clips.yml`'s folder; OUT_DIR gets
<clip>.png and <clip>.txt (each row's view and time). A field with no finished run is a grey column.
The pictures are made from the clips, whose licences forbid putting them in this repository.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

from liquidgs.media import to_uint8, write_png
from liquidgs.train.run import load_run, load_run_dataset

COLUMNS = ("static", "mlp", "cfc", "hexplane")
GAP = 2


def finished_run(scene_dir: Path, field: str) -> Path | None:
    """The field's one finished run folder under the scene (a results.json marks it done)."""
    runs = sorted(p.parent for p in (scene_dir / field).glob("*/results.json"))
    return runs[-1] if runs else None


def strip(scene_dir: Path) -> tuple[np.ndarray, list[str]]:
    runs = {field: finished_run(scene_dir, field) for field in COLUMNS}
    done = [run for run in runs.values() if run is not None]
    if not done:
        raise SystemExit(f"{scene_dir}: no finished run")
    loaded = {field: load_run(run, "cpu") for field, run in runs.items() if run is not None}
    dataset = load_run_dataset(next(iter(loaded.values())).config)
    background = torch.tensor(dataset.background, dtype=torch.float32)
    rows, notes = [], []
    for frame in dataset.test:
        truth = frame.image_uint8()
        cells = [truth]
        for field in COLUMNS:
            if field in loaded:
                with torch.no_grad():
                    cells.append(to_uint8(loaded[field].render(frame.camera, frame.time, background).rgb))
            else:
                cells.append(np.full_like(truth, 128))
        gap = np.full((truth.shape[0], GAP, 3), 255, np.uint8)
        rows.append(np.concatenate([c for cell in cells for c in (cell, gap)][:-1], axis=1))
        notes.append(f"view {frame.name}, t = {frame.time:.2f}")
    blank = np.full((GAP, rows[0].shape[1], 3), 255, np.uint8)
    return np.concatenate([r for row in rows for r in (row, blank)][:-1], axis=0), notes


def main(experiment: Path, out: Path) -> int:
    out.mkdir(parents=True, exist_ok=True)
    for scene_dir in sorted((experiment / "real-clips").iterdir()):
        if not scene_dir.is_dir():
            continue
        picture, notes = strip(scene_dir)
        write_png(out / f"{scene_dir.name}.png", picture)
        header = "columns: ground truth | " + " | ".join(COLUMNS) + " (test cameras as given)"
        (out / f"{scene_dir.name}.txt").write_text("\n".join([header, *notes]) + "\n")
        print(f"{out / scene_dir.name}.png: {len(notes)} test views")
    return 0


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit("usage: python docs/experiments/real_clips_strips.py EXPERIMENT_DIR OUT_DIR")
    sys.exit(main(Path(sys.argv[1]), Path(sys.argv[2])))
