"""The formats of a run folder's records: results.json, the per-view files and checkpoint.pt."""

from __future__ import annotations

import dataclasses
import json
import typing
from dataclasses import dataclass
from pathlib import Path

import torch

from liquidgs.atomic import save_torch_atomic, write_json_atomic
from liquidgs.errors import LiquidGSError
from liquidgs.gaussians import PARAM_KEYS
from liquidgs.train.run_folder.layout import CHECKPOINT, FAILURE, RESULTS

RESULTS_FORMAT = "liquidgs-results-1"
"""A results.json without a format was written before the format was recorded: it is this one."""
CHECKPOINT_FORMAT = "liquidgs-checkpoint-1"


@dataclass(frozen=True, kw_only=True)
class RunResults:
    """results.json: a finished run's record, written once when training ends.

    `final` and `best_of` are evaluation summaries (eval.evaluate_views, with the iteration);
    their keys belong to the evaluation, not to this format.
    """

    format: str = RESULTS_FORMAT
    scene: str
    data: str
    field: str
    preset: str
    lambda_: float
    """The resolved noise level ("lambda" in the file)."""
    seed: int
    iterations: int
    final: dict
    """The evaluation at the last iteration: the unbiased number."""
    best_of: dict
    """The evaluation with the best test PSNR (test-set model selection), with a note saying so."""
    evaluated_at: list
    fps: float
    num_gaussians: int
    field_parameters: int
    field_flops_per_gaussian: int
    train_seconds: float
    peak_memory_mb: float
    peak_memory_kind: str
    """cuda_max_memory_allocated or process_peak_rss: what peak_memory_mb measures."""
    device: str
    backend: str
    torch: str
    lpips_backbone: str
    lpips_normalize: bool
    resolution: list
    """[width, height] of the training images."""
    perturb: dict
    """The perturbations switched on, by name (data.perturb)."""
    views: dict
    """{"train": n, "test": n}."""
    final_aligned: dict = dataclasses.field(default_factory=dict)
    """Runs that refine their cameras or compensate exposure: the final evaluation again with each test
    view aligned to the frozen scene, its pose and exposure (its "cameras" says how); `final` is with
    the test cameras as given. Empty for a run that does neither, and then left out of results.json,
    as before refinement existed."""
    threads: int | None = None
    """torch's intra-op threads, which the compiled CPU kernels use too (train.run.training_threads);
    None in results written before it was recorded. Some results depend on it (docs/training.md says which)."""
    dynamic_gaussians: int | None = None
    """Of num_gaussians, those the field moves in a run that splits them (train.dynamic_split); None
    (left out) in a run that does not."""

    def to_json(self) -> dict:
        """The file's content; what was recorded later and is absent here (threads or dynamic_gaussians
        None, final_aligned empty) is left out, as it was before."""
        return {
            _json_key(name): value
            for name, value in dataclasses.asdict(self).items()
            if not (name in _RECORDED_LATER and value is None) and (name != "final_aligned" or value)
        }

    @classmethod
    def from_json(cls, raw, path: Path) -> RunResults:
        """The record in `raw` (results.json's content); anything else is one error naming `path`."""
        if not isinstance(raw, dict):
            raise LiquidGSError(f"{path}: corrupt results (not a JSON object)")
        check_results_format(raw, path)
        types = typing.get_type_hints(cls)
        names = {_json_key(f.name): f.name for f in dataclasses.fields(cls)}
        unknown = sorted(raw.keys() - names.keys())
        if unknown:
            raise LiquidGSError(f"{path}: field '{unknown[0]}' is not part of {RESULTS_FORMAT}")
        for key, name in names.items():
            if name == "format":
                continue
            if key not in raw:
                if _has_default(cls, name):  # added to the format later
                    continue
                raise LiquidGSError(f"{path}: field '{key}' is missing")
            if raw[key] is None and name in _RECORDED_LATER:
                continue
            kind = _RECORDED_LATER.get(name, types[name])
            if not _is_a(raw[key], kind):
                raise LiquidGSError(f"{path}: field '{key}' is not {_JSON_KINDS[kind]}")
        return cls(**{name: raw[key] for key, name in names.items() if key in raw})


_RECORDED_LATER = {"threads": int, "dynamic_gaussians": int}
"""Fields added to the format after results were written without them, with their kind: absent or
null means unknown (None)."""

_JSON_KINDS = {
    str: "a string",
    int: "an integer",
    float: "a number",
    bool: "true or false",
    dict: "an object",
    list: "a list",
}


def check_results_format(raw: dict, path: Path) -> None:
    """Refuse results of a format this version does not read (none recorded: the first)."""
    version = raw.get("format", RESULTS_FORMAT)
    if version != RESULTS_FORMAT:
        raise LiquidGSError(f"{path}: results format {version!r} is not one this liquidgs reads ({RESULTS_FORMAT})")


def _has_default(cls, name: str) -> bool:
    field = next(f for f in dataclasses.fields(cls) if f.name == name)
    return field.default is not dataclasses.MISSING or field.default_factory is not dataclasses.MISSING


def _json_key(name: str) -> str:
    return "lambda" if name == "lambda_" else name


def _is_a(value, kind: type) -> bool:
    if isinstance(value, bool):  # a bool is an int to Python, never to this format
        return kind is bool
    if kind is float:
        return isinstance(value, (int, float))
    return isinstance(value, kind)


def write_results(run_dir: Path, results: RunResults) -> Path:
    return write_json_atomic(run_dir / RESULTS, results.to_json())


def read_results(run_dir: Path) -> RunResults:
    path = run_dir / RESULTS
    try:
        raw = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise LiquidGSError(f"{path}: unreadable ({type(err).__name__})") from None
    return RunResults.from_json(raw, path)


def write_per_view(path: Path, iteration: int, views: list[dict], source: dict | None = None) -> Path:
    """PER_VIEW (training's final evaluation) or EVAL_PER_VIEW: each view's scores at `iteration`;
    EVAL_PER_VIEW with the source record of the checkpoint it scored (provenance)."""
    record = {"iteration": iteration, "views": views}
    return write_json_atomic(path, record if source is None else {**record, "source": source})


def write_failure(run_dir: Path, checkpoint_iteration: int | None, reason: str) -> Path:
    """FAILURE: why the run stopped (the error it exited with) and the iteration of the checkpoint
    it kept (None: none yet)."""
    return write_json_atomic(run_dir / FAILURE, {"reason": reason, "checkpoint_iteration": checkpoint_iteration})


def write_checkpoint(run_dir: Path, contents: dict) -> Path:
    """checkpoint.pt: the trainer's `contents` (tensors, numbers, strings and plain containers
    only, so read_checkpoint can load it safely) under this format's marker."""
    payload = {"format": CHECKPOINT_FORMAT, **contents}

    return save_torch_atomic(run_dir / CHECKPOINT, payload)


def read_checkpoint(path: Path) -> dict:
    """A checkpoint's contents; an unreadable, truncated or foreign file is one error naming it.

    weights_only=True: the payload holds only tensors, numbers, strings and plain containers,
    so a crafted file cannot run code when a shared run folder is evaluated or resumed.
    """
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
        if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
            raise ValueError("not a liquidgs checkpoint")
        missing = [k for k in PARAM_KEYS if k not in payload["params"]]
        if missing:
            raise ValueError(f"missing parameters {missing}")
    except Exception as err:  # noqa: BLE001 - any unpickling failure means a corrupt or unsafe file
        first_line = (str(err).strip().splitlines() or [""])[0][:200]
        raise LiquidGSError(f"{path}: corrupt or unreadable checkpoint ({type(err).__name__}: {first_line})") from None
    return payload
