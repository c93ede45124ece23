"""Reading an experiment folder: the manifest, then each run's config.yml, results.json and per_view.json.

A run counts as finished only when its results.json exists (the trainer writes it last,
atomically); every other planned run is listed as missing, never silently dropped.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from liquidgs.errors import LiquidGSError
from liquidgs.experiments.plan import Experiment, RunEntry, read_manifest
from liquidgs.fields.registry import field_label, field_names, field_type
from liquidgs.train.config import TrainConfig, load_yaml
from liquidgs.train.run_folder import CONFIG, EVAL, PER_VIEW, RESULTS, check_results_format, check_source

EVALUATIONS = ("final", "best_of")
SCORE_KEYS = ("psnr", "ssim")
COST_KEYS = ("fps", "num_gaussians", "field_parameters", "field_flops_per_gaussian", "train_seconds", "peak_memory_mb")


@dataclass(frozen=True, order=True)
class Method:
    """A table row: a field, and for the sde field its noise level."""

    field_rank: int
    lambda_: float

    @classmethod
    def of(cls, field: str, lambda_: float) -> Method:
        field_type(field)  # a run of a field no longer registered: one line, the registered ones
        return cls(field_names().index(field), lambda_ if field == "sde" else 0.0)

    @property
    def field(self) -> str:
        return field_names()[self.field_rank]

    @property
    def label(self) -> str:
        base = field_label(self.field)
        return f"{base} (lambda {self.lambda_:g})" if self.field == "sde" else base

    @property
    def latex_label(self) -> str:
        base = field_label(self.field)
        return f"{base} ($\\lambda{{=}}{self.lambda_:g}$)" if self.field == "sde" else base


@dataclass(frozen=True)
class RunRecord:
    entry: RunEntry
    folder: Path
    config: TrainConfig
    results: dict
    per_view: dict | None
    """None when the run folder has no per_view.json."""

    @property
    def method(self) -> Method:
        return Method.of(self.entry.field, self.entry.lambda_)

    def evaluation(self, which: str) -> dict:
        return self.results[which]

    def second_scores(self) -> tuple[dict | None, dict | None, dict | None]:
        """The labelled second scores: the final test split with test cameras aligned to the scene
        (results.json's final_aligned, runs that refine), and `liquidgs eval --mask`'s inside / outside
        scores (eval.json's masked, cameras as given, and masked_aligned, test cameras aligned); None
        where the run has none. A region's psnr is null where its masks leave it no pixel (an eval.json
        written before such mask sets were refused): the tables say n/a there."""
        aligned = self.results.get("final_aligned") or None
        eval_path = self.folder / EVAL
        evaluation = _read_json(eval_path, EVAL) if eval_path.is_file() else {}
        if evaluation:
            _check_evaluated_checkpoint(eval_path, evaluation, self.results)
        masked, masked_aligned = evaluation.get("masked"), evaluation.get("masked_aligned")
        regions = ("inside", "outside")
        for what, record, path, keys in (("final_aligned", aligned, self.folder / RESULTS, ("psnr", "ssim")),
                                         ("masked", masked, eval_path, regions),
                                         ("masked_aligned", masked_aligned, eval_path, regions)):  # fmt: skip
            if record is not None and not (isinstance(record, dict) and all(k in record for k in keys)):
                raise LiquidGSError(f"{path}: field '{what}' must be an object with {', '.join(keys)}")
        for what, record in (("masked", masked), ("masked_aligned", masked_aligned)):
            for region in regions if record is not None else ():
                scores = record[region]
                if not (isinstance(scores, dict) and _is_number(scores.get("share"))
                        and (scores.get("psnr") is None or _is_number(scores["psnr"]))):  # fmt: skip
                    raise LiquidGSError(
                        f"{eval_path}: field '{what}.{region}' must be an object with numbers psnr (or null), share"
                    )
        return aligned, masked, masked_aligned


@dataclass(frozen=True)
class Collection:
    experiment: Experiment
    finished: tuple[RunRecord, ...]
    missing: tuple[RunEntry, ...]

    def datasets(self) -> list[str]:
        return list(dict.fromkeys(run.dataset for run in self.experiment.runs))

    def scenes(self, dataset: str) -> list[str]:
        return list(dict.fromkeys(run.scene for run in self.experiment.runs if run.dataset == dataset))

    def runs(self, dataset: str) -> list[RunRecord]:
        return [r for r in self.finished if r.entry.dataset == dataset]

    def restricted(self, keep: Callable[[RunEntry], bool]) -> Collection:
        """The same experiment with only the planned runs `keep` accepts."""
        experiment = dataclasses.replace(self.experiment, runs=tuple(r for r in self.experiment.runs if keep(r)))
        finished = tuple(r for r in self.finished if keep(r.entry))
        return Collection(experiment, finished, tuple(r for r in self.missing if keep(r)))


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _read_json(path: Path, what: str) -> dict:
    try:
        raw = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise LiquidGSError(f"{path}: corrupt or unreadable {what} ({err})") from None
    if not isinstance(raw, dict):
        raise LiquidGSError(f"{path}: corrupt {what} (not a JSON object)")
    return raw


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_results(path: Path, results: dict) -> None:
    """Every field the report reads, so a damaged file fails here with its name, not mid-report."""
    check_results_format(results, path)
    for which in EVALUATIONS:
        evaluation = results.get(which)
        if not isinstance(evaluation, dict):
            raise LiquidGSError(f"{path}: field '{which}' is missing or not an object")
        for key in SCORE_KEYS:
            if not _number(evaluation.get(key)):
                raise LiquidGSError(f"{path}: field '{which}.{key}' is missing or not a finite number")
        if evaluation.get("lpips") is not None and not _number(evaluation["lpips"]):
            raise LiquidGSError(f"{path}: field '{which}.lpips' is not a number")
    for key in COST_KEYS:
        if not _number(results.get(key)):
            raise LiquidGSError(f"{path}: field '{key}' is missing or not a finite number")


def _check_evaluated_checkpoint(path: Path, evaluation: dict, results: dict) -> None:
    """eval.json must score the checkpoint the run holds now, not one it has trained past."""
    if "source" in evaluation:
        check_source(
            path,
            evaluation["source"],
            folder=path.parent,
            again=f"run `liquidgs eval --run {path.parent}` again (with its --mask)",
        )
    elif evaluation.get("iteration") != results.get("iterations"):  # made before eval.json had a source
        raise LiquidGSError(
            f"{path}: scores iteration {evaluation.get('iteration')!r}, but the run finished at iteration "
            f"{results.get('iterations')}; run `liquidgs eval --run {path.parent}` again (with its --mask)"
        )


def _check_views(path: Path, per_view: dict) -> None:
    views = per_view.get("views")
    if not isinstance(views, list) or not all(
        isinstance(v, dict) and isinstance(v.get("name"), str) and _number(v.get("psnr")) for v in views
    ):
        raise LiquidGSError(f"{path}: field 'views' must be a list of {{name, psnr, ...}} records")


def _check_matches(path: Path, entry: RunEntry, config: TrainConfig) -> None:
    """The folder must hold the run the manifest planned, or its numbers land in the wrong row."""
    found = (config.field, config.seed, config.resolved_lambda() if config.field == "sde" else 0.0)
    planned = (entry.trained_field, entry.seed, entry.lambda_ if entry.trained_field == "sde" else 0.0)
    if found != planned:
        raise LiquidGSError(
            f"{path}: holds field/seed/lambda {found}, but the manifest plans {planned} for {entry.name} here"
        )


def read_run(experiment_dir: Path, entry: RunEntry) -> RunRecord | None:
    """The finished run, or None while it has no results.json."""
    folder = entry.folder(experiment_dir)
    results_path = folder / RESULTS
    if not results_path.is_file():
        return None
    config_path = folder / CONFIG
    if not config_path.is_file():
        raise LiquidGSError(f"{folder}: has {RESULTS} but no {CONFIG}")
    config = load_yaml(config_path)
    _check_matches(config_path, entry, config)
    results = _read_json(results_path, RESULTS)
    _check_results(results_path, results)
    per_view_path = folder / PER_VIEW
    per_view = None
    if per_view_path.is_file():
        per_view = _read_json(per_view_path, PER_VIEW)
        _check_views(per_view_path, per_view)
    record = RunRecord(entry, folder, config, results, per_view)
    record.second_scores()  # eval.json checked (well-formed, of the checkpoint the run holds) before any writing
    return record


def collect(experiment_dir: str | Path) -> Collection:
    experiment_dir = Path(experiment_dir)
    experiment = read_manifest(experiment_dir)
    finished: list[RunRecord] = []
    missing: list[RunEntry] = []
    seen: set[tuple[str, str]] = set()
    for entry in experiment.runs:
        # A hand-edited manifest listing a run twice: count it once. An SDE row at lambda 0 and the
        # CfC row whose run it is (plan.cfc_twin) are two rows of one folder: both are read.
        if (entry.run_dir, entry.label) in seen:
            continue
        seen.add((entry.run_dir, entry.label))
        record = read_run(experiment_dir, entry)
        if record is None:
            missing.append(entry)
        else:
            finished.append(record)
    return Collection(experiment, tuple(finished), tuple(missing))
