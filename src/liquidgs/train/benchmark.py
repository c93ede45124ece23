"""`liquidgs bench train`: milliseconds per training iteration, split into its phases.

The real trainer runs --from-step untimed steps (so densification has grown the Gaussians to a
trained scene's count), then --steps timed ones; each phase (train/phases.py) and the whole
step are reported as medians over the timed steps, with the Gaussian count, the backend the
rasteriser used, the machine and the thread count. The built-in puppet scene at 128 px is the
default; --data takes a D-NeRF or Nerfies folder (with --downscale). --clock cpu times the
process's CPU seconds instead of the wall clock's, on a CPU: on a machine shared with other work
they count this run's own work only (the record says which clock). Any other flag of `liquidgs
train` sets that setting of the timed run (e.g. `--cameras.refine off`, `--motion.rigidity 0`), so a
setting's cost is two runs on one commit; the settings given are in the record.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

import torch

from liquidgs.data import DEFAULT_SYNTHETIC_SCENE, DataConfig, generate_synthetic
from liquidgs.errors import ConfigError
from liquidgs.fields.config import PRESET_NAMES
from liquidgs.render import BACKENDS
from liquidgs.render.benchmark import machine_description
from liquidgs.settings import ArgumentParser, parse_flag_settings, to_dict_value, with_settings
from liquidgs.train.config import TrainConfig, preset_config
from liquidgs.train.model import deform
from liquidgs.train.phases import PHASES, PhaseClock
from liquidgs.train.run import resolve_device
from liquidgs.train.trainer import Trainer

CLOCKS = ("wall", "cpu")

# Settings the benchmark itself decides: how many steps run, where, and that none evaluates.
_OWN_SETTINGS = ("iterations", "out", "resume", "eval.start")


class _BenchParser(ArgumentParser):
    """The benchmark's own options; the flags left over are `liquidgs train`'s, as `args.settings`."""

    def parse_args(self, args=None, namespace=None):
        known, rest = self.parse_known_args(args, namespace)
        known.settings = parse_flag_settings(TrainConfig, rest, self.prog)
        taken = [key for key in known.settings if key in _OWN_SETTINGS]
        if taken:
            raise ConfigError(f"{self.prog}: --{taken[0]} is the benchmark's to set (--from-step and --steps)")
        return known


def build_parser() -> argparse.ArgumentParser:
    parser = _BenchParser(
        prog="liquidgs bench train",
        description=__doc__.splitlines()[0],
        epilog="Any other flag of `liquidgs train` sets that setting of the timed run.",
    )
    parser.add_argument("--json", action="store_true", help="print one JSON object (default: a table)")
    parser.add_argument("--data", type=Path, help=f"scene folder (default: the built-in {DEFAULT_SYNTHETIC_SCENE})")
    parser.add_argument("--size", type=int, default=128, help="built-in scene's image size")
    parser.add_argument("--downscale", type=int, help="image downscale of --data")
    parser.add_argument("--preset", default="tiny", choices=PRESET_NAMES, help="the training preset")
    parser.add_argument("--field", default="mlp", help="a registered field (checked by TrainConfig)")
    parser.add_argument("--backend", default="auto", choices=BACKENDS, help="the rasteriser")
    parser.add_argument("--device", default="auto", help="auto, cpu, cuda or cuda:N")
    parser.add_argument("--from-step", type=int, default=700, help="untimed steps first (default 700)")
    parser.add_argument("--steps", type=int, default=300, help="timed steps (default 300)")
    parser.add_argument("--threads", type=int, default=0, help="torch intra-op threads (0: torch's default)")
    parser.add_argument("--seed", type=int, default=0, help="the run's seed")
    parser.add_argument("--clock", default="wall", choices=CLOCKS,
                        help="wall time, or the process's CPU time (a CPU device only: steadier under other load)")
    parser.add_argument("--output", type=Path, help="also append the JSON object as a line to this file")
    return parser


def run(args: argparse.Namespace) -> int:
    if args.steps < 1 or args.from_step < 0 or args.threads < 0 or args.size < 8:
        raise ConfigError("bench train: need --steps >= 1, --from-step >= 0, --threads >= 0 and --size >= 8")
    if args.clock == "cpu" and resolve_device(args.device).type != "cpu":
        raise ConfigError(f"bench train: --clock cpu times a CPU run; --device {args.device} runs on CUDA")
    if args.threads:
        torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory(prefix="liquidgs-bench-") as scratch:
        data = args.data
        if data is None:
            data = generate_synthetic(DEFAULT_SYNTHETIC_SCENE, Path(scratch) / "scene", size=args.size) / "dnerf"
        record = measure(args, data, Path(scratch) / "run")
    if args.json:
        print(json.dumps(record), flush=True)
    else:
        given = "".join(f", {key}={value}" for key, value in record["settings"].items())
        clock = " (CPU time)" if record["clock"] == "cpu" else ""
        print(f"{record['scene']} {record['resolution'][0]}x{record['resolution'][1]}, {record['field']}{given}, "
              f"{record['backend']} backend, {record['n_gaussians']['median']} Gaussians: "
              f"{record['ms_per_iteration']} ms per iteration{clock}")  # fmt: skip
        for phase, ms in record["phases_ms"].items():
            print(f"  {phase:<16} {ms:8.2f} ms")
    if args.output is not None:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        with args.output.open("a") as file:
            file.write(json.dumps(record) + "\n")
    return 0


def measure(args: argparse.Namespace, data: Path, run_dir: Path) -> dict:
    iterations = args.from_step + args.steps
    cfg = with_settings(preset_config(args.preset, DataConfig(path=data, downscale=args.downscale)), {
        **args.settings, "field": args.field, "seed": args.seed, "device": args.device, "backend": args.backend,
        "iterations": iterations, "eval.start": iterations + 1,  # no evaluation inside the timed steps
    }, "bench train")  # fmt: skip
    run_dir.mkdir(parents=True)
    trainer = Trainer(cfg, run_dir)
    for step in range(1, args.from_step + 1):
        trainer.train_step(step)
    clock = trainer.clock = PhaseClock(trainer.device, cpu_time=args.clock == "cpu")
    totals, phases, counts, dynamic = [], {phase: [] for phase in PHASES}, [], []
    for step in range(args.from_step + 1, cfg.iterations + 1):
        started = clock.now()
        stats = trainer.train_step(step)
        totals.append(clock.now() - started)
        for phase in PHASES:
            phases[phase].append(clock.times[phase])
        counts.append(stats["n_gaussians"])
        if (moving := trainer.moving()) is not None:  # the split: the field moves these alone
            dynamic.append(moving.numel())
    frame = trainer.dataset.train[0]
    return {
        "benchmark": "train",
        "scene": DEFAULT_SYNTHETIC_SCENE if args.data is None else trainer.dataset.scene_name,
        "resolution": [frame.camera.width, frame.camera.height],
        "preset": args.preset,
        "field": args.field,
        "settings": {key: to_dict_value(value) for key, value in args.settings.items()},
        "backend": _backend_used(trainer, frame),
        "timed_steps": [args.from_step + 1, cfg.iterations],
        "n_gaussians": _spread(counts),
        **({"dynamic_gaussians": _spread(dynamic)} if dynamic else {}),
        "clock": args.clock,
        "ms_per_iteration": round(1000 * statistics.median(totals), 2),
        "phases_ms": {phase: round(1000 * statistics.median(values), 3) for phase, values in phases.items()},
        "device": trainer.device.type,
        "machine": machine_description(trainer.device),
        "torch_version": torch.__version__,
        "torch_threads": torch.get_num_threads(),
    }


def _spread(counts: list[int]) -> dict:
    return {"min": min(counts), "median": int(statistics.median(counts)), "max": max(counts)}


@torch.no_grad()
def _backend_used(trainer: Trainer, frame) -> str:
    return trainer._render(deform(trainer.params, None, frame.time), frame).info["backend"]


def main(argv: list[str]) -> int:
    return run(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
