"""The real-clip benchmark's controlled comparisons, from the runs scripts/real_clips.sh made:

    python docs/experiments/real_clips_compare.py DIR

Each run's margin over the static model of its seed on the moving subject (PSNR inside the boxes,
test views aligned: the run's eval.json), and the paired differences of those margins between two
specs over every (clip, seed) both hold, with the project's verdict rule
(liquidgs.experiments.report.significance: Student's t over the pairs, a verdict from 6 pairs on):

- the motion evidence against none: experiment-motion (the flow loss at 0.02, the split) and
  experiment-defaults (the evidence as the defaults give it) against experiment (real-clips.yml);
- everything against each piece off: the flow loss (experiment-motion-without-flow, whose static
  model is experiment's: the specs' own comments say which) and the static/dynamic split
  (experiment-motion-without-split, whose static model is experiment-motion's);
- the tracks: experiment-motion-with-tracks against experiment-motion;
- each piece alone against neither: an ablation spec against experiment;
- the schedule: experiment-defaults-3000 (the quick look's schedule doubled) against experiment-defaults,
  and at that schedule the motion evidence against none (experiment-defaults-3000 against experiment-3000).

Before them, each spec's own subject margins over its static model, field by field (the benchmark's
bars are on these: every field +3.0 dB, the best +4.0).

Then the rendered motion's end-point error inside the scenes' own motion masks (eval-auto.json), and
the still clips (no boxes: each field's aligned PSNR over the static model's, on the whole views).
A spec folder that is missing is left out of the comparisons that need it. An evaluation whose run
has trained on since, or was evaluated before it finished, is refused in one line naming the file.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from liquidgs.errors import LiquidGSError
from liquidgs.experiments.report.significance import call, t_interval
from liquidgs.train.run_folder.provenance import check_source

BOXES = Path(__file__).with_name("real-clips-boxes.json")
STATIC = "static"
FIELDS = ("mlp", "cfc", "hexplane")
OWN_STATIC = {"experiment-motion-without-flow": "experiment", "experiment-motion-without-split": "experiment-motion"}
"""The ablation specs train no static model of their own; their margins are over these specs' (the
static model has nothing to split, and without the flow loss it is real-clips.yml's)."""
COMPARISONS = (
    ("the motion evidence at the defaults against none", "experiment-defaults", "experiment"),
    ("the motion evidence against none", "experiment-motion", "experiment"),
    ("with the flow loss against without it", "experiment-motion", "experiment-motion-without-flow"),
    ("with the split against without it", "experiment-motion", "experiment-motion-without-split"),
    ("with the tracks against without them", "experiment-motion-with-tracks", "experiment-motion"),
    ("the split alone against neither piece", "experiment-motion-without-flow", "experiment"),
    ("the flow loss alone against neither piece", "experiment-motion-without-split", "experiment"),
    ("3,000 iterations against the quick look's 1,500", "experiment-defaults-3000", "experiment-defaults"),
    ("the motion evidence at the defaults against none, at 3,000", "experiment-defaults-3000", "experiment-3000"),
)
EPE_COMPARISONS = (
    ("the motion evidence at the defaults against none", "experiment-defaults", "experiment"),
    ("the motion evidence at the defaults against none, at 3,000", "experiment-defaults-3000", "experiment-3000"),
    ("the flow loss on against off", "experiment-motion", "experiment-motion-without-flow"),
    ("the motion evidence against none", "experiment-motion", "experiment"),
    ("the flow loss alone against neither piece", "experiment-motion-without-split", "experiment"),
)

Runs = dict[tuple[str, str, int], dict]


def read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise SystemExit(f"{path}: cannot be read as JSON ({err})") from None


def read_eval(run: Path, name: str, iterations: int) -> dict:
    """A run's evaluation file, checked against the run as it is now: of its final checkpoint, at
    the iteration the run finished at."""
    path = run / name
    scores = read_json(path)
    try:
        check_source(path, scores.get("source"), folder=run, again=f"evaluate it again (liquidgs eval --run {run})")
    except LiquidGSError as err:
        raise SystemExit(str(err)) from None
    if scores.get("iteration") != iterations or scores.get("finished") is not True:
        raise SystemExit(f"{path}: evaluates iteration {scores.get('iteration')}, not the finished run's {iterations}")
    return scores


def read_runs(folder: Path) -> Runs:
    """{(clip, field, seed): scores} of every finished run under an experiment folder
    (DATASET/CLIP/FIELD/HASH/results.json)."""
    runs: Runs = {}
    for results_file in sorted(folder.glob("*/*/*/*/results.json")):
        run = results_file.parent
        results = read_json(results_file)
        if not isinstance((results.get("final_aligned") or {}).get("psnr"), float) or "seed" not in results:
            raise SystemExit(f"{results_file}: no seed or final_aligned.psnr (the real-clip specs score aligned)")
        if type(results.get("iterations")) is not int:
            raise SystemExit(f"{results_file}: no iterations")
        clip, field = run.parent.parent.name, run.parent.name
        scores = {"aligned": results["final_aligned"]["psnr"]}
        if (run / "eval.json").is_file():
            inside = (read_eval(run, "eval.json", results["iterations"]).get("masked_aligned") or {}).get("inside")
            scores["subject"] = (inside or {}).get("psnr")
        if (run / "eval-auto.json").is_file():
            flow_error = read_eval(run, "eval-auto.json", results["iterations"]).get("flow_error") or {}
            scores["epe"] = flow_error.get("inside_masks_px")
        key = (clip, field, int(results["seed"]))
        if key in runs:
            raise SystemExit(f"{run}: a second finished run of {key} in {folder}")
        runs[key] = scores
    return runs


def margin(specs: dict[str, Runs], spec: str, clip: str, field: str, seed: int, score: str) -> float | None:
    """The run's `score` minus the static model's of the same clip and seed."""
    static_spec = OWN_STATIC.get(spec, spec)
    run = specs.get(spec, {}).get((clip, field, seed), {}).get(score)
    static = specs.get(static_spec, {}).get((clip, STATIC, seed), {}).get(score)
    return None if run is None or static is None else run - static


def interval_line(differences: list[float]) -> str:
    mean, low, high = t_interval(differences)
    interval = "-" if math.isnan(low) else f"{low:+.2f} to {high:+.2f}"
    return f"{mean:+.2f} | {interval} | {call(mean, low, high, len(differences))}"


def margin_rows(specs: dict[str, Runs]) -> list[str]:
    """Markdown rows, one per spec and field: pairs, mean subject margin over the spec's static model,
    95% interval, verdict, and each pair's margin."""
    rows = []
    for spec in sorted(specs):
        for field in FIELDS:
            values, shown = [], []
            for clip, seed in sorted((c, s) for c, f, s in specs[spec] if f == field):
                value = margin(specs, spec, clip, field, seed, "subject")
                if value is not None:
                    values.append(value)
                    shown.append(f"{clip} s{seed} {value:+.2f}")
            if values:
                rows.append(f"| {spec} | {field} | {len(values)} | {interval_line(values)} | {'; '.join(shown)} |")
    return rows


def compare(specs: dict[str, Runs], a: str, b: str) -> list[str]:
    """Markdown rows, one per field: pairs, mean difference of the subject margins, 95% interval,
    verdict, and each pair's margins b -> a."""
    rows = []
    for field in FIELDS:
        pairs = sorted({(c, s) for (c, f, s) in specs.get(a, {}) if f == field})
        values, shown = [], []
        for clip, seed in pairs:
            with_a, with_b = (margin(specs, spec, clip, field, seed, "subject") for spec in (a, b))
            if with_a is None or with_b is None:
                continue
            values.append(with_a - with_b)
            shown.append(f"{clip} s{seed} {with_b:+.2f} -> {with_a:+.2f}")
        if values:
            rows.append(f"| {field} | {len(values)} | {interval_line(values)} | {'; '.join(shown)} |")
    return rows


def epe_rows(specs: dict[str, Runs], a: str, b: str) -> list[str]:
    rows = []
    for field in (STATIC, *FIELDS):
        changes, shown = [], []
        for (clip, f, seed), scores in sorted(specs.get(a, {}).items()):
            before = specs.get(OWN_STATIC.get(b, b) if field == STATIC else b, {}).get((clip, f, seed), {}).get("epe")
            if f != field or scores.get("epe") is None or before is None or before <= 0:
                continue
            changes.append(100.0 * (scores["epe"] - before) / before)
            shown.append(f"{clip} s{seed} {before:.2f} -> {scores['epe']:.2f}")
        if changes:
            rows.append(f"| {field} | {len(changes)} | {sum(changes) / len(changes):+.0f}% | "
                        f"{min(changes):+.0f}% to {max(changes):+.0f}% | {'; '.join(shown)} |")  # fmt: skip
    return rows


def still_rows(specs: dict[str, Runs]) -> list[str]:
    """The clips with no subject boxes (nothing moves in them)."""
    moving = set(json.loads(BOXES.read_text())["clips"])
    rows = []
    for spec, runs in sorted(specs.items()):
        for clip, field, seed in sorted(runs):
            if field == STATIC or clip in moving:
                continue
            value = margin(specs, spec, clip, field, seed, "aligned")
            if value is not None:
                rows.append(f"| {spec} | {clip} | {seed} | {field} | {value:+.2f} |")
    return rows


def section(title: str, columns: list[str], rows: list[str]) -> list[str]:
    """A markdown table under a heading; nothing without rows."""
    if not rows:
        return []
    return [f"## {title}", "", f"| {' | '.join(columns)} |", "|" + "---|" * len(columns), *rows, ""]


def report(root: Path) -> str:
    specs = {folder.name: read_runs(folder) for folder in sorted(root.glob("experiment*")) if folder.is_dir()}
    if not specs:
        raise SystemExit(f"{root}: no experiment* folder (scripts/real_clips.sh writes them)")
    columns = ["spec", "field", "pairs", "mean (dB)", "95% t-interval", "verdict", "each pair"]
    lines = section("Subject margin over the static model, each spec", columns, margin_rows(specs))
    for title, a, b in COMPARISONS:
        rows = compare(specs, a, b) if a in specs and b in specs else []
        columns = ["field", "pairs", "mean (dB)", "95% t-interval", "verdict", "each pair, b -> a"]
        lines += section(f"Subject margin, {title} ({a} - {b})", columns, rows)
    for title, a, b in EPE_COMPARISONS:
        rows = epe_rows(specs, a, b) if a in specs and b in specs else []
        columns = ["field", "runs", "mean change", "range", "each run (px)"]
        lines += section(f"End-point error in the motion masks, {title} ({b} -> {a})", columns, rows)
    columns = ["spec", "clip", "seed", "field", "margin"]
    lines += section("Still clips: aligned PSNR over the static model (dB)", columns, still_rows(specs))
    return "\n".join(lines) or "nothing to compare yet: no run has its static model's scores beside it"


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: python docs/experiments/real_clips_compare.py DIR")
    print(report(Path(sys.argv[1])))
