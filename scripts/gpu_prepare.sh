#!/usr/bin/env bash
# Prepares, on this machine, what the GPU acceptance carries to the GPU machine (Python 3.12,
# torch 2.11 + CUDA 13, no registry reachable): both folders are git-ignored and named in the
# device call's carry (scripts/gpu_acceptance.sh says how it is called).
#   .whl/    the wheels the machine lacks, for CPython 3.12 on x86-64 (pip download; pure-Python
#            wheels but torchsde's and plyfile's needs), one version each
#   .scene/  hellwarrior (D-NeRF, 800x800, 24 MB) and the LPIPS weights (13 MB) from ../shared
# Usage: bash scripts/gpu_prepare.sh [SHARED]   (SHARED default ../shared)
set -euo pipefail
cd "$(dirname "$0")/.."
shared=${1:-../shared}
py=${PYTHON:-python3}
# The versions the project is tested with (its .venv); the machine has numpy, scipy, torch, rich,
# jaxtyping, ninja, typing-extensions, pyyaml, pillow, matplotlib, imageio and tensorboard already.
WHEELS="gsplat==1.5.3 tyro==1.0.17 docstring-parser==0.18.0 typeguard==4.6.1 torchsde==0.2.6 trampoline==0.1.2 plyfile==1.1.5"
rm -rf .whl.tmp && mkdir -p .whl.tmp
# shellcheck disable=SC2086
"$py" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    --platform any -d .whl.tmp $WHEELS
rm -rf .whl && mv .whl.tmp .whl
[ -f "$shared/data/dnerf/hellwarrior/transforms_train.json" ] || { echo "gpu_prepare: no $shared/data/dnerf/hellwarrior" >&2; exit 2; }
rm -rf .scene.tmp && mkdir -p .scene.tmp
cp -r "$shared/data/dnerf/hellwarrior" .scene.tmp/hellwarrior
[ -d "$shared/data/lpips" ] && cp -r "$shared/data/lpips" .scene.tmp/lpips
rm -rf .scene && mv .scene.tmp .scene
du -sh .whl .scene
echo "carry: [\".whl\", \".scene\"]; check the plan here first: bash scripts/gpu_acceptance.sh --dry-run"
