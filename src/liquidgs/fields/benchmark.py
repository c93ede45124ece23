"""`liquidgs bench fields`: size, cost and throughput of every deformation field.

One JSON object per (field, preset, number of Gaussians): parameters, FLOPs per Gaussian,
forward throughput (eval mode, no autograd) and forward+backward throughput (train mode, so
the 'sde' field draws its noise; loss = sum of squared deltas, gradients to the parameters),
in Gaussians per second, with the device, torch version and thread count. Each timing is the
median of up to --repeats runs after --warmup runs (on CPU the warm-up uses at most 4096
Gaussians), stopping early once a case has used --max-seconds, so the default run (20k and
100k Gaussians, every preset) stays within about three minutes on a 2-core CPU for the four
paper fields; every other registered field (hexplane, plugins) adds its own rows and time, and
has rows only for the presets it registered.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable, Iterator

import torch

from liquidgs.errors import ConfigError, LiquidGSError, one_line
from liquidgs.fields.build import build_field
from liquidgs.fields.config import PRESET_NAMES, FieldConfig
from liquidgs.fields.registry import field_names, field_type
from liquidgs.settings import ArgumentParser

# Variants of the 'sde' field beyond the paper, benchmarked with --variants.
VARIANTS: dict[str, dict] = {
    "sde-adaptive": dict(name="sde", adaptive_lambda=True),
    "sde-ou": dict(name="sde", noise="ou"),
    "sde-solver": dict(name="sde", noise="solver"),
}


def _csv(kind: Callable[[str], object]) -> Callable[[str], list]:
    return lambda text: [kind(item) for item in text.split(",") if item]


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="liquidgs bench fields", description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="one JSON object per line (default: a table)")
    parser.add_argument("--device", default="auto", help="cpu, cuda, cuda:N or auto (cuda when available)")
    parser.add_argument("--sizes", type=_csv(int), default=[20_000, 100_000], help="numbers of Gaussians")
    parser.add_argument(
        "--presets", type=_csv(str), default=list(PRESET_NAMES), help="comma-separated presets to size the fields by"
    )
    parser.add_argument("--fields", type=_csv(str), help="comma-separated (default: every registered field)")
    parser.add_argument("--variants", action="store_true", help="also: " + ", ".join(VARIANTS))
    parser.add_argument("--lambda", dest="lambda_", type=float, default=0.05, help="noise level of sde rows")
    parser.add_argument("--warmup", type=int, default=1, help="untimed passes first")
    parser.add_argument("--repeats", type=int, default=3, help="timed passes per case (the fastest counts)")
    parser.add_argument("--max-seconds", type=float, default=1.0, help="stop repeating a case after this")
    parser.add_argument("--threads", type=int, default=0, help="torch intra-op threads (0: torch's default)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the fields' weights and inputs")
    return parser


def _timer(device: torch.device) -> Callable[[Callable[[], None]], float]:
    def run(step: Callable[[], None]) -> float:
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        start = time.perf_counter()
        step()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        return time.perf_counter() - start

    return run


def _step(field, n: int, device: torch.device, backward: bool) -> Callable[[], None]:
    """One pass over n random Gaussians at a shared time (the trainer's case)."""
    xyz = torch.rand(n, 3, device=device) * 2 - 1
    t = torch.rand(1, 1, device=device)

    def forward():
        with torch.no_grad():
            field(xyz, t)

    def forward_backward():
        sum(d.square().sum() for d in field(xyz, t)).backward()

    return forward_backward if backward else forward


def _median_seconds(field, n: int, device: torch.device, backward: bool, args) -> float:
    # On CUDA the warm-up must use the measured shape (kernel selection, allocator); on CPU a
    # small batch is enough to start the thread pool and saves minutes on the big fields.
    warm_n = n if device.type == "cuda" else min(n, 4096)
    timer = _timer(device)
    warm = _step(field, warm_n, device, backward)
    for _ in range(args.warmup):
        timer(warm)
    step = _step(field, n, device, backward)
    times: list[float] = []
    while len(times) < args.repeats and (not times or sum(times) < args.max_seconds):
        times.append(timer(step))
    return statistics.median(times)


def _cases(args) -> list[tuple[str, str, dict]]:
    """(row label, preset, FieldConfig settings) of every row."""
    cases = []
    for preset in args.presets:
        # A field without sizes for this preset (a plugin may have fewer) has no row for it.
        labels = {name: dict(name=name) for name in args.fields if preset in field_type(name).presets}
        if args.variants:
            labels.update(VARIANTS)
        for label, settings in labels.items():
            noisy = field_type(settings["name"]).default_lambda is not None
            cases.append((label, preset, dict(settings, lambda_=args.lambda_ if noisy else 0.0)))
    return cases


def benchmark(args, skip_broken: bool = False) -> Iterator[dict]:
    """Run every case, yielding one row per (field, preset, size) as soon as it is measured.
    skip_broken: a plugin field that fails is one warning line and the others are still measured."""
    if args.device == "auto":
        device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    else:
        try:
            device = torch.device(args.device)
        except RuntimeError:
            raise ConfigError(f"--device: unknown device {args.device!r}") from None
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    device_name = torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"
    broken: set[str] = set()
    for label, preset, settings in _cases(args):
        kind = field_type(settings["name"])
        if kind.name in broken:
            continue
        try:
            yield from _rows(label, preset, FieldConfig(preset=preset, **settings), device, device_name, args)
        except Exception as error:
            if not (skip_broken and kind.plugin):
                raise
            broken.add(kind.name)
            if isinstance(error, LiquidGSError):  # build_field's: it names the field and its package
                detail = str(error)
            else:
                detail = f"field '{kind.name}' (package {kind.origin}): {type(error).__name__}: {error}"
            print(f"liquidgs bench fields: warning: skipped {one_line(detail)}", file=sys.stderr, flush=True)


def _rows(label: str, preset: str, config: FieldConfig, device, device_name: str, args) -> Iterator[dict]:
    torch.manual_seed(args.seed)
    field = build_field(config).to(device)
    for n in args.sizes:
        field.eval()
        fwd = _median_seconds(field, n, device, False, args)
        fwd_bwd = None
        if field.num_parameters() > 0:
            field.train()
            fwd_bwd = _median_seconds(field, n, device, True, args)
            field.zero_grad(set_to_none=True)
        yield {
            "field": label,
            "preset": preset,
            "gaussians": n,
            "params": field.num_parameters(),
            "flops_per_gaussian": field.flops_per_gaussian(),
            "forward_gaussians_per_s": n / fwd,
            "forward_backward_gaussians_per_s": None if fwd_bwd is None else n / fwd_bwd,
            "forward_ms": 1e3 * fwd,
            "forward_backward_ms": None if fwd_bwd is None else 1e3 * fwd_bwd,
            "lambda": config.resolved().lambda_,
            "device": str(device),
            "device_name": device_name,
            "threads": torch.get_num_threads(),
            "dtype": "float32",
            "torch": torch.__version__,
        }


def _table(rows: list[dict]) -> str:
    lines = [f"{'field':<13}{'preset':<8}{'N':>8}{'params':>11}{'FLOPs/G':>11}{'fwd G/s':>12}{'fwd+bwd G/s':>13}"]
    for r in rows:
        both = r["forward_backward_gaussians_per_s"]
        bwd = "-" if both is None else f"{both:.3g}"
        lines.append(
            f"{r['field']:<13}{r['preset']:<8}{r['gaussians']:>8}{r['params']:>11,}"
            f"{r['flops_per_gaussian']:>11,}{r['forward_gaussians_per_s']:>12.3g}{bwd:>13}"
        )
    if rows:
        lines.append(
            f"device {rows[0]['device']} ({rows[0]['device_name']}), {rows[0]['threads']} threads, "
            f"torch {rows[0]['torch']}"
        )
    return "\n".join(lines)


def main(argv: list[str]) -> int:
    return run(build_parser().parse_args(argv))


def run(args: argparse.Namespace) -> int:
    # Every registered field unless named: then a broken plugin is skipped with a warning, not fatal.
    skip_broken = not args.fields
    args.fields = args.fields or list(field_names())
    for name in args.fields:
        field_type(name)  # an unknown name: one line with the registered ones
    if not args.sizes or min(args.sizes) < 1 or args.repeats < 1 or args.warmup < 0 or args.threads < 0:
        raise ConfigError("bench fields: sizes and repeats must be >= 1, warmup and threads >= 0")
    if not (args.max_seconds > 0 and args.lambda_ >= 0) or max(args.sizes) > 100_000_000:
        raise ConfigError("bench fields: need --max-seconds > 0, --lambda >= 0 and sizes up to 100000000")
    for name in args.presets:
        if name not in PRESET_NAMES:
            raise ConfigError(f"unknown preset '{name}' (choose from {', '.join(PRESET_NAMES)})")
    if args.json:
        for row in benchmark(args, skip_broken):
            print(json.dumps(row), flush=True)
    else:
        print(_table(list(benchmark(args, skip_broken))))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
