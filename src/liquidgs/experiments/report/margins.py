"""The margin section: how far each deformation field is above the static model, and where.

For every scene with static runs: each field's PSNR minus the static model's, paired by seed
(same data, same initial points), over the whole test images and over two regions of them:
- moving: the pixels whose ground truth changes between neighbouring frames from the same camera
  (data.regions.moving_region). Exact, but only the built-in synthetic scenes have it.
- foreground: the pixels the object covers (alpha > 0; data.regions.foreground_region). Any RGBA
  scene has it; it does not depend on any model, but it includes the parts that do not move.
Whole-image PSNR is results.json's final evaluation (mean of per-view PSNRs); region PSNRs pool
the squared errors over the region (eval.regions), from 8-bit renders of the final checkpoint.
Runs that refine cameras add two scores they recorded, each its own column, never mixed with the
above: the whole image with the test cameras aligned (results.json's final_aligned) and the moving
subject (`liquidgs eval --mask`'s inside score, test cameras aligned: eval.json's masked_aligned).
Cells are mean +- sample std over the seeds both runs finished. A margin is called a gain or a loss
by the rule of every verdict in the reports (significance.py): the clusters are the (scene, seed)
pairs, a call needs MIN_CLUSTERS of them and their t-interval wholly beyond the ties rule's
2 sigma, sigma the static model's run-to-run spread (the baseline's, as in the paper's rule).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from liquidgs.data.regions import foreground_region, frame_step, moving_region
from liquidgs.errors import LiquidGSError
from liquidgs.eval.regions import region_psnr, region_share
from liquidgs.experiments.report.aggregate import TIE_SIGMAS, Stat, stat
from liquidgs.experiments.report.collect import Collection, RunRecord
from liquidgs.experiments.report.references import MEAN, paper_sigma
from liquidgs.experiments.report.significance import (
    CONFIDENCE,
    MIN_CLUSTERS,
    TOO_FEW,
    PairedDifference,
    cluster_difference,
    pooled_sigma,
)
from liquidgs.experiments.report.stress import is_paper_run
from liquidgs.experiments.report.tables import PlainTable
from liquidgs.experiments.spec import SyntheticScene
from liquidgs.fields.registry import field_label, field_names
from liquidgs.media import to_uint8
from liquidgs.train.dataset import load_run_dataset
from liquidgs.train.run import load_run

BASELINE = "static"
RENDERED = ("foreground", "moving")
"""Regions scored here from renders of the final checkpoint."""
RECORDED = ("aligned", "subject")
"""Scores the run recorded with its test cameras aligned (RunRecord.second_scores)."""
REGIONS = ("whole", *RENDERED, *RECORDED)
SHARED = ("foreground", "moving", "subject")
"""Regions that cover part of the image: the table gives their share of the pixels."""
REGION_TEXT = {"whole": "whole image", "foreground": "foreground (alpha > 0)", "moving": "moving pixels",
               "aligned": "whole image with test cameras aligned",
               "subject": "inside the masks (eval --mask) with test cameras aligned"}  # fmt: skip
VERDICT_WORDS = {"helps": "gain", "hurts": "loss", "tie": "tie", TOO_FEW: TOO_FEW}
"""significance's verdicts of a field minus static, in the words of this section."""
CHECK_TOLERANCE_DB = 0.01
"""Whole-image PSNR of the re-rendered checkpoint against results.json: more apart is reported."""


@dataclass(frozen=True)
class RunScores:
    dataset: str
    scene: str
    field: str
    seed: int
    psnr: dict[str, float | None]
    """region -> PSNR (dB); None where the scene has no such region."""


@dataclass(frozen=True)
class SceneRegions:
    """A scene's test views with their region masks (one list per region, None where unavailable)."""

    frames: list
    truths: list[np.ndarray]
    background: torch.Tensor
    masks: dict[str, list[np.ndarray] | None]

    def share(self, region: str) -> float | None:
        masks = self.masks.get(region)
        return None if masks is None else region_share(masks)


def synthetic_names(collection: Collection) -> dict[tuple[str, str], str]:
    """(dataset, scene label) -> built-in scene name, for the synthetic:NAME:SIZE scenes of the spec."""
    names = {}
    for grid in collection.experiment.spec.get("grids", []):
        for scene in grid.get("scenes", []):
            parsed = SyntheticScene.parse(scene, "spec")
            if parsed is not None:
                names[(grid.get("dataset", ""), parsed.label)] = parsed.name
    return names


def scene_regions(run: RunRecord, synthetic: str | None) -> SceneRegions:
    dataset = load_run_dataset(run.config)
    frames = sorted(dataset.test, key=lambda f: f.time)
    masks: dict[str, list[np.ndarray] | None] = {
        "whole": [np.ones((f.camera.height, f.camera.width), dtype=bool) for f in frames],
        "foreground": [foreground_region(f) for f in frames],
        "moving": None,
    }
    if synthetic is not None:
        step = frame_step(frame for split in dataset.splits.values() for frame in split)
        masks["moving"] = [moving_region(synthetic, f, step) for f in frames]
    background = torch.tensor(dataset.background, dtype=torch.float32)
    return SceneRegions(frames, [f.image_uint8() for f in frames], background, masks)


def run_region_psnrs(run: RunRecord, regions: SceneRegions, device: str) -> tuple[dict[str, float | None], float]:
    """Region -> PSNR of the run's final checkpoint, and its whole-image PSNR (mean over views) as
    rendered here, to hold against results.json."""
    trained = load_run(run.folder, device)
    renders = [to_uint8(trained.render(f.camera, f.time, regions.background).rgb) for f in regions.frames]
    scores = {
        region: None if masks is None else region_psnr(renders, regions.truths, masks)
        for region, masks in regions.masks.items()
        if region != "whole"
    }
    per_view = [region_psnr([r], [t], [m]) for r, t, m in zip(renders, regions.truths, regions.masks["whole"])]
    return scores, float(np.mean(per_view))


def collect_scores(collection: Collection, device: str) -> tuple[list[RunScores], dict, list[str]]:
    """Every clean plain run of a scene that has static runs, scored on every region; the regions'
    shares per (dataset, scene); and notes on runs that could not be re-rendered or whose re-render
    disagrees with results.json."""
    names = synthetic_names(collection)
    runs = [r for r in collection.finished if is_paper_run(r.entry)]
    with_static = {(r.entry.dataset, r.entry.scene) for r in runs if r.entry.field == BASELINE}
    regions: dict[tuple, SceneRegions | LiquidGSError] = {}
    shares: dict[tuple[str, str], dict[str, float | None]] = {}
    out, notes = [], []
    for run in runs:
        key = (run.entry.dataset, run.entry.scene)
        if key not in with_static:
            continue
        data_key = (*key, repr(run.config.data))
        if data_key not in regions:
            try:
                regions[data_key] = scene_regions(run, names.get(key))
                shares.setdefault(key, {}).update({region: regions[data_key].share(region) for region in RENDERED})
            except LiquidGSError as err:
                regions[data_key] = err
        whole = run.evaluation("final")["psnr"]
        scores, rendered_whole = dict.fromkeys(RENDERED), whole
        try:
            if isinstance(regions[data_key], LiquidGSError):
                raise regions[data_key]
            scores, rendered_whole = run_region_psnrs(run, regions[data_key], device)
        except LiquidGSError as err:
            notes.append(f"{run.entry.name}: could not be re-rendered ({err}); its region scores are left out")
        if abs(rendered_whole - whole) > CHECK_TOLERANCE_DB:
            notes.append(f"{run.entry.name}: re-rendered whole-image PSNR {rendered_whole:.3f} dB, "
                         f"results.json {whole:.3f} dB")  # fmt: skip
        aligned, _, masked_aligned = run.second_scores()
        recorded = {"aligned": aligned["psnr"] if aligned else None,
                    "subject": masked_aligned["inside"]["psnr"] if masked_aligned else None}  # fmt: skip
        if masked_aligned:
            shares.setdefault(key, {})["subject"] = masked_aligned["inside"]["share"]
            if recorded["subject"] is None:
                notes.append(f"{run.entry.name}: its masks hold no subject pixel in any test view (eval.json's "
                             "masked_aligned.inside.psnr is null); its subject score is n/a")  # fmt: skip
        out.append(RunScores(*key, run.entry.field, run.entry.seed, {"whole": whole, **scores, **recorded}))
    return out, shares, notes


@dataclass(frozen=True)
class SceneMargins:
    static: dict[str, Stat]
    """region -> the static model's PSNR over seeds."""
    static_runs: dict[str, list[float]]
    """region -> the static model's PSNR per seed (its run-to-run spread sets the ties floor)."""
    margins: dict[tuple[str, str], Stat]
    """(field, region) -> field minus static over the seeds both finished."""
    per_seed: dict[tuple[str, str], dict[int, float]]


def scene_margins(scores: list[RunScores]) -> dict[tuple[str, str], SceneMargins]:
    """(dataset, scene) -> the static scores and every field's margin over them, paired by seed."""
    by_scene: dict[tuple[str, str], dict[str, dict[int, RunScores]]] = defaultdict(lambda: defaultdict(dict))
    for s in scores:
        by_scene[(s.dataset, s.scene)][s.field][s.seed] = s
    out = {}
    for key, fields in by_scene.items():
        static = fields.get(BASELINE, {})
        static_stats, static_runs = {}, {}
        for region in REGIONS:
            values = [r.psnr[region] for r in static.values() if r.psnr.get(region) is not None]
            if values:
                static_stats[region], static_runs[region] = stat(values), values
        margins, per_seed = {}, {}
        for field, runs in fields.items():
            if field == BASELINE:
                continue
            for region in REGIONS:
                diffs = {
                    seed: run.psnr[region] - static[seed].psnr[region]
                    for seed, run in sorted(runs.items())
                    if seed in static and run.psnr.get(region) is not None and static[seed].psnr.get(region) is not None
                }
                if diffs:
                    margins[(field, region)] = stat(list(diffs.values()))
                    per_seed[(field, region)] = diffs
        out[key] = SceneMargins(static_stats, static_runs, margins, per_seed)
    return out


def dataset_margin(scenes: list[SceneMargins], field: str, region: str) -> Stat | None:
    """Mean of the per-scene mean margins (every scene needed); spread over the per-seed means of
    the seeds every scene finished, as the dataset means of the score tables."""
    cells = [s.per_seed.get((field, region)) for s in scenes]
    if not cells or not all(cells):
        return None
    mean = math.fsum(math.fsum(c.values()) / len(c) for c in cells) / len(cells)
    complete = sorted(set.intersection(*(set(c) for c in cells)))
    per_seed = stat([math.fsum(c[s] for c in cells) / len(cells) for s in complete])
    return Stat(mean, per_seed.std if per_seed else None, len(complete))


def dataset_static(scenes: list[SceneMargins], region: str) -> Stat | None:
    cells = [s.static.get(region) for s in scenes]
    if not cells or not all(cells):
        return None
    return Stat(math.fsum(c.mean for c in cells) / len(cells), None, min(c.n for c in cells))


def cell(value: Stat | None, signed: bool = False) -> str:
    if value is None:
        return "-"
    text = f"{value.mean:+.2f}" if signed else f"{value.mean:.2f}"
    return text + (f" ± {value.std:.2f}" if value.std is not None else "") + (f" (n={value.n})" if value.n < 2 else "")


def margin_floor(scenes: list[SceneMargins], region: str) -> tuple[float, str]:
    """(TIE_SIGMAS x sigma, where sigma comes from): sigma is the static model's PSNR spread over
    seeds, pooled over the scenes; with one seed per scene, the paper's sigma."""
    sigma, cells, runs = pooled_sigma([s.static_runs.get(region, []) for s in scenes])
    if sigma is None:
        sigma, source = paper_sigma()
        return TIE_SIGMAS * sigma, f"one static run per scene, so {source}"
    return TIE_SIGMAS * sigma, f"the static model's spread over seeds, pooled over {cells} scenes ({runs} runs)"


def margin_difference(scenes: list[SceneMargins], field: str, region: str, floor: float) -> PairedDifference | None:
    """The field's margin with its t-interval over the (scene, seed) clusters of `scenes`."""
    margins = [m for s in scenes for _, m in sorted(s.per_seed.get((field, region), {}).items())]
    return cluster_difference(margins, floor) if margins else None


def verdict(difference: PairedDifference) -> str:
    """'gain', 'loss', 'tie' or 'too few runs to call' (significance.call over the clusters)."""
    return VERDICT_WORDS[difference.verdict]


def scenes_scored(by_scene: dict[str, SceneMargins], region: str) -> dict[str, SceneMargins]:
    """The scenes whose static runs have a score on `region` (a clip without masks has no subject
    score): the scenes a dataset's mean and verdict on that region are over."""
    return {scene: m for scene, m in by_scene.items() if region in m.static}


def margin_sentences(
    dataset: str, by_scene: dict[str, SceneMargins], fields: list[str], floors: dict[str, float], complete: bool
) -> list[str]:
    """Per field and region (the regions of `floors`, each with its ties floor, margin_floor): the
    range of the scene margins, each scene's verdict over its seeds and, when every scene of the
    dataset is there, the verdict over all (scene, seed) clusters of the scenes scored on the region."""
    lines = []
    for field in fields:
        parts = []
        for region, floor in floors.items():
            cells = {scene: m.margins[(field, region)] for scene, m in by_scene.items() if (field, region) in m.margins}
            if not cells:
                continue
            low = min(cells, key=lambda s: cells[s].mean)
            high = max(cells, key=lambda s: cells[s].mean)
            counts = defaultdict(list)
            for scene in cells:
                counts[verdict(margin_difference([by_scene[scene]], field, region, floor))].append(scene)
            kinds = [kind for kind in VERDICT_WORDS.values() if kind in counts]
            tally = ", ".join(f"{kind} on {', '.join(counts[kind])}" for kind in kinds)
            if len(kinds) == 1 and len(cells) > 1:
                tally = f"{kinds[0]} on every scene"
            span = f"{cells[low].mean:+.2f} ({low}) to {cells[high].mean:+.2f} dB ({high})"
            if len(cells) == 1:
                span = f"{cells[low].mean:+.2f} dB"
            text = f"{REGION_TEXT[region]} {span}; per scene {tally}"
            scored = scenes_scored(by_scene, region)
            if complete and len(cells) == len(scored) > 1:
                every = margin_difference(list(scored.values()), field, region, floor)
                text += (f"; over all {every.clusters} scene-seed runs {every.mean:+.2f} dB, "
                         f"t-interval {every.interval_text(2)}: {verdict(every)}")  # fmt: skip
            parts.append(text)
        if parts:
            lines.append(f"- {dataset}, {field_label(field)} minus static: " + "; ".join(parts) + ".")
    return lines


def margin_section(collection: Collection, md: list[str], tex: list[str], device: str | None = None,
                   render: Callable = collect_scores) -> None:  # fmt: skip
    """The margins of every field over the static model, per dataset; nothing without static runs."""
    if not any(r.field == BASELINE for r in collection.experiment.runs):
        return
    device = device or ("cuda" if torch.cuda.is_available() else "cpu")
    scores, shares, notes = render(collection, device)
    md += [
        "## Margin over the static model",
        "",
        "Each field's test PSNR minus the static model's, paired by seed, from the **final** evaluation whatever "
        "`--eval` says (region scores need the final checkpoint). Whole image: results.json (mean of per-view "
        "PSNRs). Regions pool the squared errors of their pixels over the test views, from 8-bit renders of the "
        "final checkpoint: **moving** = pixels whose ground truth changes between neighbouring frames from the "
        "same camera (exact; built-in synthetic scenes only, as real captures never see one camera at two "
        "times); **foreground** = pixels with alpha > 0 in the ground truth (model-independent, but it includes "
        "the parts that do not move). Runs that refine cameras add what they recorded with the test cameras "
        "aligned, in columns of their own: **aligned** = the whole image (results.json's final_aligned), "
        "**subject** = inside the per-view masks of `liquidgs eval --run RUN --mask DIR` (eval.json's masked_aligned; "
        "its share: of the test pixels). Cells: mean ± sample std over seeds. A margin is a gain (or a loss) when "
        f"the {CONFIDENCE:.0%} Student t-interval of its mean over the (scene, seed) runs lies wholly above "
        f"(below) the ties rule's {TIE_SIGMAS:g} sigma, sigma the static model's run-to-run PSNR spread; else a "
        f"tie; under {MIN_CLUSTERS} runs it is {TOO_FEW} (the seeds of one scene alone rarely are enough).",
        "",
    ]
    margins = scene_margins(scores)
    for dataset in collection.datasets():
        names = [scene for scene in collection.scenes(dataset) if (dataset, scene) in margins]
        by_scene = {scene: margins[(dataset, scene)] for scene in names}
        if not by_scene:
            continue
        fields = sorted({f for m in by_scene.values() for f, _ in m.margins}, key=field_names().index)
        regions = [r for r in REGIONS if any(r in m.static for m in by_scene.values())]
        header = ["scene", *(f"{r} share" for r in regions if r in SHARED)]
        header += [f"static {r} PSNR" for r in regions]
        header += [f"{field_label(f)} - static, {r}" for f in fields for r in regions]
        table = PlainTable(header)
        for scene, m in by_scene.items():
            known = shares.get((dataset, scene), {})
            share = [f"{100 * known[r]:.1f}%" if known.get(r) is not None else "-" for r in regions if r in SHARED]
            values = [cell(m.static.get(r)) for r in regions]
            values += [cell(m.margins.get((f, r)), signed=True) for f in fields for r in regions]
            table.add(scene, scene, share + values)
        complete = len(by_scene) == len(collection.scenes(dataset))
        if len(by_scene) > 1 and complete:
            every = {r: list(scenes_scored(by_scene, r).values()) for r in regions}
            values = [cell(dataset_static(every[r], r)) for r in regions]
            values += [cell(dataset_margin(every[r], f, r), signed=True) for f in fields for r in regions]
            table.add(MEAN, MEAN, ["-" for r in regions if r in SHARED] + values)
        caption = (f"{dataset}: margin of each field over the static model (dB), final evaluation; mean ± std over "
                   "seeds; Mean row: mean of the scene means, spread over the per-seed means.")  # fmt: skip
        md += [f"**{caption}**", "", table.to_markdown()]
        floors = {region: margin_floor(list(by_scene.values()), region) for region in regions}
        md += [*margin_sentences(dataset, by_scene, fields, {r: f for r, (f, _) in floors.items()}, complete), ""]
        md += ["Ties floor (2 sigma): " + "; ".join(f"{REGION_TEXT[r]} {f:.3f} dB ({why})"
                                                  for r, (f, why) in floors.items()) + ".", ""]  # fmt: skip
        latex = table.to_latex(caption.replace("_", "\\_"), f"tab:{dataset}-margins")
        tex.append(latex.replace("±", "$\\pm$"))
    if notes:
        md += ["Runs whose region scores are missing, or whose re-rendered checkpoint does not reproduce its "
               f"results.json whole-image PSNR within {CHECK_TOLERANCE_DB} dB:"]  # fmt: skip
        md += [*(f"- {n}" for n in notes), ""]
    elif scores:
        md += ["Every re-rendered checkpoint reproduces its results.json whole-image PSNR within "
               f"{CHECK_TOLERANCE_DB} dB, so the region scores describe the runs the tables describe.", ""]  # fmt: skip
