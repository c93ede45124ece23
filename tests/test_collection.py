"""Every test module imports without the optional packages the GPU machine lacks (ncps, pycolmap,
playwright, viser; no Chromium), so `pytest -m cuda tests` collects there: a test needing one
skips (fails under CI, shared_data.require_module) instead of stopping the collection."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
HIDDEN = ("ncps", "pycolmap", "playwright", "viser")
# Put first on sys.meta_path by sitecustomize: `import NAME` of a hidden package raises as if it were absent.
BLOCKER = f'''import sys

class HideOptionalPackages:
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in {HIDDEN!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}} (hidden by the collection test)", name=name)
        return None

sys.meta_path.insert(0, HideOptionalPackages())
'''


@pytest.mark.slow  # a second pytest process that imports every test module
def test_every_module_collects_with_the_optional_packages_hidden(tmp_path):
    (tmp_path / "sitecustomize.py").write_text(BLOCKER)
    path = os.pathsep.join([str(tmp_path), str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])
    env = {**os.environ, "PYTHONPATH": path, "LIQUIDGS_CHROMIUM": str(tmp_path / "no-chromium")}
    probe = subprocess.run([sys.executable, "-c", "import ncps"], env=env, capture_output=True, text=True)
    assert "hidden by the collection test" in probe.stderr  # the blocker is in force
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", "-m", "cuda", "tests"],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode in (0, 5), done.stdout[-3000:] + done.stderr[-2000:]  # 5: none selected
    assert "error" not in done.stdout.splitlines()[-1], done.stdout[-3000:]
    assert "tests/test_render.py::" in done.stdout  # the cuda tests are what `-m cuda` would run
