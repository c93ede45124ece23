"""`liquidgs bench {raster,fields,train,gpu,acceptance,bake}`: benchmarks that print one JSON object per
case, and the GPU acceptance (scripts/gpu_acceptance.sh) in stages."""

from __future__ import annotations

import importlib
import sys

BENCHMARKS = {
    "raster": "liquidgs.render.benchmark",
    "fields": "liquidgs.fields.benchmark",
    "train": "liquidgs.train.benchmark",
    "gpu": "liquidgs.train.acceptance",
    "acceptance": "liquidgs.train.gpu_acceptance",
    "bake": "liquidgs.bake.benchmark",
}


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in BENCHMARKS:
        print(f"usage: liquidgs bench {{{','.join(BENCHMARKS)}}} [--json] [options]", file=sys.stderr)
        return 0 if argv and argv[0] in ("-h", "--help") else 2
    module = importlib.import_module(BENCHMARKS[argv[0]])
    args = module.build_parser().parse_args(argv[1:])  # usage errors: one line (settings.ArgumentParser)
    return int(module.run(args) or 0)
