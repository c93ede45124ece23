"""The margin section: how far each deformation field is above the static model, and where.

For every scene with static runs: each field's PSNR minus the static model's, paired by seed
(same data, same initial points), over the whole test images and over two regions of them:
- moving: the pixels whose ground truth changes between neighbouring frames from the same camera
  (data.regions.moving_region). Exact, but only the built-in synthetic scenes have it.
- foreground: the pixels the object covers (alpha > 0; data.regions.foreground_region). Any RGBA
  scene has it; it does not depend on any model, but it includes the parts that do not move.
Whole-image PSNR is results.json's final evaluation (mean of per-view PSNRs); region PSNRs pool
the squared errors over the region (eval.regions), from 8-bit renders of the final checkpoint.
Cells are mean +- sample std over the seeds both runs finished.
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
from liquidgs.experiments.report.references import MEAN
from liquidgs.experiments.report.stress import is_paper_run
from liquidgs.experiments.report.tables import PlainTable
from liquidgs.experiments.spec import SyntheticScene
from liquidgs.fields.registry import field_label, field_names
from liquidgs.media import to_uint8
from liquidgs.train.run import load_run, load_run_dataset

BASELINE = "static"
REGIONS = ("whole", "foreground", "moving")
REGION_TEXT = {"whole": "whole image", "foreground": "foreground (alpha > 0)", "moving": "moving pixels"}
VERDICTS = ("gain", "unclear", "loss", "one seed only")
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
                shares[key] = {region: regions[data_key].share(region) for region in REGIONS}
            except LiquidGSError as err:
                regions[data_key] = err
        whole = run.evaluation("final")["psnr"]
        scores, rendered_whole = dict.fromkeys(REGIONS[1:]), whole
        try:
            if isinstance(regions[data_key], LiquidGSError):
                raise regions[data_key]
            scores, rendered_whole = run_region_psnrs(run, regions[data_key], device)
        except LiquidGSError as err:
            notes.append(f"{run.entry.name}: could not be re-rendered ({err}); its region scores are left out")
        if abs(rendered_whole - whole) > CHECK_TOLERANCE_DB:
            notes.append(f"{run.entry.name}: re-rendered whole-image PSNR {rendered_whole:.3f} dB, "
                         f"results.json {whole:.3f} dB")  # fmt: skip
        out.append(RunScores(*key, run.entry.field, run.entry.seed, {"whole": whole, **scores}))
    return out, shares, notes


@dataclass(frozen=True)
class SceneMargins:
    static: dict[str, Stat]
    """region -> the static model's PSNR over seeds."""
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
        static_stats = {}
        for region in REGIONS:
            values = [r.psnr[region] for r in static.values() if r.psnr.get(region) is not None]
            if values:
                static_stats[region] = stat(values)
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
        out[key] = SceneMargins(static_stats, margins, per_seed)
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


def verdict(margin: Stat) -> str:
    """'gain', 'loss' or 'unclear': the mean against TIE_SIGMAS x its seed spread ('one seed only'
    when there is no spread to hold it against)."""
    if margin.std is None:
        return "one seed only"
    if abs(margin.mean) <= TIE_SIGMAS * margin.std:
        return "unclear"
    return "gain" if margin.mean > 0 else "loss"


def margin_sentences(
    dataset: str, by_scene: dict[str, SceneMargins], fields: list[str], regions: list[str]
) -> list[str]:
    """Per field and region: the range of the scene margins and which scenes gain, are unclear or lose."""
    lines = []
    for field in fields:
        parts = []
        for region in regions:
            cells = {scene: m.margins[(field, region)] for scene, m in by_scene.items() if (field, region) in m.margins}
            if not cells:
                continue
            low = min(cells, key=lambda s: cells[s].mean)
            high = max(cells, key=lambda s: cells[s].mean)
            counts = defaultdict(list)
            for scene, value in cells.items():
                counts[verdict(value)].append(scene)
            tally = ", ".join(f"{kind} on {', '.join(counts[kind])}" for kind in VERDICTS if counts[kind])
            span = f"{cells[low].mean:+.2f} ({low}) to {cells[high].mean:+.2f} dB ({high})"
            if len(cells) == 1:
                span = f"{cells[low].mean:+.2f} dB"
            parts.append(f"{REGION_TEXT[region]} {span}: {tally}")
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
        "the parts that do not move). Cells: mean ± sample std over seeds. A margin is a gain (or a loss) when "
        f"its mean is more than {TIE_SIGMAS:g} std from 0, else unclear.",
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
        header = ["scene", *(f"{r} share" for r in regions if r != "whole")]
        header += [f"static {r} PSNR" for r in regions]
        header += [f"{field_label(f)} - static, {r}" for f in fields for r in regions]
        table = PlainTable(header)
        for scene, m in by_scene.items():
            known = shares.get((dataset, scene), {})
            share = [f"{100 * known[r]:.1f}%" if known.get(r) is not None else "-" for r in regions if r != "whole"]
            values = [cell(m.static.get(r)) for r in regions]
            values += [cell(m.margins.get((f, r)), signed=True) for f in fields for r in regions]
            table.add(scene, scene, share + values)
        if len(by_scene) > 1 and len(by_scene) == len(collection.scenes(dataset)):
            every = list(by_scene.values())
            values = [cell(dataset_static(every, r)) for r in regions]
            values += [cell(dataset_margin(every, f, r), signed=True) for f in fields for r in regions]
            table.add(MEAN, MEAN, ["-" for r in regions if r != "whole"] + values)
        caption = (f"{dataset}: margin of each field over the static model (dB), final evaluation; mean ± std over "
                   "seeds; Mean row: mean of the scene means, spread over the per-seed means.")  # fmt: skip
        md += [f"**{caption}**", "", table.to_markdown()]
        md += [*margin_sentences(dataset, by_scene, fields, regions), ""]
        latex = table.to_latex(caption.replace("_", "\\_"), f"tab:{dataset}-margins")
        tex.append(latex.replace("±", "$\\pm$"))
    if notes:
        md += ["Runs whose region scores are missing, or whose re-rendered checkpoint does not reproduce its "
               f"results.json whole-image PSNR within {CHECK_TOLERANCE_DB} dB:"]  # fmt: skip
        md += [*(f"- {n}" for n in notes), ""]
    elif scores:
        md += ["Every re-rendered checkpoint reproduces its results.json whole-image PSNR within "
               f"{CHECK_TOLERANCE_DB} dB, so the region scores describe the runs the tables describe.", ""]  # fmt: skip
