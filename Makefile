# Two commands do all set-up on a fresh machine:
#   make demo   - train static / MLP / CfC / SDE-LNN / HexPlane on the built-in synthetic scene, write a report
#   make test   - the whole test suite (what .ci/run calls)
#   make docs   - the documentation site (docs/, mkdocs.yml) into build/site, offline, warnings as
#                 errors; installs the `docs` extra into .venv first (CI runs it after make test)
#   make test-fast - the suite without the tests marked slow, for a contributor's loop
#   make reference - rewrite docs/reference/{cli,specs,errors}.md from the code (committed, so their
#                 links work on GitHub too; tests/test_docs.py fails while they are out of date)
# and one opt-in target:
#   make lpips-reference - re-check (or, with LPIPS_REFERENCE=write, re-record) the PyPI lpips
#                          distances that tests/test_lpips_reference.py holds ours to; it builds
#                          a separate 5.6 GB environment (torch 2.14.1 + torchvision) for them
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
# The PyPI lpips package with torchvision, apart from .venv (make lpips-reference only).
LPIPS_REF := .venv-lpips-ref
LPIPS_RECORD := tests/data/lpips_pypi_reference.json
LPIPS_REFERENCE ?= check
# pytest-xdist workers, one per core by default; whole files go to one worker (--dist loadfile), so a
# module's shared fixture (test_quality's eight trainings, say) is built once; in collection order
# (--no-loadscope-reorder), which tests/conftest.py starts with the longest files. TEST_WORKERS=0: serial.
TEST_WORKERS ?= auto
# Bytecode caches written even where the environment says not to (PYTHONDONTWRITEBYTECODE=1): without
# them every worker and every test's subprocess recompiles what it imports and pytest rewrites every
# test file's asserts again, about 4 s of CPU per worker. __pycache__ is ignored by git.
PYTEST := PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

.PHONY: demo test test-fast docs lint setup lpips-reference reference

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

# examples/field-plugin's own tests too: the template plugin, loaded from its checkout (not installed).
test: $(BIN)/liquidgs
	bash scripts/setup_browser.sh
	bash scripts/setup_npm_tests.sh
	$(BIN)/ruff check src tests examples
	$(PYTEST) tests examples/field-plugin/tests

$(BIN)/mkdocs: $(BIN)/liquidgs pyproject.toml
	$(BIN)/python -m pip install -q -e ".[docs]"
	touch $(BIN)/mkdocs

docs: $(BIN)/mkdocs
	$(BIN)/mkdocs build --strict

reference: $(BIN)/liquidgs
	$(BIN)/python scripts/docs_hooks.py

# Not a substitute for `make test`: the slow tests hold the quality bars and the crash, resume and
# executor guarantees.
test-fast: $(BIN)/liquidgs
	$(BIN)/ruff check src tests examples
	$(PYTEST) -m "not slow" tests examples/field-plugin/tests

lint: $(BIN)/liquidgs
	$(BIN)/ruff check src tests examples

lpips-reference: $(BIN)/liquidgs $(LPIPS_REF)/installed
	env -u PYTHONPATH $(LPIPS_REF)/bin/python tests/lpips_reference.py $(LPIPS_REFERENCE) $(LPIPS_RECORD)
	$(BIN)/python -m pytest -q tests/test_lpips_reference.py
