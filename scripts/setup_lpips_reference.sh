#!/usr/bin/env bash
# Creates the environment `make lpips-reference` runs the PyPI `lpips` package in, to re-check or
# re-record tests/data/lpips_pypi_reference.json (what tests/test_lpips_reference.py holds our
# LPIPS to; `make test` needs only that file). It is separate from .venv because lpips imports
# torchvision, and PyPI's torchvision does not load beside the project's torch; torch 2.14.1 with
# torchvision 0.29.1 is a matching pair (a CUDA build of about 5.5 GB; only its CPU code is used).
# The marker file is written last: make reruns this script while it is missing, so an
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
