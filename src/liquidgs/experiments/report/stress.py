"""The stress-test section: does the noise help under corrupted or sparse supervision?

For each perturbation: test PSNR against its strength per field configuration (one PNG), a
table of each sde variant minus the deterministic CfC at each strength with a paired
confidence interval over the scene-seed clusters (significance.py), and one sentence saying
where noise helps, hurts, ties, or rests on too few runs to call. A difference is called only
on at least MIN_CLUSTERS clusters, where its t-interval lies wholly beyond the ties rule's
2 sigma (sigma: the CfC's run-to-run PSNR spread over seeds in this experiment). The clean runs
(strength 0) are shared by every perturbation.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from liquidgs.experiments.plan import RunEntry
from liquidgs.experiments.report.aggregate import TIE_SIGMAS
from liquidgs.experiments.report.collect import Collection, RunRecord
from liquidgs.experiments.report.figures import save_plot
from liquidgs.experiments.report.references import paper_sigma
from liquidgs.experiments.report.significance import (
    CONFIDENCE,
    MIN_CLUSTERS,
    TOO_FEW,
    PairedDifference,
    paired_difference,
    per_view_differences,
    pooled_sigma,
    smallest_sign_flip_p,
)
from liquidgs.experiments.report.tables import PlainTable
from liquidgs.experiments.spec import Variant

BASELINE = "cfc"
"""What every sde variant is compared with: the same cell without noise."""
PERTURBATION_TEXT = {
    "time_jitter": "time jitter (std of the timestamp noise)",
    "pose_rot_deg": "camera rotation (RMS angle, degrees)",
    "pose_trans": "camera translation (RMS shift, x camera extent)",
    "keep_frames": "fewer frames (training frames kept; 0 = all)",
    "time_split": "extrapolation in time (train t < T0, test t >= T0; 0 = interpolation)",
    "image_noise": "image noise (std on pixel values in [0, 1])",
    "exposure": "exposure flicker (std of each frame's per-channel gain)",
}


@dataclass(frozen=True)
class Comparison:
    variant: str
    strength: float
    difference: PairedDifference


def is_paper_run(entry: RunEntry) -> bool:
    """A clean run of a plain field configuration: what the per-scene, noise-study and cost
    tables describe (a named variant such as sde-ou would share a row with plain sde there)."""
    return not entry.perturb and entry.label == Variant("", entry.field, entry.lambda_).label


def perturbations(collection: Collection) -> list[str]:
    return list(dict.fromkeys(r.perturb for r in collection.experiment.runs if r.perturb))


def _runs_at(collection: Collection, perturb: str, strength: float) -> list[RunRecord]:
    if strength == 0:
        return [r for r in collection.finished if not r.entry.perturb]
    return [r for r in collection.finished if r.entry.perturb == perturb and r.entry.strength == strength]


def strengths(collection: Collection, perturb: str) -> list[float]:
    return sorted({0.0} | {r.strength for r in collection.experiment.runs if r.perturb == perturb})


def variants(collection: Collection) -> list[str]:
    return list(dict.fromkeys(r.label for r in collection.experiment.runs))


def psnr_curve(collection: Collection, perturb: str, variant: str, evaluation: str):
    """(strength, mean, std over seeds or None) per strength where every scene of a seed finished.

    A seed's value is its mean PSNR over the experiment's scenes, so every point averages the
    same scenes."""
    scenes = {(r.dataset, r.scene) for r in collection.experiment.runs}
    points = []
    for strength in strengths(collection, perturb):
        by_seed: dict[int, dict] = defaultdict(dict)
        for run in _runs_at(collection, perturb, strength):
            if run.entry.label == variant:
                by_seed[run.entry.seed][(run.entry.dataset, run.entry.scene)] = run.evaluation(evaluation)["psnr"]
        seeds = [np.mean(list(values.values())) for values in by_seed.values() if set(values) == scenes]
        if seeds:
            std = float(np.std(seeds, ddof=1)) if len(seeds) > 1 else None
            points.append((strength, float(np.mean(seeds)), std))
    return points


def tie_floor(collection: Collection) -> tuple[float, str]:
    """(TIE_SIGMAS x sigma, where sigma comes from): the interval must lie beyond +-floor for a verdict.

    sigma is the run-to-run PSNR spread of the deterministic baseline, as the paper's own sigma is
    (its calibration retrains the lambda-0 model, the CfC): the sample variance of the final PSNR
    over the seeds, pooled over every baseline cell (dataset, scene, perturbation, strength) with at
    least two seeds; with one seed per cell, the paper's sigma."""
    cells: dict[tuple, list[float]] = defaultdict(list)
    for run in collection.finished:
        e = run.entry
        if e.label == BASELINE:
            cells[(e.dataset, e.scene, e.perturb, e.strength)].append(run.evaluation("final")["psnr"])
    sigma, count, runs = pooled_sigma(list(cells.values()))
    if sigma is None:
        sigma, source = paper_sigma()
        return TIE_SIGMAS * sigma, f"sigma = {sigma:.3f} dB: one seed per {BASELINE} cell here, so {source}"
    measured = f"the {BASELINE}'s seed-to-seed PSNR spread, pooled over {count} cells of {runs} runs, measured here"
    return TIE_SIGMAS * sigma, f"sigma = {sigma:.3f} dB: {measured}"


Cluster = tuple[str, str, int]
"""(dataset, scene, seed): the runs of one cluster."""


def paired_clusters(collection: Collection, perturb: str) -> dict[tuple[str, float], dict[Cluster, np.ndarray]]:
    """(sde variant, strength) -> cluster -> PSNR of the variant minus the CfC per test view, the
    runs paired by scene, seed and strength under one perturbation (strength 0: the clean runs)."""
    out: dict[tuple[str, float], dict[Cluster, np.ndarray]] = defaultdict(dict)
    for strength in strengths(collection, perturb):
        runs = _runs_at(collection, perturb, strength)
        baseline = {
            (r.entry.dataset, r.entry.scene, r.entry.seed): r.per_view
            for r in runs
            if r.entry.label == BASELINE and r.per_view is not None
        }
        for run in runs:
            key = (run.entry.dataset, run.entry.scene, run.entry.seed)
            if run.entry.field == "sde" and run.per_view is not None and key in baseline:
                out[(run.entry.label, strength)][key] = per_view_differences(run.per_view, baseline[key])
    return out


def compare(collection: Collection, perturb: str, floor: float = 0.0) -> list[Comparison]:
    """Each sde variant minus the CfC at each strength, paired by scene, seed and test view; a
    difference is called only where its interval lies beyond +-`floor` dB."""
    return [
        Comparison(variant, strength, paired_difference(list(clusters.values()), floor))
        for (variant, strength), clusters in paired_clusters(collection, perturb).items()
        if any(len(d) for d in clusters.values())
    ]


def verdict_sentence(perturb: str, comparisons: list[Comparison]) -> str:
    """Where noise helps, hurts and ties under one perturbation, in words; comparisons on fewer than
    MIN_CLUSTERS clusters are counted as too few runs to call, never as ties."""
    subject = perturb.replace("_", " ")
    if not comparisons:
        return f"{subject}: no sde variant has a finished CfC run to be compared with."
    called = [c for c in comparisons if c.difference.verdict != TOO_FEW]
    too_few = len(comparisons) - len(called)
    if not called:
        counts = sorted({c.difference.clusters for c in comparisons})
        listed = " or ".join(map(str, counts))
        return (
            f"{subject}: {TOO_FEW}: every comparison rests on {listed} scene-seed cluster"
            f"{'s' if counts != [1] else ''}, fewer than the {MIN_CLUSTERS} a verdict needs."
        )

    def listed(verdict: str) -> list[str]:
        return [
            f"{c.variant} at {c.strength:g} ({c.difference.mean:+.2f} dB)"
            for c in called
            if c.difference.verdict == verdict
        ]

    helps, hurts = listed("helps"), listed("hurts")
    ties = sum(c.difference.verdict == "tie" for c in called)
    parts = [f"noise helps: {', '.join(helps)}" if helps else "noise helps nowhere"]
    parts.append(f"it hurts: {', '.join(hurts)}" if hurts else "it hurts nowhere")
    parts.append(f"{ties} of {len(called)} comparisons are ties (the interval reaches within {TIE_SIGMAS:g} sigma "
                 "of 0)")  # fmt: skip
    if too_few:
        parts.append(f"{too_few} more rest on fewer than {MIN_CLUSTERS} scene-seed clusters: {TOO_FEW}")
    return f"{subject}: " + "; ".join(parts) + "."


def strength_plot(path: Path, perturb: str, curves: dict[str, list[tuple[float, float, float | None]]]) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    for variant, points in curves.items():
        xs, means, stds = zip(*points)
        ax.errorbar(xs, means, yerr=[s or 0.0 for s in stds], marker="o", capsize=3, label=variant)
    ax.set_xlabel(PERTURBATION_TEXT.get(perturb, perturb))
    ax.set_ylabel("test PSNR (dB)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return save_plot(fig, path)


def stress_section(collection: Collection, evaluation: str, out_dir: Path, md: list[str]) -> None:
    floor, floor_source = tie_floor(collection)
    md += [
        "## Stress tests: does the noise help?",
        "",
        f"Each sde variant minus the deterministic CfC ({BASELINE}), paired on the same scene, seed and "
        "perturbation and matched by test view (final evaluation, per_view.json). A scene-seed pair of runs is one "
        "cluster (its test views share the runs' training, so they are not independent) and counts by its mean "
        f"difference. Interval: {CONFIDENCE:.0%} Student t-interval on the cluster means (n - 1 degrees of "
        f"freedom). Verdict: under {MIN_CLUSTERS} clusters, **{TOO_FEW}** (no distribution-free test can call a "
        f"difference on fewer: a sign test's smallest p-value is {smallest_sign_flip_p(MIN_CLUSTERS - 1):.4g} on "
        f"{MIN_CLUSTERS - 1}); from {MIN_CLUSTERS} on, **helps** / **hurts** where the whole interval lies above / "
        f"below the ties rule's {TIE_SIGMAS:g} sigma = {floor:.3f} dB ({floor_source}; the paper reads differences "
        "under 2 sigma as ties, and a change of machine alone moves a run by about a seed's spread), else tie. "
        "Strength 0 is the clean run every perturbation shares.",
        "",
    ]
    for perturb in perturbations(collection):
        md += [f"### {PERTURBATION_TEXT.get(perturb, perturb)}", ""]
        curves = {v: psnr_curve(collection, perturb, v, evaluation) for v in variants(collection)}
        curves = {v: points for v, points in curves.items() if points}
        if curves:
            path = strength_plot(out_dir / f"stress_{perturb}.png", perturb, curves)
            md += [
                f"![test PSNR against {perturb}]({path.name}) Test PSNR ({evaluation} evaluation, mean over the "
                "scenes) against strength; error bars: std over seeds (none where one seed finished).",
                "",
            ]
        comparisons = compare(collection, perturb, floor)
        table = PlainTable(["variant", "strength", "minus CfC (dB)", f"{CONFIDENCE:.0%} interval",
                            "clusters (views)", "verdict"])  # fmt: skip
        for c in comparisons:
            d = c.difference
            verdict = f"**{d.verdict}**" if d.verdict in ("helps", "hurts") else d.verdict
            table.add(c.variant, c.variant, [f"{c.strength:g}", f"{d.mean:+.3f}", d.interval_text(),
                                             f"{d.clusters} ({d.pairs} views)", verdict])  # fmt: skip
        if comparisons:
            md += [table.to_markdown()]
        md += [verdict_sentence(perturb, comparisons), ""]
