"""The project's read-only shared folder (../shared from the repository root), for tests that use it.

A clone with nothing beside it has no ../shared: a test that needs a file from it skips with one
line naming that file. CI has the folder and sets LIQUIDGS_REQUIRE_SHARED=1 (.ci/run), which
turns such a skip into a failure, so a moved or renamed shared file cannot silently skip tests.
"""

from __future__ import annotations

import os
from pathlib import Path

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
