"""`liquidgs demo`: the main job on a built-in default.

Generates the default synthetic scene, trains the static model and the MLP, CfC and SDE-LNN
fields with the tiny preset (as `liquidgs train` processes, --parallel at a time, logs in
OUT/logs), evaluates them and writes a report folder: report.md (a table of
the runs, with the PSNR of the moving pixels), side_by_side.png (ground truth | static | MLP |
CfC | SDE-LNN on the fastest-moving test frame) and sweep.mp4 (the runs side by side, time
going 0 -> 1 from one test camera).
Finished runs are reused and stopped ones resumed, so an interrupted demo picks up where it
stopped.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from rich.console import Console

from liquidgs.atomic import write_text_atomic
from liquidgs.data import DEFAULT_SYNTHETIC_SCENE, SYNTHETIC_SCENES, generate_synthetic
from liquidgs.data.regions import moving_region
from liquidgs.errors import ConfigError, LiquidGSError
from liquidgs.eval.lpips import metric_name
from liquidgs.eval.regions import region_psnr, region_share
from liquidgs.experiments.plan import RunEntry, run_config
from liquidgs.experiments.runner import RunOutcome, default_parallel, run_local
from liquidgs.fields.registry import field_label, field_names, field_type
from liquidgs.media import labelled, to_uint8, write_png, write_video
from liquidgs.settings import parse_flags, to_dict
from liquidgs.train.config import stretched_schedule
from liquidgs.train.dataset import load_run_dataset
from liquidgs.train.run import TrainedRun, load_run
from liquidgs.train.run_folder import read_results

FRAMES = 80
"""Frames of the demo scene (train, val and test interleaved in time)."""
DISPLAY_SIZE = 128
"""side_by_side.png and sweep.mp4 show renders at least this large."""
DENSIFY_GRAD_THRESHOLD = 0.0014
"""Twice the tiny preset's: a 64 px image needs fewer Gaussians. Measured (MLP, 2,000
iterations): 3,920 Gaussians instead of 7,912 at the same PSNR (25.81 vs 25.90 dB), half
the time per step."""
DEMO_PRESET = "tiny"


def demo_fields() -> tuple[str, ...]:
    """The runs of the demo: every registered field with a tiny preset (plugins included), in the
    registry's order; the static model is the floor the deformation fields must beat."""
    return tuple(name for name in field_names() if DEMO_PRESET in field_type(name).presets)


@dataclass
class DemoArgs:
    out: Path = Path("report")
    """Folder for the report, its pictures, the runs (runs/) and their logs."""
    scene: str = DEFAULT_SYNTHETIC_SCENE
    """Built-in synthetic scene (puppet, spinner or still)."""
    size: int = 64
    """Image width and height. 64 px rather than the tiny preset's 128: the time goes into
    iterations, which is what the fields need to learn the swinging limbs."""
    iterations: int = 2000
    """Training iterations per run; the tiny preset's schedule is stretched to them."""
    seed: int = 0
    """Seed of every run."""
    device: str = "auto"
    """auto (CUDA where torch sees a GPU, else the CPU), cpu, cuda or cuda:N."""
    parallel: int = dataclasses.field(default_factory=default_parallel)
    """Runs trained at the same time (default: one per CPU core, or one per GPU)."""


def run_entry(args: DemoArgs, name: str, data_path: Path) -> RunEntry:
    """One demo run: the tiny preset stretched to args.iterations (see stretched_schedule);
    the report shows final scores only."""
    run_settings = {
        "field": name,
        "seed": args.seed,
        "device": args.device,
        "densify.grad_threshold": DENSIFY_GRAD_THRESHOLD,
        **stretched_schedule(DEMO_PRESET, args.iterations),
    }
    cfg = run_config(DEMO_PRESET, data_path, run_settings, f"demo run {name}")
    return RunEntry(
        dataset="synthetic",
        scene=args.scene,
        field=name,
        lambda_=cfg.resolved_lambda(),
        seed=args.seed,
        preset=DEMO_PRESET,
        data=str(data_path),
        run_dir=f"runs/{name}",
        config=to_dict(cfg),
    )


def check_settings(args: DemoArgs) -> None:
    """Every run's settings, checked before the scene is generated."""
    for name in demo_fields():
        run_entry(args, name, args.out)


def train_fields(args: DemoArgs, data_path: Path, console: Console) -> dict[str, Path]:
    """Train the runs as `liquidgs train` subprocesses, --parallel at a time (finished runs are
    kept, stopped ones resumed). The registry's last fields (the liquid ones, then plugins) start
    first: the static model, the quickest, goes last, so the two CPU slots balance."""
    entries = [run_entry(args, name, data_path) for name in reversed(demo_fields())]

    def report(outcome: RunOutcome) -> None:
        seconds = f" in {outcome.seconds:.0f} s" if outcome.status == "done" else ""
        console.print(f"{outcome.status} {outcome.name}{seconds} (log: {outcome.log})")

    console.rule(f"training {len(entries)} runs, {args.parallel} at a time")
    outcomes = run_local(entries, args.out, args.parallel, report)
    failed = [outcome for outcome in outcomes if outcome.status == "failed"]
    if failed:
        raise LiquidGSError(f"demo run {failed[0].name} failed ({failed[0].message}); its log: {failed[0].log}")
    return {name: args.out / "runs" / name for name in demo_fields()}


def fastest_moving_frame(run: TrainedRun, frames) -> int:
    """The test frame whose time has the largest mean Gaussian speed under the trained field."""
    h = 0.01
    speeds = []
    with torch.no_grad():
        for frame in frames:
            t0, t1 = max(frame.time - h, 0.0), min(frame.time + h, 1.0)
            step = run.at_time(t1).means - run.at_time(t0).means
            speeds.append(float(step.norm(dim=-1).mean()) / max(t1 - t0, 1e-9))
    return int(np.argmax(speeds))


def moving_region_psnr(args: DemoArgs, loaded: dict[str, TrainedRun], frames, background) -> tuple[dict, float]:
    """PSNR of each run over the test pixels whose ground truth moves (see data.regions.moving_region),
    from 8-bit renders as the evaluation scores them, and the share of test pixels that move."""
    masks = [moving_region(args.scene, frame, 1.0 / (FRAMES - 1)) for frame in frames]
    truths = [frame.image_uint8() for frame in frames]

    def renders(run: TrainedRun):
        for frame in frames:
            yield to_uint8(run.render(frame.camera, frame.time, background).rgb)

    return {name: region_psnr(renders(run), truths, masks) for name, run in loaded.items()}, region_share(masks)


def write_report(args: DemoArgs, runs: dict[str, Path], data_path: Path) -> Path:
    loaded = {name: load_run(path, args.device) for name, path in runs.items()}
    results = {name: read_results(path) for name, path in runs.items()}
    dataset = load_run_dataset(loaded["mlp"].config)
    frames = sorted(dataset.test, key=lambda f: f.time)
    background = torch.tensor(dataset.background, dtype=torch.float32)

    # Small renders are enlarged (nearest neighbour) so the limbs and the labels can be seen.
    zoom = max(1, DISPLAY_SIZE // max(frames[0].camera.width, frames[0].camera.height))

    def enlarged(image: np.ndarray) -> np.ndarray:
        return image.repeat(zoom, axis=0).repeat(zoom, axis=1)

    def render(run: TrainedRun, frame, t):
        return enlarged(to_uint8(run.render(frame.camera, t, background).rgb))

    moving, moving_share = moving_region_psnr(args, loaded, frames, background)
    index = fastest_moving_frame(loaded["mlp"], frames)
    frame = frames[index]
    panels = [labelled(enlarged(frame.image_uint8()), "ground truth")]
    panels += [labelled(render(run, frame, frame.time), field_label(n)) for n, run in loaded.items()]
    write_png(args.out / "side_by_side.png", np.concatenate(panels, axis=1))

    fixed = frames[0]
    sweep = []
    for i in range(48):
        t = i / 47
        row = [labelled(render(run, fixed, t), f"{field_label(n)} t={t:.2f}") for n, run in loaded.items()]
        sweep.append(np.concatenate(row, axis=1))
    write_video(args.out / "sweep.mp4", sweep, fps=12)

    def fmt(value, digits):
        return "n/a" if value is None else f"{value:.{digits}f}"

    final_mlp = results["mlp"].final
    if final_mlp.get("lpips") is None:
        lpips_desc = final_mlp["lpips_unavailable"]
    else:
        scaling = "inputs scaled to [-1,1]" if final_mlp.get("lpips_normalize") else "unnormalised inputs"
        lpips_desc = f"LPIPS: {metric_name(final_mlp['lpips_backbone'])}, v0.1, {scaling}"
        if final_mlp["lpips_backbone"] != "vgg":
            lpips_desc += (
                " (the paper names no backbone; the D-3DGS metrics code it inherits uses LPIPS-VGG on [0,1] "
                "inputs: these LPIPS values are not comparable with its tables)"
            )
    lines = [
        f"# liquidgs demo: {args.scene}",
        "",
        f"Scene: built-in synthetic `{args.scene}` at {frame.camera.width}x{frame.camera.height}, "
        f"{len(dataset.train)} train / {len(dataset.test)} test frames (data: `{data_path}`).",
        f"Preset `tiny` stretched to {results['mlp'].iterations} iterations (learning-rate decays over all of "
        f"them, densification until 3/4 with a gradient threshold of {DENSIFY_GRAD_THRESHOLD}, opacity reset every "
        f"2/5), seed {args.seed}, device "
        f"{results['mlp'].device}. Scores are the **final** evaluation on the test split "
        "(8-bit quantised renders); best-of numbers are in each run's results.json.",
        "",
        "| field | PSNR | moving-region PSNR | SSIM | LPIPS | params | FPS | train time (s) | Gaussians |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, res in results.items():
        final = res.final
        scores = (f"{fmt(final['psnr'], 2)} | {fmt(moving[name], 2)} | {fmt(final['ssim'], 4)} | "
                  f"{fmt(final.get('lpips'), 4)}")  # fmt: skip
        cost = f"{res.field_parameters:,} | {res.fps:.1f} | {res.train_seconds:.0f} | {res.num_gaussians:,}"
        lines.append(f"| {field_label(name)} | {scores} | {cost} |")
    lines += [
        "",
        f"Moving-region PSNR: over the test pixels whose ground truth changes between neighbouring frames "
        f"(rendered again from the same camera at t -+ 1/{FRAMES - 1}; {100 * moving_share:.1f}% of the test "
        "pixels), where a field has to reproduce the motion; the static model is the floor.",
        "",
        lpips_desc + ".",
        "",
        f"![side by side](side_by_side.png) Fastest-moving test frame `{frame.name}` (t = {frame.time:.3f}): "
        "ground truth | " + " | ".join(map(field_label, demo_fields())) + ".",
        "",
        "`sweep.mp4`: the runs side by side, time 0 -> 1, from test camera "
        f"`{fixed.name}`. Runs: " + ", ".join(f"`{p}`" for p in runs.values()) + ".",
        "",
    ]
    return write_text_atomic(args.out / "report.md", "\n".join(lines))


def main(argv: list[str]) -> int:
    args = parse_flags(DemoArgs, argv, prog="liquidgs demo", description=__doc__)
    if args.scene not in SYNTHETIC_SCENES:
        raise ConfigError(f"unknown synthetic scene '{args.scene}' (choose from {', '.join(SYNTHETIC_SCENES)})")
    if not 8 <= args.size <= 4096:
        raise ConfigError(f"--size must be between 8 and 4096, got {args.size}")
    if args.iterations < 1:
        raise ConfigError(f"--iterations must be >= 1, got {args.iterations}")
    if args.parallel < 1:
        raise ConfigError(f"--parallel must be >= 1, got {args.parallel}")
    check_settings(args)
    console = Console(stderr=True)
    started = time.perf_counter()
    data_root = generate_synthetic(
        args.scene, args.out / "data" / args.scene, size=args.size, frames=FRAMES, seed=args.seed
    )
    data_path = Path(data_root) / "dnerf"
    runs = train_fields(args, data_path, console)
    report = write_report(args, runs, data_path)
    console.print(report.read_text())
    console.print(f"[bold green]report written to {report.parent.resolve()}[/] ({time.perf_counter() - started:.0f} s)")
    return 0
