"""From finished runs to table cells: means and spreads over seeds, dataset means, costs, ties.

Spreads are sample standard deviations (ddof=1) over seeds; a cell from one seed has none.
A dataset mean is the mean of the per-scene means and exists only when every scene of the
dataset has a finished run; its spread is over the per-seed dataset means of the seeds
finished on every scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from liquidgs.experiments.report.collect import Collection, Method, RunRecord
from liquidgs.experiments.report.references import MEAN, paper_sigma
from liquidgs.experiments.report.significance import CONFIDENCE, MIN_CLUSTERS, TOO_FEW, cluster_difference
from liquidgs.experiments.report.tables import METRICS, SizeRow, latex_escape
from liquidgs.fields.registry import field_label, field_names, field_type

TIE_SIGMAS = 2.0


@dataclass(frozen=True)
class Stat:
    mean: float
    std: float | None
    n: int


def stat(values: list[float]) -> Stat | None:
    if not values:
        return None
    mean = math.fsum(values) / len(values)
    if len(values) < 2:
        return Stat(mean, None, 1)
    return Stat(mean, math.sqrt(math.fsum((v - mean) ** 2 for v in values) / (len(values) - 1)), len(values))


@dataclass
class DatasetScores:
    """One dataset's scores under one evaluation: (method, scene, metric) -> seed -> value."""

    dataset: str
    scenes: list[str]
    methods: list[Method]
    values: dict[tuple[Method, str, str], dict[int, float]]
    runs: list[RunRecord]

    @classmethod
    def build(cls, collection: Collection, dataset: str, evaluation: str) -> DatasetScores:
        runs = collection.runs(dataset)
        values: dict[tuple[Method, str, str], dict[int, float]] = {}
        for run in runs:
            scores = run.evaluation(evaluation)
            for metric in METRICS:
                if scores.get(metric.key) is not None:
                    per_seed = values.setdefault((run.method, run.entry.scene, metric.key), {})
                    per_seed[run.entry.seed] = scores[metric.key]
        planned = {Method.of(r.field, r.lambda_) for r in collection.experiment.runs if r.dataset == dataset}
        return cls(dataset, collection.scenes(dataset), sorted(planned), values, runs)

    def cell(self, method: Method, scene: str, metric: str) -> Stat | None:
        if scene == MEAN:
            return self.dataset_mean(method, metric)
        return stat(list(self.values.get((method, scene, metric), {}).values()))

    def dataset_mean(self, method: Method, metric: str) -> Stat | None:
        cells = [self.values.get((method, scene, metric), {}) for scene in self.scenes]
        if not all(cells):
            return None
        mean = math.fsum(math.fsum(c.values()) / len(c) for c in cells) / len(cells)
        complete = set.intersection(*(set(c) for c in cells))
        per_seed = stat([math.fsum(c[s] for c in cells) / len(cells) for s in sorted(complete)])
        return Stat(mean, per_seed.std if per_seed else None, len(complete))

    def seeds(self) -> list[int]:
        return sorted({seed for per_seed in self.values.values() for seed in per_seed})


@dataclass(frozen=True)
class Spread:
    scene: str
    method: Method
    n: int
    low: float
    high: float
    sigma: float | None


def seed_spreads(scores: DatasetScores) -> list[Spread]:
    """PSNR over seeds per scene and method."""
    out = []
    for scene in scores.scenes:
        for method in scores.methods:
            psnrs = list(scores.values.get((method, scene, "psnr"), {}).values())
            if psnrs:
                s = stat(psnrs)
                out.append(Spread(scene, method, len(psnrs), min(psnrs), max(psnrs), s.std if s else None))
    return out


def tie_sigma(spreads: list[Spread]) -> tuple[float, str]:
    """The PSNR sigma behind the tie rule: pooled over this dataset's cells with >1 seed, else the paper's."""
    variances = [s.sigma**2 for s in spreads if s.sigma is not None]
    if not variances:
        sigma, source = paper_sigma()
        return sigma, f"one seed per run, so no spread can be measured here; using {source}"
    pooled = math.sqrt(math.fsum(variances) / len(variances))
    return pooled, f"pooled over {len(variances)} scene/method cells with several seeds (measured here)"


def paired_psnr_differences(scores: DatasetScores, scene: str, a: Method, b: Method) -> list[float]:
    """PSNR of a minus b per (scene, seed) both have: the clusters behind a lead (every scene for MEAN)."""
    out = []
    for name in scores.scenes if scene == MEAN else [scene]:
        va, vb = scores.values.get((a, name, "psnr"), {}), scores.values.get((b, name, "psnr"), {})
        out += [va[seed] - vb[seed] for seed in sorted(set(va) & set(vb))]
    return out


def lead_sentence(subject: str, ranked: list[tuple[Method, float]], sigma: float, paired: list[float]) -> str:
    """Who leads on PSNR, by how much, and whether the lead is called a lead, a tie or too few to call.

    `paired`: the leader minus the runner-up per (scene, seed). A lead needs at least MIN_CLUSTERS of
    them and their t-interval wholly above TIE_SIGMAS sigma (significance.py)."""
    if len(ranked) < 2:
        if not ranked:
            return f"{subject}: no method has scores yet; no comparison."
        return f"{subject}: only {ranked[0][0].label} has scores; no comparison."
    (first, a), (second, b) = ranked[0], ranked[1]
    gap = a - b
    head = f"{subject}: {first.label} leads with {a:.2f} dB, {gap:.2f} dB ahead of {second.label} ({b:.2f} dB); "
    runs = f"{len(paired)} paired scene-seed run{'s' if len(paired) != 1 else ''}"
    if len(paired) < MIN_CLUSTERS:
        return head + f"{runs}, fewer than the {MIN_CLUSTERS} a call needs: {TOO_FEW}."
    diff = cluster_difference(paired, TIE_SIGMAS * sigma)
    verdict = "a lead" if diff.verdict == "helps" else "a tie"
    return head + (
        f"over {runs}, {CONFIDENCE:.0%} t-interval {diff.interval_text(2)} dB; under the ties rule (the interval "
        f"wholly above {TIE_SIGMAS:g} sigma = {TIE_SIGMAS * sigma:.2f} dB) this is {verdict}."
    )


def leaders(scores: DatasetScores, scene: str) -> list[tuple[Method, float]]:
    """Methods by PSNR on a scene (or MEAN), best first."""
    pairs = [(m, s.mean) for m in scores.methods if (s := scores.cell(m, scene, "psnr")) is not None]
    return sorted(pairs, key=lambda pair: -pair[1])


@dataclass(frozen=True)
class Cost:
    method: Method
    n: int
    values: dict[str, float]
    memory_kinds: tuple[str, ...]
    devices: tuple[str, ...]


COST_COLUMNS = (
    ("field_parameters", "params", 0),
    ("field_flops_per_gaussian", "FLOPs / Gaussian", 0),
    ("fps", "render FPS", 1),
    ("train_seconds", "train time (s)", 0),
    ("peak_memory_mb", "peak memory (MB)", 0),
    ("num_gaussians", "Gaussians", 0),
)


def costs(scores: DatasetScores) -> list[Cost]:
    """Mean over every finished run of each method (all scenes and seeds)."""
    out = []
    for method in scores.methods:
        runs = [r for r in scores.runs if r.method == method]
        if runs:
            out.append(
                Cost(
                    method,
                    len(runs),
                    {key: math.fsum(r.results[key] for r in runs) / len(runs) for key, _, _ in COST_COLUMNS},
                    tuple(sorted({str(r.results.get("peak_memory_kind", "unlabelled")) for r in runs})),
                    tuple(sorted({str(r.results.get("device", "unknown")) for r in runs})),
                )
            )
    return out


def lpips_description(runs: list[RunRecord], evaluation: str) -> str:
    """Which LPIPS every number is: backbone, version and input normalisation, or why it is unavailable."""
    kinds = set()
    for run in runs:
        scores = run.evaluation(evaluation)
        if scores.get("lpips") is None:
            kinds.add(f"unavailable ({scores.get('lpips_unavailable', 'no reason recorded')})")
        else:
            backbone = scores.get("lpips_backbone", run.results.get("lpips_backbone"))
            normalize = scores.get("lpips_normalize", run.results.get("lpips_normalize"))
            version = scores.get("lpips_version", "0.1")
            inputs = "inputs scaled to [-1,1]" if normalize else "[0,1] inputs fed as [-1,1] (D-3DGS reference quirk)"
            kinds.add(f"LPIPS-{backbone} v{version}, {inputs}")
    if not kinds:
        return "LPIPS: no finished runs"
    listed = "; ".join(sorted(kinds))
    return "LPIPS: " + (listed if len(kinds) == 1 else "MIXED across runs: " + listed)


DATASET_TITLES = {"dnerf": "D-NeRF", "nerfds": "NeRF-DS"}


def inference_kind(run: RunRecord) -> str:
    """How the field infers: a numerical solver (the liquid field's 'solver' noise steps the LTC ODE),
    else one feed-forward pass (the noise of the SDE is off at inference)."""
    return "ODE solver" if getattr(run.config.field_options, "noise", "gate") == "solver" else "feed-forward"


def field_sizes(per_dataset: list[DatasetScores]) -> list[SizeRow]:
    """Table III's rows: the fields of one module (the CfC and SDE-LNN at every lambda: the noise adds
    no parameters) with the same size share a row, over every dataset where they have that size;
    a field whose size differs between datasets gets a row per size, named by its datasets.
    Rows by field, then by size, as the paper orders them."""
    groups: dict[tuple, dict] = {}
    for scores in per_dataset:
        for method in scores.methods:
            runs = [r for r in scores.runs if r.method == method]
            if not runs:
                continue
            params = round(math.fsum(r.results["field_parameters"] for r in runs) / len(runs))
            module = field_type(method.field).family or method.field
            group = groups.setdefault((module, params, inference_kind(runs[0])),
                                      {"fields": {}, "datasets": [], "rank": method.field_rank})  # fmt: skip
            group["fields"].setdefault(method.field, None)
            group["datasets"] += [] if scores.dataset in group["datasets"] else [scores.dataset]
            group["rank"] = min(group["rank"], method.field_rank)
    per_module: dict[str, int] = {}
    for module, _, _ in groups:
        per_module[module] = per_module.get(module, 0) + 1
    rows = []
    for (module, params, inference), group in sorted(groups.items(), key=lambda kv: (kv[1]["rank"], kv[0][1])):
        names = " / ".join(field_label(name) for name in sorted(group["fields"], key=field_names().index))
        where = ", ".join(DATASET_TITLES.get(d, d) for d in group["datasets"]) if per_module[module] > 1 else ""
        label = f"{names} — {where}" if where else names
        rows.append(SizeRow(label, latex_escape(label).replace("—", "---"), params / 1e6, inference))
    return rows
