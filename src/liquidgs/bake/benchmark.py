"""`liquidgs bench bake --run DIR --baked BAKED`: a baked scene against the field it came from.

On the run's test views: PSNR of the baked render against the field's render, the test PSNR of
each against ground truth (8-bit, as eval scores it) and its change, bytes per Gaussian, the PSNR
against the field of the splatv model fitted to the baked scene (as the file stores it), its
records per Gaussian and the share of the motion it keeps, and the
render time of each (the same cameras, resolution and Gaussians; the fastest of --repeats passes over
the views, by the wall clock and by the process's CPU time) with the speed-ups; and the CPU time
of a frame's parts: the field's deformation, the keyframe interpolation, the rasteriser, with the
speed-up that free interpolation would reach, (deformation + rasteriser) / rasteriser. Prints one
JSON object; --output appends it to a JSONL file.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import torch

from liquidgs.bake.formats import parse_splatv, splatv_bytes
from liquidgs.bake.pieces import agreement, fit_within_bytes
from liquidgs.bake.scene import is_baked, load_baked
from liquidgs.errors import ConfigError, LiquidGSError
from liquidgs.eval.metrics import psnr, quantize_8bit
from liquidgs.render.benchmark import machine_description
from liquidgs.settings import ArgumentParser
from liquidgs.train.dataset import load_run_dataset
from liquidgs.train.model import render_frame
from liquidgs.train.run import load_run

MAX_REPEATS = 100
"""The most --repeats: 33x the default 3; each is one more pass of every render and every part timed."""


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="liquidgs bench bake", description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True, help="the run folder")
    parser.add_argument("--baked", type=Path, required=True, help="its baked scene (liquidgs bake)")
    parser.add_argument(
        "--repeats", type=int, default=3, help=f"timed passes over the test views (at most {MAX_REPEATS})"
    )
    parser.add_argument("--threads", type=int, default=0, help="torch intra-op threads (0: torch's default)")
    parser.add_argument("--output", type=Path, help="also append the record to this JSONL file")
    return parser


def mean(values: list[float]) -> float:
    return sum(values) / len(values)


def timed_pass(render, frames) -> tuple[float, float]:
    """Seconds per frame of one pass over `frames`: wall clock, and the process's CPU time (on a
    machine shared with other work the wall clock also counts the time others hold the cores)."""
    wall, cpu = time.perf_counter(), time.process_time()
    for frame in frames:
        render(frame)
    return (time.perf_counter() - wall) / len(frames), (time.process_time() - cpu) / len(frames)


def fastest(render, frames, repeats: int) -> tuple[float, float]:
    """The smallest wall and CPU time per frame over `repeats` passes."""
    passes = [timed_pass(render, frames) for _ in range(repeats)]
    return min(wall for wall, _ in passes), min(cpu for _, cpu in passes)


@torch.no_grad()
def measure(run_dir: Path, baked_dir: Path, repeats: int) -> dict:
    if not is_baked(baked_dir):
        raise LiquidGSError(f"{baked_dir}: not a baked scene (no baked.json)")
    if is_baked(run_dir):  # a scene against itself, or against another bake: no field to compare with
        raise LiquidGSError(f"{run_dir}: a baked scene, not a run; give --run the run it came from")
    run = load_run(run_dir, "cpu")
    baked = load_baked(baked_dir, "cpu")
    if baked.params["means"].shape != run.params["means"].shape or baked.iteration != run.iteration:
        raise LiquidGSError(f"{baked_dir}: not baked from {run_dir} at its iteration {run.iteration}")
    dataset = load_run_dataset(run.config)
    frames = dataset.test or dataset.train
    background = torch.tensor(dataset.background, dtype=torch.float32)

    def field_render(frame):
        return run.render(frame.camera, frame.time, background).rgb.clamp(0, 1)

    def baked_render(frame):
        return baked.render(frame.camera, frame.time, background).rgb.clamp(0, 1)

    fitted = fit_within_bytes(baked, [*dataset.test, *dataset.train], dataset.train, background)  # the export's
    splatv, _ = parse_splatv(splatv_bytes(fitted.model, []))  # as the file holds it: float16, 8-bit colour
    splatv_agreement = agreement(run, splatv, frames, background)

    baked_agreement, field_gt, baked_gt = [], [], []
    for frame in frames:
        a, b = field_render(frame), baked_render(frame)
        truth = quantize_8bit(frame.image().clamp(0, 1))
        baked_agreement.append(float(psnr(b, a)))
        field_gt.append(float(psnr(quantize_8bit(a), truth)))
        baked_gt.append(float(psnr(quantize_8bit(b), truth)))
    field_seconds, field_cpu = fastest(field_render, frames, repeats)
    baked_seconds, baked_cpu = fastest(baked_render, frames, repeats)
    # Where a frame's time goes: the Gaussians at the frame's time (field or keyframes), then the
    # rasteriser, which both pay alike; its share bounds the speed-up however cheap the keyframes.
    at_time = {frame.time: baked.at_time(frame.time) for frame in frames}
    _, deformation_cpu = fastest(lambda frame: run.at_time(frame.time), frames, repeats)
    _, interpolation_cpu = fastest(lambda frame: baked.at_time(frame.time), frames, repeats)
    _, rasteriser_cpu = fastest(
        lambda frame: render_frame(at_time[frame.time], frame.camera, sh_degree=baked.sh_degree,
                                   background=background, backend=run.config.backend),
        frames, repeats,
    )  # fmt: skip
    camera = frames[0].camera
    return {
        "scene": dataset.scene_name,
        "field": run.config.field,
        "preset": run.config.preset,
        "iteration": run.iteration,
        "gaussians": int(run.params["means"].shape[0]),
        "keyframes_max": int(baked.tracks.counts.max()),
        "keyframes_mean": float(baked.tracks.counts.double().mean()),
        "test_views": len(frames),
        "resolution": [camera.width, camera.height],
        "baked_vs_field_psnr": mean(baked_agreement),
        "baked_vs_field_psnr_min": min(baked_agreement),
        "field_test_psnr": mean(field_gt),
        "baked_test_psnr": mean(baked_gt),
        "test_psnr_change": mean(baked_gt) - mean(field_gt),
        "bytes_per_gaussian": baked.manifest["bytes_per_gaussian"],
        "splatv_vs_field_psnr": mean(splatv_agreement),
        "splatv_vs_field_psnr_min": min(splatv_agreement),
        "splatv_records_per_gaussian": fitted.report["records"] / int(run.params["means"].shape[0]),
        "splatv_motion_kept": fitted.motion_kept,
        "midpoint_max_relative_error": baked.manifest["error"]["max_relative_error"],
        "gaussians_over_budget": baked.manifest["error"]["gaussians_over_budget"],
        "field_ms_per_frame": 1000 * field_seconds,
        "baked_ms_per_frame": 1000 * baked_seconds,
        "speedup": field_seconds / baked_seconds,
        "field_cpu_ms_per_frame": 1000 * field_cpu,
        "baked_cpu_ms_per_frame": 1000 * baked_cpu,
        "cpu_speedup": field_cpu / baked_cpu,
        "field_deformation_cpu_ms": 1000 * deformation_cpu,
        "keyframe_interpolation_cpu_ms": 1000 * interpolation_cpu,
        "rasteriser_cpu_ms": 1000 * rasteriser_cpu,
        "speedup_bound": (deformation_cpu + rasteriser_cpu) / rasteriser_cpu,
        "timing": f"fastest of {repeats} passes over the test views, render only (no PNG), backend "
        f"{run.config.backend}",
        "machine": machine_description(torch.device("cpu")),
        "python": platform.python_version(),
        "torch_version": torch.__version__,
        "torch_threads": torch.get_num_threads(),
    }


def run(args: argparse.Namespace) -> int:
    if not 1 <= args.repeats <= MAX_REPEATS or args.threads < 0:
        raise ConfigError(
            f"bench bake: need --repeats between 1 and {MAX_REPEATS} and --threads >= 0, "
            f"got {args.repeats} and {args.threads}"
        )
    if args.threads:
        torch.set_num_threads(args.threads)
    record = measure(args.run, args.baked, args.repeats)
    print(json.dumps(record), flush=True)
    if args.output is not None:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        with args.output.open("a") as file:
            file.write(json.dumps(record) + "\n")
    return 0
