#!/usr/bin/env bash
# Creates the virtual environment and installs liquidgs with its test tools.
# torch: a torch already importable by the chosen Python is kept (users bring their own
# CUDA build); only where none is present is the CPU build 2.13.0 installed.
set -euo pipefail
venv=${1:-.venv}
py=${2:-python3}
if [ ! -x "$venv/bin/python" ]; then
    "$py" -m venv --system-site-packages "$venv"
fi
pip="$venv/bin/python -m pip"
if ! "$venv/bin/python" -c "import torch" 2>/dev/null; then
    $pip install -q "torch==2.13.0"
fi
$pip install -q -e ".[dev]"
# LPIPS: only the package's linear-layer weight files are used (liquidgs has its own
# network code); --no-deps keeps torchvision, which pins a torch build, out.
$pip install -q --no-deps "lpips==0.1.4"
touch "$venv/bin/liquidgs"
