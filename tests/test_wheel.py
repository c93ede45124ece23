"""liquidgs installs like a package: its wheel, built from the clone, holds every file the package
reads besides its modules (the CPU kernels' C++ sources, the web player, the paper's targets), and,
installed into a fresh environment, its `liquidgs` command trains a built-in scene from a folder
outside the clone, importing liquidgs from that environment, not from the clone."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

from tiny_runs import tiny_flags

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "liquidgs"

pytestmark = pytest.mark.slow


def package_data() -> set[str]:
    """Every file under src/liquidgs the package needs besides its modules, as wheel paths."""
    return {
        path.relative_to(PACKAGE.parent).as_posix()
        for path in PACKAGE.rglob("*")
        if path.is_file() and path.suffix not in {".py", ".pyc"} and "__pycache__" not in path.parts
    }


def build_wheel(out: Path) -> Path:
    """The wheel of a copy of the clone's sources (so no build/ or egg-info lands in the clone), built
    with this environment's setuptools: nothing is downloaded."""
    source = out / "source"
    source.mkdir(parents=True)
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        if (ROOT / name).is_file():  # the licence as the clone has it, or none
            shutil.copy2(ROOT / name, source / name)
    shutil.copytree(PACKAGE, source / "src" / "liquidgs", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    command = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q",
               "-w", str(out / "dist"), str(source)]  # fmt: skip
    subprocess.run(command, check=True, cwd=out, env=clean_env(), capture_output=True, text=True)
    (wheel,) = (out / "dist").glob("liquidgs-*.whl")
    return wheel


def clean_env(**extra: str) -> dict[str, str]:
    """The environment without PYTHONPATH (the test suite runs with src/ on it: the clone)."""
    env = {k: v for k, v in os.environ.items() if k not in {"PYTHONPATH", "VIRTUAL_ENV"}}
    return {**env, **extra}


def fresh_venv(path: Path) -> Path:
    """A new virtual environment that sees this one's installed packages (torch, gsplat, numpy, ...)
    but not liquidgs from the clone. `--system-site-packages` gives it the base interpreter's
    packages; where this environment is itself a virtual environment (as `make setup`'s .venv is),
    its own site-packages are added by a .pth file listing them. A plain path line in a .pth file
    puts the folder on sys.path without reading the .pth files inside it, so the clone's editable
    install there (`__editable__.liquidgs-*.pth`) is not taken along, and the fresh environment's
    own site-packages come first. So nothing is downloaded, and the wheel alone provides liquidgs."""
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", str(path)], check=True)
    python = path / "bin" / "python"
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True, capture_output=True, text=True, env=clean_env(),
    ).stdout.strip()  # fmt: skip
    ours = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (Path(purelib) / "running-environment.pth").write_text("\n".join(sorted(ours)) + "\n")
    return python


def test_the_wheel_holds_the_package_data(tmp_path_factory):
    wheel = build_wheel(tmp_path_factory.mktemp("wheel"))
    names = set(zipfile.ZipFile(wheel).namelist())
    data = package_data()
    # The files the code reads at run time, named so that an empty glob cannot pass.
    assert {"liquidgs/render/cpu_composite.cpp", "liquidgs/render/cpu_project.cpp", "liquidgs/eval/cpu_ssim.cpp",
            "liquidgs/fields/cpu_gate.cpp", "liquidgs/bake/web/index.html", "liquidgs/bake/web/player.js",
            "liquidgs/experiments/report/paper_targets.json"} <= data  # fmt: skip
    assert not data - names, f"package data missing from the wheel: {sorted(data - names)}"
    assert any(name.endswith(".dist-info/licenses/LICENSE") for name in names)
    entry_points = next(name for name in names if name.endswith(".dist-info/entry_points.txt"))
    assert "liquidgs = liquidgs.cli:main" in zipfile.ZipFile(wheel).read(entry_points).decode()


def test_the_installed_wheel_trains_outside_the_clone(tmp_path):
    wheel = build_wheel(tmp_path / "build")
    python = fresh_venv(tmp_path / "venv")
    subprocess.run(
        [str(python), "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(wheel)],
        check=True, env=clean_env(), capture_output=True, text=True,
    )  # fmt: skip
    liquidgs = tmp_path / "venv" / "bin" / "liquidgs"
    work = tmp_path / "work"  # outside the clone: nothing of it is on the path
    work.mkdir()
    # A fresh kernel cache: the CPU kernels are compiled from the C++ sources the wheel installed.
    env = clean_env(LIQUIDGS_CACHE_DIR=str(tmp_path / "kernels"), OMP_NUM_THREADS="1")

    def run(*args: str) -> subprocess.CompletedProcess:
        done = subprocess.run([*args], cwd=work, env=env, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, f"{args}: exit {done.returncode}\n{done.stdout}\n{done.stderr}"
        return done

    where = run(str(python), "-c", "import liquidgs; print(liquidgs.__file__)").stdout.strip()
    assert Path(where).is_relative_to(tmp_path / "venv"), where
    assert not Path(where).is_relative_to(ROOT)
    assert "train" in run(str(liquidgs), "--help").stdout
    licence = "from importlib.metadata import files; print([f.name for f in files('liquidgs')])"
    assert "'LICENSE'" in run(str(python), "-c", licence).stdout  # the installed package carries its licence
    run(str(liquidgs), "data", "synth", "--scene", "puppet", "--out", "scene", "--size", "32", "--frames", "12")
    flags = tiny_flags({"iterations": 20, "eval.start": 20, "eval.every": 20, "checkpoint_every": 20})
    done = run(str(liquidgs), "train", "--data", "scene/dnerf", "--field", "mlp", "--device", "cpu",
               "--out", "run", *flags)  # fmt: skip
    assert (work / "run" / "results.json").is_file(), done.stdout + done.stderr
    assert "liquidgs: compiled" not in done.stderr, done.stderr  # native.report_fallback: a kernel not built
    assert list((tmp_path / "kernels").glob("*.so")), "no CPU kernel was compiled from the installed sources"
