"""The real-clip benchmark's pictures: per clip, one row per test view, ground truth | static | MLP |
CfC | HexPlane, each run rendered from the test camera as given (<clip>-given.png) and from the test
camera aligned to that run's frozen scene as the aligned scores are (<clip>-aligned.png; `liquidgs
eval`'s alignment, camera_opt.aligned_render).

    python docs/experiments/real_clips_strips.py EXPERIMENT_DIR OUT_DIR [SEED]

EXPERIMENT_DIR is `liquidgs experiment run docs/experiments/real-clips.yml`'s folder; OUT_DIR also gets
<clip>.txt (each row's view and time). Runs of SEED (default 0) in every column; a field with no
finished run of it is a grey column.
The pictures are made from the clips, whose licences forbid putting them in this repository.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch

from liquidgs.media import to_uint8, write_png
from liquidgs.train.camera_opt import aligned_render
from liquidgs.train.model import render_frame
from liquidgs.train.run import load_run, load_run_dataset

COLUMNS = ("static", "mlp", "cfc", "hexplane")
DEFAULT_SEED = 0
GAP = 2


def finished_run(scene_dir: Path, field: str, seed: int) -> Path | None:
    """The field's finished run of `seed` under the scene (a results.json marks it done): a clip with
    several seeds is pictured with the same seed in every column."""
    runs = sorted(p.parent for p in (scene_dir / field).glob("*/results.json")
                  if json.loads(p.read_text()).get("seed") == seed)  # fmt: skip
    return runs[-1] if runs else None


def renderers(run, dataset, background) -> dict:
    """The run's render of a test frame from its camera as given and aligned to the frozen scene."""
    cfg = run.config

    def rasterise(gaussians, camera):
        return render_frame(gaussians, camera, sh_degree=run.sh_degree, background=background, backend=cfg.backend).rgb

    aligned = aligned_render(run.at_time, rasterise, cfg.cameras, dataset.camera_extent, cfg.ssim_weight,
                             cfg.alignment(dataset.format))
    return {"given": lambda frame: run.render(frame.camera, frame.time, background).rgb, "aligned": aligned}


def strips(scene_dir: Path, seed: int) -> tuple[dict[str, np.ndarray], list[str]]:
    runs = {field: finished_run(scene_dir, field, seed) for field in COLUMNS}
    loaded = {field: load_run(run, "cpu") for field, run in runs.items() if run is not None}
    if not loaded:
        raise SystemExit(f"{scene_dir}: no finished run")
    dataset = load_run_dataset(next(iter(loaded.values())).config)
    background = torch.tensor(dataset.background, dtype=torch.float32)
    render = {field: renderers(run, dataset, background) for field, run in loaded.items()}
    rows: dict[str, list[np.ndarray]] = {"given": [], "aligned": []}
    notes = []
    for frame in dataset.test:
        truth = frame.image_uint8()
        gap = np.full((truth.shape[0], GAP, 3), 255, np.uint8)
        for cameras, row in rows.items():
            cells = [truth]
            for field in COLUMNS:
                if field in render:
                    with torch.no_grad():
                        cells.append(to_uint8(render[field][cameras](frame)))
                else:
                    cells.append(np.full_like(truth, 128))
            row.append(np.concatenate([c for cell in cells for c in (cell, gap)][:-1], axis=1))
        notes.append(f"view {frame.name}, t = {frame.time:.2f}")
    pictures = {}
    for cameras, row in rows.items():
        blank = np.full((GAP, row[0].shape[1], 3), 255, np.uint8)
        pictures[cameras] = np.concatenate([r for image in row for r in (image, blank)][:-1], axis=0)
    return pictures, notes


def main(experiment: Path, out: Path, seed: int = DEFAULT_SEED) -> int:
    out.mkdir(parents=True, exist_ok=True)
    for scene_dir in sorted((experiment / "real-clips").iterdir()):
        if not scene_dir.is_dir():
            continue
        pictures, notes = strips(scene_dir, seed)
        for cameras, picture in pictures.items():
            write_png(out / f"{scene_dir.name}-{cameras}.png", picture)
        header = f"columns: ground truth | {' | '.join(COLUMNS)} (-given: test cameras as given; -aligned: aligned)"
        (out / f"{scene_dir.name}.txt").write_text("\n".join([header, *notes]) + "\n")
        print(f"{out / scene_dir.name}-given.png, -aligned.png: {len(notes)} test views")
    return 0


if __name__ == "__main__":
    if len(sys.argv) not in (3, 4) or (len(sys.argv) == 4 and not sys.argv[3].isdigit()):
        raise SystemExit("usage: python docs/experiments/real_clips_strips.py EXPERIMENT_DIR OUT_DIR [SEED]")
    sys.exit(main(Path(sys.argv[1]), Path(sys.argv[2]), *map(int, sys.argv[3:])))
