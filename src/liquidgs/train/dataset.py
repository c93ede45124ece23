"""The scene as a run sees it, for the trainer and every reader of a run or baked scene."""

from __future__ import annotations

from liquidgs.data import SceneDataset, load_dataset, perturb_dataset
from liquidgs.train.config import TrainConfig


def load_run_dataset(cfg: TrainConfig, clean: SceneDataset | None = None) -> SceneDataset:
    """The scene as this run sees it: `clean` (else read from cfg.data) with cfg.perturb applied,
    so training, evaluation and renders of a perturbed run use the same splits."""
    return perturb_dataset(clean if clean is not None else load_dataset(cfg.data), cfg.perturb, cfg.seed)
