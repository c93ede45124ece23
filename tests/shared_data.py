"""The project's read-only shared folder (../shared from the repository root), and the optional
test packages (the dev extras), for tests that use them.

A clone with nothing beside it has no ../shared: a test that needs a file from it skips with one
line naming that file. CI has the folder and sets LIQUIDGS_REQUIRE_SHARED=1 (.ci/run), which
turns such a skip into a failure, so a moved or renamed shared file cannot silently skip tests.
The same holds for the dev extras (ncps, pycolmap, playwright): a machine without them (the GPU
machine) skips the tests that need one, and CI, which installs them all, fails instead.
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path
from types import ModuleType

import pytest

from liquidgs.eval.lpips import WEIGHTS_ENV

SHARED = Path(__file__).resolve().parents[2] / "shared"
REQUIRE_ENV = "LIQUIDGS_REQUIRE_SHARED"
LPIPS_DIR = SHARED / "data" / "lpips"
DNERF_ROOT = SHARED / "data" / "dnerf"
PAPER_DIR = SHARED / "paper"


def shared_required() -> bool:
    return os.environ.get(REQUIRE_ENV, "") not in ("", "0")


def require_shared(path: Path) -> Path:
    """`path` (inside ../shared) if it exists; otherwise skip the calling test, or fail it under CI."""
    if path.exists():
        return path
    shown = f"../shared/{path.relative_to(SHARED)}"
    if shared_required():
        pytest.fail(f"{shown} is missing, and {REQUIRE_ENV} is set: this run must have ../shared", pytrace=False)
    pytest.skip(f"needs {shown} (not in this checkout)")


def require_module(name: str) -> ModuleType:
    """The optional package `name` (a dev extra); otherwise skip the calling test, or fail it under CI.
    Called inside tests or fixtures, never at a module's top level, so every test module imports
    (and `pytest -m cuda` collects) on a machine without the dev extras."""
    try:
        return importlib.import_module(name)
    except ImportError as err:
        if shared_required():
            pytest.fail(f"{name} is not importable ({err}), and {REQUIRE_ENV} is set: install .[dev]", pytrace=False)
        pytest.skip(f"needs {name} (pip install -e .[dev])")


def require_installed(path: Path | str, missing: str) -> Path:
    """`path`, a tool the project's own set-up installs (Chromium, gsplat.js); otherwise skip the calling
    test with `missing`, or fail it under CI, where a missing tool is a set-up that went wrong."""
    if Path(path).exists():
        return Path(path)
    if shared_required():
        pytest.fail(f"{missing}, and {REQUIRE_ENV} is set: make test's set-up should have installed it", pytrace=False)
    pytest.skip(missing)


def lpips_weights_dir() -> Path:
    """The offline LPIPS backbone weights (alexnet / squeezenet features), or skip as above."""
    return require_shared(LPIPS_DIR / "alexnet_features.pth").parent


def use_optional_lpips(monkeypatch) -> Path | None:
    """optional_lpips_dir(); when there is one, the code under test finds it through $LIQUIDGS_LPIPS_WEIGHTS."""
    found = optional_lpips_dir()
    if found:
        monkeypatch.setenv(WEIGHTS_ENV, str(found))
    return found


def optional_lpips_dir() -> Path | None:
    """The LPIPS weights folder for tests that also run without LPIPS (it is then reported unavailable).
    Under CI the folder must be there, so the run scores LPIPS as the tests expect to check."""
    if LPIPS_DIR.is_dir() or not shared_required():
        return LPIPS_DIR if LPIPS_DIR.is_dir() else None
    return require_shared(LPIPS_DIR)
