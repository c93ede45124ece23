#!/usr/bin/env bash
# Creates the reference environment that tests/test_lpips_reference.py runs the PyPI `lpips`
# package in. It is separate from .venv because lpips imports torchvision, and PyPI's
# torchvision does not load beside the project's torch; torch 2.14.1 with torchvision 0.29.1
# is a matching pair (a CUDA build of about 5.5 GB; only its CPU code is used).
# The marker file is written last: `make test` reruns this script while it is missing, so an
# interrupted install is completed. Running it again on a complete environment installs nothing.
set -euo pipefail
venv=${1:-.venv-lpips-ref}
py=${2:-python3}
marker="$venv/installed"
if [ ! -x "$venv/bin/python" ]; then
    "$py" -m venv "$venv"
fi
"$venv/bin/python" -m pip install -q "torch==2.14.1" "torchvision==0.29.1" "lpips==0.1.4" numpy
"$venv/bin/python" -c "import lpips, torchvision"
touch "$marker"
