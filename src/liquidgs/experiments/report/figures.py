"""The report's figures: mean PSNR against lambda, and the qualitative MLP vs SDE-LNN comparison."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from liquidgs.atomic import write_atomic
from liquidgs.errors import LiquidGSError
from liquidgs.experiments.report.aggregate import DatasetScores
from liquidgs.experiments.report.collect import Method, RunRecord
from liquidgs.fields.config import PAPER_LAMBDA
from liquidgs.media import labelled, to_uint8, write_png
from liquidgs.train.dataset import load_run_dataset
from liquidgs.train.run import load_run

QUALITATIVE_SCENES = 3
PANEL = 192
"""Side of each panel in pixels: the crop is scaled to it (nearest neighbour, so pixels stay visible)."""
CROP_FRACTION = 0.5
"""The crop window's side as a fraction of the image's shorter side."""


def save_plot(fig, path: Path) -> Path:
    """A matplotlib figure as a PNG, written atomically; the figure is closed either way."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    try:
        return write_atomic(path, lambda tmp: fig.savefig(tmp, format="png", dpi=120))
    finally:
        plt.close(fig)


def noise_plot(path: Path, curves: dict[str, list[tuple[float, float, float | None]]]) -> Path:
    """One panel per dataset: mean PSNR per lambda, with the seed spread (std) as error bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(curves), figsize=(4.2 * len(curves), 3.2), squeeze=False)
    for ax, (dataset, points) in zip(axes[0], curves.items()):
        lambdas, means, stds = zip(*points)
        errors = [s if s is not None else 0.0 for s in stds]
        ax.errorbar(lambdas, means, yerr=errors, marker="o", capsize=4)
        ax.set_title(f"{dataset}: dataset mean")
        ax.set_xlabel("lambda (gate-noise level)")
        ax.set_ylabel("PSNR (dB)")
        ax.grid(alpha=0.3)
    return save_plot(fig, path)


@dataclass(frozen=True)
class QualitativeRow:
    scene: str
    gain_db: float
    """SDE-LNN minus MLP, the scene's PSNR (mean over seeds) under the report's evaluation."""
    seed: int
    view: str
    time: float
    view_psnr: tuple[float, float]
    """(MLP, SDE-LNN) PSNR on the chosen view, from per_view.json (final evaluation)."""
    crop: tuple[int, int, int]
    """(x, y, side) of the crop window, in pixels of the test image."""
    image_size: tuple[int, int]


def qualitative_pair(scores: DatasetScores) -> tuple[Method, Method] | None:
    """The MLP and the SDE-LNN row to compare: the paper's lambda when run, else the smallest lambda."""
    sde = [m for m in scores.methods if m.field == "sde"]
    mlp = [m for m in scores.methods if m.field == "mlp"]
    if not sde or not mlp:
        return None
    paper = [m for m in sde if m.lambda_ == PAPER_LAMBDA]
    return mlp[0], (paper or sde)[0]


def crop_window(improvement: np.ndarray, side: int) -> tuple[int, int]:
    """Top-left (x, y) of the side x side window whose summed |err_sde| - |err_mlp| is largest in magnitude."""
    integral = np.pad(improvement, ((1, 0), (1, 0))).cumsum(0).cumsum(1)
    sums = integral[side:, side:] - integral[:-side, side:] - integral[side:, :-side] + integral[:-side, :-side]
    y, x = np.unravel_index(np.argmax(np.abs(sums)), sums.shape)
    return int(x), int(y)


def _panel(image: np.ndarray, x: int, y: int, side: int, text: str) -> np.ndarray:
    crop = image[y : y + side, x : x + side]
    rows = np.linspace(0, side - 1, PANEL).round().astype(int)
    return labelled(np.ascontiguousarray(crop[rows][:, rows]), text)


def _by_seed(runs: list[RunRecord], method: Method, scene: str) -> dict[int, RunRecord]:
    return {r.entry.seed: r for r in runs if r.method == method and r.entry.scene == scene}


def qualitative_figure(scores: DatasetScores, path: Path, device: str) -> tuple[list[QualitativeRow], list[str]]:
    """Write the figure; returns its rows (top to bottom) and the scenes skipped, each with its reason."""
    pair = qualitative_pair(scores)
    if pair is None:
        return [], ["the experiment has no MLP / SDE-LNN pair on this dataset"]
    mlp, sde = pair
    gains = []
    for scene in scores.scenes:
        a, b = scores.cell(mlp, scene, "psnr"), scores.cell(sde, scene, "psnr")
        if a is not None and b is not None:
            gains.append((b.mean - a.mean, scene))
    if not gains:
        return [], [f"no scene has finished runs of both {mlp.label} and {sde.label}"]
    gains.sort(reverse=True)
    rows, images, skipped = [], [], []
    for gain, scene in gains:
        if len(rows) == QUALITATIVE_SCENES:
            break
        mlp_runs, sde_runs = _by_seed(scores.runs, mlp, scene), _by_seed(scores.runs, sde, scene)
        seeds = sorted(s for s in mlp_runs.keys() & sde_runs.keys() if mlp_runs[s].per_view and sde_runs[s].per_view)
        if not seeds:
            skipped.append(f"{scene}: no seed with per_view.json for both fields")
            continue
        try:
            row, image = _scene_row(scene, gain, seeds[0], mlp_runs[seeds[0]], sde_runs[seeds[0]], device)
        except LiquidGSError as err:
            skipped.append(f"{scene}: {err}")
            continue
        rows.append(row)
        images.append(image)
    if images:
        write_png(path, np.concatenate(images, axis=0))
    return rows, skipped


def _scene_row(scene: str, gain: float, seed: int, mlp: RunRecord, sde: RunRecord, device: str):
    mlp_views = {v["name"]: v["psnr"] for v in mlp.per_view["views"]}
    sde_views = {v["name"]: v["psnr"] for v in sde.per_view["views"]}
    common = mlp_views.keys() & sde_views.keys()
    if not common:
        raise LiquidGSError("the two runs' per_view.json share no test view")
    view = max(sorted(common), key=lambda name: sde_views[name] - mlp_views[name])
    dataset = load_run_dataset(sde.config)
    frame = next((f for f in dataset.test if f.name == view), None)
    if frame is None:
        raise LiquidGSError(f"test view '{view}' of per_view.json is not in {sde.config.data.path}")
    background = torch.tensor(dataset.background, dtype=torch.float32)
    truth = to_uint8(frame.image())
    renders = []
    for record in (mlp, sde):
        run = load_run(record.folder, device)
        rendered = run.render(frame.camera, frame.time, background)
        renders.append(to_uint8(rendered.rgb))
    errors = [np.abs(r.astype(np.float64) - truth).mean(axis=-1) / 255.0 for r in renders]
    side = max(1, int(min(truth.shape[:2]) * CROP_FRACTION))
    x, y = crop_window(errors[1] - errors[0], side)
    panels = [
        _panel(truth, x, y, side, "ground truth"),
        _panel(renders[0], x, y, side, f"MLP {mlp_views[view]:.2f} dB"),
        _panel(renders[1], x, y, side, f"SDE-LNN {sde_views[view]:.2f} dB"),
    ]
    row = QualitativeRow(scene, gain, seed, view, float(frame.time), (mlp_views[view], sde_views[view]), (x, y, side),
                         (truth.shape[1], truth.shape[0]))  # fmt: skip
    return row, np.concatenate(panels, axis=1)


def mean_psnr_curve(scores: DatasetScores, methods: list[Method]) -> list[tuple[float, float, float | None]]:
    """(lambda, dataset-mean PSNR, std over seeds) for each sde row with a complete dataset mean."""
    points = []
    for method in methods:
        mean = scores.dataset_mean(method, "psnr")
        if mean is not None:
            points.append((method.lambda_, mean.mean, mean.std))
    return points
