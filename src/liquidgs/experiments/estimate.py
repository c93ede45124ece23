"""The GPU time an experiment would take, for `liquidgs experiment run --dry-run`.

From measured per-iteration costs where the GPU acceptance left one (benchmarks/gpu.jsonl: the
scene stage's iterations per second, per preset and field); else from FLOPs, under the stated
assumptions below, which make it a lower bound: the field's forward and backward only (three
times its forward FLOPs, fields' own flops_per_gaussian), at an assumed Gaussian count and an
assumed sustained rate, with the rasteriser, densification and evaluation not counted.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from liquidgs.experiments.plan import RunEntry

GPU_RECORDS = Path("benchmarks/gpu.jsonl")
ASSUMED_GAUSSIANS = 150_000
"""Gaussians per step over a run: an assumption (no GPU run of the full schedule exists yet)."""
ASSUMED_FLOPS_PER_S = 0.25 * 67e12
"""A quarter of the H200's fp32 peak (67 TFLOP/s, its datasheet): narrow layers on 150k rows."""
BACKWARD_FACTOR = 3
"""Forward + backward of a layer: about three times its forward FLOPs."""


@dataclass(frozen=True)
class Estimate:
    seconds: float
    measured_runs: int
    """Runs whose cost is a measured it/s; the others are FLOPs estimates or unmeasured."""
    sources: tuple[str, ...]
    unmeasured_runs: int = 0
    """Runs with neither a measured it/s nor field FLOPs (the static model): not in `seconds`."""

    def line(self, runs: int) -> str:
        how = "; ".join(self.sources)
        if self.unmeasured_runs == runs:  # nothing was counted: no figure, rather than a 0.0 that reads as free
            return f"GPU-time estimate for the {runs} runs to train: unmeasured ({how})"
        hours = f"{self.seconds / 3600:,.1f} GPU-hours" + (" plus the unmeasured runs" if self.unmeasured_runs else "")
        return f"GPU-time estimate for the {runs} runs to train: {hours} ({how})"


def measured_rates(path: Path = GPU_RECORDS) -> dict[tuple[str, str], tuple[float, str]]:
    """(preset, field) -> (iterations per second, GPU) from the acceptance's scene-stage records."""
    rates: dict[tuple[str, str], tuple[float, str]] = {}
    if not path.is_file():
        return rates
    for line in path.read_text().splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        if record.get("benchmark") == "gpu-acceptance" and record.get("iterations_per_second"):
            key = (record.get("preset", "dnerf"), record.get("field", "mlp"))
            rates[key] = (float(record["iterations_per_second"]), str(record.get("device_name", "a GPU")))
    return rates


def _field_flops(entry: RunEntry, cache: dict) -> int:
    from liquidgs.fields import build_field

    cfg = entry.train_config()
    key = (cfg.preset, cfg.field, repr(cfg.field_options))
    if key not in cache:
        cache[key] = int(build_field(cfg.field_config()).flops_per_gaussian())
    return cache[key]


def estimate(runs: list[RunEntry], rates: dict[tuple[str, str], tuple[float, str]] | None = None) -> Estimate:
    rates = measured_rates() if rates is None else rates
    seconds, measured, unmeasured, gpus, cache = 0.0, 0, 0, set(), {}
    for entry in runs:
        iterations = int(entry.config["iterations"]) if entry.config else 0
        rate = rates.get((entry.preset, entry.field))
        if rate is not None:
            seconds += iterations / rate[0]
            measured += 1
            gpus.add(rate[1])
        elif _field_flops(entry, cache) == 0:  # the static model still trains its Gaussians: not free
            unmeasured += 1
        else:
            flops = BACKWARD_FACTOR * _field_flops(entry, cache) * ASSUMED_GAUSSIANS * iterations
            seconds += flops / ASSUMED_FLOPS_PER_S
    sources = []
    if measured:
        sources.append(f"{measured} runs from measured it/s on {', '.join(sorted(gpus))}")
    if unmeasured:
        sources.append(
            f"{unmeasured} runs unmeasured: a field without FLOPs (static) still trains its Gaussians, whose "
            "rasteriser time this estimate does not model, and no GPU figure of it is measured yet"
        )
    if measured + unmeasured < len(runs):
        sources.append(
            f"{len(runs) - measured - unmeasured} runs from FLOPs, a lower bound: the field's forward + backward "
            f"({BACKWARD_FACTOR}x its forward FLOPs) on an assumed {ASSUMED_GAUSSIANS:,} Gaussians a step at an "
            f"assumed {ASSUMED_FLOPS_PER_S / 1e12:.1f} TFLOP/s (a quarter of an H200's fp32 peak); rasteriser, "
            "densification and evaluation not counted, no GPU figure measured yet"
        )
    return Estimate(seconds, measured, tuple(sources), unmeasured)
