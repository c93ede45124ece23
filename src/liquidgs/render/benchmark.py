"""`liquidgs bench raster`: time forward and backward of `rasterize` on D-NeRF-like random scenes.

Prints one JSON object per case and line. Peak memory: on CUDA, torch.cuda.max_memory_allocated
after a reset; on CPU, the growth of the process's peak resident set (VmHWM in /proc/self/status,
reset per case by writing 5 to /proc/self/clear_refs) over the resident set before the case, taken
after glibc's malloc_trim; memory freed by an earlier case and still resident can hide some growth.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch

from liquidgs.atomic import write_text_atomic
from liquidgs.cameras import DNERF_CAMERA_ANGLE_X, centred_intrinsics, focal_from_fov
from liquidgs.errors import ConfigError
from liquidgs.render.contract import DEPTH_ALPHA_FLOOR
from liquidgs.render.projection import project_gaussians
from liquidgs.render.rasterize import BACKENDS, rasterize
from liquidgs.render.reference import composite_dense
from liquidgs.render.torch_backend import view_colors
from liquidgs.settings import ArgumentParser

DEFAULT_CASES = "64x64/5000,200x200/20000,800x800/100000"
CAMERA_DISTANCE = 4.0


def parse_case(text: str) -> tuple[int, int, int]:
    size, _, count = text.partition("/")
    width, _, height = size.partition("x")
    try:
        case = int(width), int(height), int(count)
    except ValueError:
        raise ConfigError(f"--cases: a case looks like WIDTHxHEIGHT/N, got {text!r}") from None
    if not all(1 <= value <= 100_000_000 for value in case):
        raise ConfigError(f"--cases: width, height and N must be between 1 and 100000000, got {text!r}")
    return case


def dnerf_like_scene(n: int, width: int, height: int, device: torch.device, seed: int = 0) -> dict:
    """Small Gaussians (std-devs 0.005-0.03) in the unit ball, seen from 4 units at D-NeRF's field of view."""
    generator = torch.Generator().manual_seed(seed)
    directions = torch.randn(n, 3, generator=generator)
    means = directions / directions.norm(dim=1, keepdim=True) * torch.rand(n, 1, generator=generator) ** (1 / 3)
    focal = focal_from_fov(DNERF_CAMERA_ANGLE_X, width)
    viewmat = torch.eye(4)
    viewmat[2, 3] = CAMERA_DISTANCE
    scene = {
        "means": means,
        "quats": torch.randn(n, 4, generator=generator),
        "scales": torch.empty(n, 3).uniform_(0.005, 0.03, generator=generator),
        "opacities": torch.empty(n).uniform_(0.1, 1.0, generator=generator),
        "colors": torch.rand(n, 3, generator=generator),
        "viewmat": viewmat,
        "K": centred_intrinsics(focal, width, height),
    }
    return {key: value.to(device) for key, value in scene.items()}


def dense_render(scene: dict, width: int, height: int):
    """All-pairs baseline: the same projection, then every pixel against every Gaussian."""
    projection = project_gaussians(
        scene["means"], scene["quats"], scene["scales"], scene["opacities"], scene["viewmat"], scene["K"],
        width, height, near_plane=0.01, far_plane=1e10, eps2d=0.3,
    )  # fmt: skip
    colors = view_colors(scene["colors"], None, scene["means"], scene["viewmat"])
    features = torch.cat([colors, projection.depths[:, None]], dim=1)
    accumulated, alpha = composite_dense(
        projection.means2d, projection.conics, scene["opacities"], features, projection.depths,
        torch.ones_like(projection.visible), width, height, pixel_chunk=1024, checkpointed=True,
    )  # fmt: skip
    return accumulated[..., :3], alpha, accumulated[..., 3:] / alpha.clamp_min(DEPTH_ALPHA_FLOOR)


def _synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _proc_status_kib(field: str) -> int | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


class PeakMemory:
    """Peak memory of one case, in MiB (see the module docstring for how)."""

    def __init__(self, device: torch.device):
        self.device = device
        self.baseline_kib = 0

    def start(self) -> None:
        if self.device.type == "cuda":
            torch.cuda.reset_peak_memory_stats(self.device)
            return
        # Hand freed heap pages back first so the baseline is not inflated by an earlier case.
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL("libc.so.6").malloc_trim(0)
        # Without the reset the peak covers the whole process so far: an over-estimate, never an under.
        with contextlib.suppress(OSError):
            Path("/proc/self/clear_refs").write_text("5")
        self.baseline_kib = _proc_status_kib("VmRSS") or 0

    def peak_mb(self) -> float:
        if self.device.type == "cuda":
            return torch.cuda.max_memory_allocated(self.device) / 2**20
        peak_kib = _proc_status_kib("VmHWM") or 0
        return max(peak_kib - self.baseline_kib, 0) / 1024


def time_case(render: Callable[[dict], tuple], scene: dict, device: torch.device, repeats: int, warmup: int) -> dict:
    leaves = {key: scene[key].clone().requires_grad_(True) for key in ("means", "quats", "scales", "opacities")}
    leaves["colors"] = scene["colors"].clone().requires_grad_(True)
    inputs = scene | leaves
    memory = PeakMemory(device)
    forward_ms, backward_ms = [], []
    for iteration in range(warmup + repeats):
        if iteration == warmup:
            memory.start()
        _synchronize(device)
        start = time.perf_counter()
        rgb, alpha, depth = render(inputs)
        _synchronize(device)
        middle = time.perf_counter()
        (rgb.sum() + alpha.sum() + 0.01 * depth.sum()).backward()
        _synchronize(device)
        end = time.perf_counter()
        for leaf in leaves.values():
            leaf.grad = None
        if iteration >= warmup:
            forward_ms.append(1000 * (middle - start))
            backward_ms.append(1000 * (end - middle))
    return {
        "forward_ms": round(statistics.median(forward_ms), 2),
        "backward_ms": round(statistics.median(backward_ms), 2),
        "total_ms": round(statistics.median(f + b for f, b in zip(forward_ms, backward_ms)), 2),
        "peak_memory_mb": round(memory.peak_mb(), 1),
        "repeats": repeats,
    }


def machine_description(device: torch.device) -> str:
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    return f"{platform.processor() or platform.machine()}, {os.cpu_count()} logical CPUs"


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="liquidgs bench raster", description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object per case (default: text)")
    parser.add_argument("--backend", default="auto", choices=BACKENDS, help="the rasteriser to time")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu", help="cpu or cuda[:N]")
    parser.add_argument("--cases", default=DEFAULT_CASES, help=f"comma-separated WxH/N (default {DEFAULT_CASES})")
    parser.add_argument("--tile-sizes", help="comma-separated (torch and cpu backends; default: the backend's)")
    parser.add_argument("--repeats", type=int, default=5, help="timed passes per case (the fastest counts)")
    parser.add_argument("--warmup", type=int, default=1, help="untimed passes first")
    parser.add_argument(
        "--dense",
        action="store_true",
        help="also time dense all-pairs evaluation at 128x128/5000 against torch",
    )
    parser.add_argument("--output", type=Path, help="also write all results as a JSON list to this file")
    return parser


def main(argv: list[str]) -> int:
    return run(build_parser().parse_args(argv))


def run(args: argparse.Namespace) -> int:
    try:
        device = torch.device(args.device)
    except RuntimeError:
        raise ConfigError(f"--device: unknown device {args.device!r}") from None
    cases = [parse_case(text) for text in args.cases.split(",") if text]
    try:
        tile_sizes = [int(text) for text in args.tile_sizes.split(",")] if args.tile_sizes else [None]
    except ValueError:
        raise ConfigError(f"--tile-sizes: comma-separated integers expected, got {args.tile_sizes!r}") from None
    tile_sizes_ok = all(size is None or 1 <= size <= 256 for size in tile_sizes)
    if not cases or not tile_sizes_ok or args.repeats < 1 or args.warmup < 0:
        raise ConfigError("bench raster: need at least one case, tile sizes in 1..256, repeats >= 1 and warmup >= 0")
    machine = {"machine": machine_description(device), "torch_version": torch.__version__,
               "torch_threads": torch.get_num_threads()}  # fmt: skip
    results = []

    def report(record: dict) -> None:
        record = record | machine
        results.append(record)
        if args.json:
            print(json.dumps(record), flush=True)
        else:
            print(
                f"{record['backend']:>16} {record['width']}x{record['height']} N={record['n_gaussians']}: "
                f"forward {record['forward_ms']} ms, backward {record['backward_ms']} ms, "
                f"peak {record['peak_memory_mb']} MB",
                flush=True,
            )

    def run_rasterize(width, height, n, tile_size, repeats, warmup):
        scene = dnerf_like_scene(n, width, height, device)
        info = {}

        def render(inputs):
            out = rasterize(
                inputs["means"], inputs["quats"], inputs["scales"], inputs["opacities"], inputs["colors"],
                inputs["viewmat"], inputs["K"], width, height, backend=args.backend, tile_size=tile_size,
            )  # fmt: skip
            info.update(backend=out.info["backend"], n_pairs=out.info["n_pairs"], tile=out.info["tile_size"])
            return out.rgb, out.alpha, out.depth

        timing = time_case(render, scene, device, repeats, warmup)
        record = {"backend": info["backend"], "device": device.type, "width": width, "height": height,
                  "n_gaussians": n, "tile_size": info["tile"]}  # fmt: skip
        report(record | timing | {"n_tile_pairs": info["n_pairs"]})
        return timing

    # The first render of a process pays one-time costs (thread pool, allocator growth) that a
    # per-case warm-up does not absorb; spend them on an untimed small scene.
    warm = dnerf_like_scene(1000, 64, 64, device)
    rasterize(warm["means"], warm["quats"], warm["scales"], warm["opacities"], warm["colors"], warm["viewmat"],
              warm["K"], 64, 64, backend=args.backend)  # fmt: skip
    for width, height, n in cases:
        for tile_size in tile_sizes:
            large = width * height * n > 10**10
            run_rasterize(width, height, n, tile_size, 1 if large else args.repeats, 0 if large else args.warmup)
    if args.dense:
        width = height = 128
        n = 5000
        tiled = run_rasterize(width, height, n, tile_sizes[0], args.repeats, args.warmup)
        scene = dnerf_like_scene(n, width, height, device)
        dense = time_case(lambda inputs: dense_render(inputs, width, height), scene, device, 1, 0)
        report(
            {
                "backend": "dense-all-pairs",
                "device": device.type,
                "width": width,
                "height": height,
                "n_gaussians": n,
            }
            | dense
            | {"speedup_of_torch_backend": round(dense["total_ms"] / tiled["total_ms"], 1)}
        )
    if args.output is not None:
        write_text_atomic(args.output, json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
