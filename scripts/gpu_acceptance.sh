#!/usr/bin/env bash
# The GPU acceptance in one command, for the day a GPU machine is lent (15 minutes in all):
#   bash scripts/gpu_acceptance.sh SCENE [SECONDS]        e.g. .scene/hellwarrior 780
#   bash scripts/gpu_acceptance.sh --dry-run SCENE [SECONDS]
# 1. installs what the machine lacks: wheels from .whl/ (carried there; see docs/gpu.md) into
#    /tmp/site, and liquidgs itself from src/ (PYTHONPATH; the machine's own torch is kept);
# 2. builds gsplat's CUDA kernels for the GPU it finds (timed), into .gsplat-build/ so a later
#    command that carries that folder reuses the build;
# 3. runs `pytest -m cuda`;
# 4. `liquidgs bench gpu`: trains SCENE at full resolution with the MLP for the seconds left
#    (SECONDS, default 780, minus what steps 1-3 took and 90 s for evaluation and rendering),
#    then appends iterations/second, render FPS, PSNR and the GPU's name to benchmarks/gpu.jsonl
#    and prints a summary.
# --dry-run prints each step's command and runs only `liquidgs bench gpu --dry-run` (any machine).
set -euo pipefail
cd "$(dirname "$0")/.."
dry_run=0
if [ "${1:-}" = "--dry-run" ]; then dry_run=1; shift; fi
if [ $# -lt 1 ] || [ $# -gt 2 ]; then
    echo "usage: bash scripts/gpu_acceptance.sh [--dry-run] SCENE [SECONDS]" >&2
    exit 2
fi
scene=$1
total=${2:-780}
case "$total" in ''|*[!0-9]*) echo "gpu_acceptance: SECONDS must be a whole number, got '$total'" >&2; exit 2;; esac
[ -d "$scene" ] || { echo "gpu_acceptance: $scene: scene folder not found" >&2; exit 2; }
py=${PYTHON:-python3}
started=$(date +%s)
elapsed() { echo $(( $(date +%s) - started )); }
run() {
    echo "== [$(elapsed) s] $*"
    if [ "$dry_run" = 0 ]; then "$@"; fi
}

site=/tmp/site
export PYTHONPATH="$PWD/src:$site${PYTHONPATH:+:$PYTHONPATH}"
export TORCH_EXTENSIONS_DIR="$PWD/.gsplat-build"
if compgen -G ".whl/*.whl" >/dev/null; then
    run "$py" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$site" .whl/*.whl
fi
build_start=$(date +%s)
run "$py" -c "import torch; from gsplat.cuda._backend import _C; assert _C is not None, 'gsplat CUDA build failed'; print('gsplat kernels for', torch.cuda.get_device_name())"
echo "== gsplat build (or reuse) took $(( $(date +%s) - build_start )) s"
run "$py" -m pytest -q -m cuda tests
budget=$(( total - $(elapsed) - 90 ))
if [ "$dry_run" = 1 ]; then
    budget=$(( total - 90 ))
    echo "== [$(elapsed) s] $py -m liquidgs.cli bench gpu --data $scene --budget-s <seconds left>"
    exec "$py" -m liquidgs.cli bench gpu --data "$scene" --budget-s "$budget" --dry-run
fi
if [ "$budget" -lt 10 ]; then
    echo "gpu_acceptance: only ${budget} s left for training after set-up; give more SECONDS" >&2
    exit 1
fi
run "$py" -m liquidgs.cli bench gpu --data "$scene" --budget-s "$budget"
echo "== done in $(elapsed) s"
