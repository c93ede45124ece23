"""The paper's printed numbers and the published D-3DGS numbers, shipped as package data.

paper_targets.json is a copy of the project's targets.json (its `_source` says where each
number is printed). Only printed numbers are used: nothing is recomputed from them, so a
dataset mean appears only where a mean was printed.

Two kinds of rows: references (the paper's retrained D-3DGS MLP and SDE-LNN, the published
D-3DGS numbers), which our rows are compared with and which are not ranked; and the baselines
the paper quotes in its tables (D-NeRF, TiNeuVox, NeRF-DS), which the paper ranks with its own
rows, so the report ranks them with ours: our numbers get the colours they would get there.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cache
from importlib import resources

from liquidgs.experiments.report.collect import Method
from liquidgs.fields.config import PAPER_LAMBDA

METRIC_KEYS = ("psnr", "ssim", "lpips")
MEAN = "mean"


@cache
def paper_targets() -> dict:
    return json.loads(resources.files(__package__).joinpath("paper_targets.json").read_text())


@dataclass(frozen=True)
class Reference:
    label: str
    latex_label: str
    scores: dict[str, dict[str, float]]
    """scene (or 'mean') -> metric key -> printed value."""
    compare_with: Method | None
    """The row of ours it is compared with; None for a quoted baseline."""
    ranked: bool = False
    """True for the quoted baselines: ranked with our rows, as in the paper's table."""


def _scores(per_scene: dict[str, list[float]]) -> dict[str, dict[str, float]]:
    return {scene: dict(zip(METRIC_KEYS, values)) for scene, values in per_scene.items()}


RETRAINED = ("D-3DGS (MLP)", "SDE-LNN")
"""The rows of the paper's Tables I and II that it retrained (ours replace them); the rest are quoted."""
TABLE_KEYS = {"dnerf": "dnerf_table", "nerfds": "nerfds_table"}


def quoted_baselines(dataset: str) -> list[Reference]:
    """The baselines the paper's table for `dataset` quotes and ranks (D-NeRF, TiNeuVox, NeRF-DS, ...)."""
    key = TABLE_KEYS.get(dataset)
    if key is None:
        return []
    methods = paper_targets()[key]["methods"]
    return [Reference(name, name, _scores(per_scene), None, ranked=True)
            for name, per_scene in methods.items() if name not in RETRAINED]  # fmt: skip


def references(dataset: str) -> list[Reference]:
    """Reference rows for a dataset label of the experiment ('dnerf', 'nerfds'); none for others.
    The paper's quoted baselines (ranked) come first, then the compared, unranked references."""
    targets = paper_targets()
    mlp, sde = Method.of("mlp", 0.0), Method.of("sde", PAPER_LAMBDA)
    published = targets["d3dgs_published"]
    if dataset == "dnerf":
        table = targets["dnerf_table"]
        paper_mlp = _scores(table["methods"]["D-3DGS (MLP)"])
        paper_sde = _scores(table["methods"]["SDE-LNN"])
        paper_mlp[MEAN] = {"psnr": table["means_psnr"]["D-3DGS (MLP)"]}
        paper_sde[MEAN] = {"psnr": table["means_psnr"]["SDE-LNN"]}
        d3dgs = _scores(published["dnerf"])
    elif dataset == "nerfds":
        table = targets["nerfds_table"]
        paper_mlp = _scores(table["methods"]["D-3DGS (MLP)"])
        paper_sde = _scores(table["methods"]["SDE-LNN"])
        d3dgs = {MEAN: dict(zip(METRIC_KEYS, published["nerfds_mean"]))}
    else:
        return []
    return [
        *quoted_baselines(dataset),
        Reference("Paper: D-3DGS (MLP)", "Paper: D-3DGS (MLP)", paper_mlp, mlp),
        Reference("Paper: SDE-LNN (lambda 0.05)", "Paper: SDE-LNN ($\\lambda{=}0.05$)", paper_sde, sde),
        Reference("D-3DGS published", "D-3DGS published", d3dgs, mlp),
    ]


def reference_scenes(dataset: str) -> list[str]:
    """The scenes the paper's table covers: its printed mean is comparable only over the same set."""
    key = TABLE_KEYS.get(dataset)
    return [s for s in paper_targets()[key]["scenes"] if s != MEAN] if key else []


def noise_study_means(dataset: str) -> dict[float, dict[str, float]]:
    """lambda -> the paper's dataset-mean metrics (Table IV), for 'dnerf' or 'nerfds'."""
    study = paper_targets()["noise_study_means"]
    columns = study["columns"]
    out = {}
    for lam, values in study.items():
        if lam == "columns":
            continue
        row = dict(zip(columns, values))
        picked = {m: row[f"{dataset}_{m}"] for m in METRIC_KEYS if f"{dataset}_{m}" in row}
        if picked:
            out[float(lam)] = picked
    return out


def paper_sigma() -> tuple[float, str]:
    """The paper's run-to-run PSNR sigma and where it comes from."""
    seeds = paper_targets()["seed_variance"]
    return float(seeds["sigma_db"]), (
        f"the paper's sigma ({seeds['sigma_db']} dB: {seeds['runs']} runs of {seeds['scene']} at lambda "
        f"{seeds['lambda']:g}, PSNR {seeds['psnr_range'][0]}-{seeds['psnr_range'][1]} dB)"
    )
