# Two commands do all set-up on a fresh machine:
#   make demo   - train MLP / CfC / SDE-LNN on the built-in synthetic scene, write a report
#   make test   - the whole test suite (what .ci/run calls)
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
# The PyPI lpips package with torchvision, apart from .venv: tests hold our LPIPS against it.
LPIPS_REF := .venv-lpips-ref

.PHONY: demo test lint setup

# As the liquidgs command does (liquidgs/__init__.py): idle OpenMP threads sleep, not spin.
export OMP_WAIT_POLICY ?= PASSIVE

# Offline LPIPS backbone weights, where the project's shared folder provides them.
ifneq ($(wildcard ../shared/data/lpips),)
export LIQUIDGS_LPIPS_WEIGHTS ?= $(abspath ../shared/data/lpips)
endif

$(BIN)/liquidgs: pyproject.toml
	bash scripts/setup.sh $(VENV) $(PY)

$(LPIPS_REF)/installed: scripts/setup_lpips_reference.sh
	bash scripts/setup_lpips_reference.sh $(LPIPS_REF) $(PY)

setup: $(BIN)/liquidgs

demo: $(BIN)/liquidgs
	$(BIN)/liquidgs demo --out report

test: $(BIN)/liquidgs $(LPIPS_REF)/installed
	bash scripts/setup_browser.sh
	$(BIN)/ruff check src tests
	$(BIN)/python -m pytest -q tests

lint: $(BIN)/liquidgs
	$(BIN)/ruff check src tests
