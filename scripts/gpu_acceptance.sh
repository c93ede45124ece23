#!/usr/bin/env bash
# The GPU acceptance, one command on a lent GPU machine (15 minutes of device time in all, a command
# killed at 10 minutes, only OUT_DIR's files come back: 8 files, 16 MiB each):
#   bash scripts/gpu_acceptance.sh "$OUT" [SCENE]          SCENE default .scene/hellwarrior
#   bash scripts/gpu_acceptance.sh --dry-run [OUT] [SCENE]  the stage plan with its times (any machine)
# What travels: the working tree, plus what scripts/gpu_prepare.sh put in two git-ignored folders,
# named in the device call's carry: .whl (the Python 3.12 wheels the machine lacks: gsplat, tyro,
# torchsde, plyfile and their needs) and .scene (the shared D-NeRF hellwarrior at 800x800, 24 MB,
# and the LPIPS weights, 13 MB): ../shared does not travel. The device call:
#   run(command="bash scripts/gpu_acceptance.sh $OUT", carry=[".whl", ".scene"], timeout_s=600)
# Steps: the wheels into /tmp/site (timed, one record), then `liquidgs bench acceptance`, whose
# stages (train/gpu_acceptance.py) append their records to OUT/acceptance.jsonl as they go and end
# with OUT/summary.txt; OUT/log.txt holds the output, OUT/gsplat-build.log the build's last lines.
# gsplat builds into .gsplat-build/ (git-ignored): a second command on the still-warm machine reuses it.
set -uo pipefail
cd "$(dirname "$0")/.."
dry_run=0
if [ "${1:-}" = "--dry-run" ]; then dry_run=1; shift; fi
if [ $# -gt 2 ] || { [ $# -lt 1 ] && [ "$dry_run" = 0 ]; }; then
    echo "usage: bash scripts/gpu_acceptance.sh [--dry-run] OUT_DIR [SCENE]" >&2
    exit 2
fi
out=${1:-/tmp/liquidgs-acceptance-out}
scene=${2:-.scene/hellwarrior}
py=${PYTHON:-python3}
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD/src:/tmp/site${PYTHONPATH:+:$PYTHONPATH}"
[ -d .scene/lpips ] && export LIQUIDGS_LPIPS_WEIGHTS="$PWD/.scene/lpips"
if ! "$py" -c "import importlib.util, sys; sys.exit(importlib.util.find_spec('torch') is None)" 2>/dev/null; then
    echo "gpu_acceptance: $py cannot import torch (set PYTHON to an interpreter that has it)" >&2
    exit 2
fi
if [ "$dry_run" = 1 ]; then
    exec "$py" -m liquidgs.cli bench acceptance --out "$out" --scene "$scene" --dry-run
fi
mkdir -p "$out" || exit 2
if compgen -G ".whl/*.whl" >/dev/null; then
    began=$(date +%s)
    "$py" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
        >"$out/log.txt" 2>&1 || { echo "gpu_acceptance: installing .whl/ failed (see $out/log.txt)" >&2; exit 2; }
    echo "{\"stage\": \"install\", \"event\": \"end\", \"status\": \"passed\", \"seconds\": $(( $(date +%s) - began ))}" \
        >>"$out/acceptance.jsonl"
fi
"$py" -m liquidgs.cli bench acceptance --out "$out" --scene "$scene" 2>&1 | tee -a "$out/log.txt"
