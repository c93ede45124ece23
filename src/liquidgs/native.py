"""Compiled CPU kernels: C++ sources built on first use and loaded with ctypes.

The kernels take plain pointers, so they need only a C++17 compiler (no torch headers, no
ninja); each library is compiled once per source text, flags, compiler and CPU into a cache
folder ($LIQUIDGS_CACHE_DIR, else ~/.cache/liquidgs) and shared by every process. Where one
cannot be built or loaded - no compiler, LIQUIDGS_CPU_KERNEL=0 - its caller does the same work
in torch, and `report_fallback` says so once, in one line on stderr.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

from torch import Tensor

FLAGS = ("-O3", "-march=native", "-std=c++17", "-shared", "-fPIC", "-fopenmp")
DISABLE_VARIABLE = "LIQUIDGS_CPU_KERNEL"

POINTER = ctypes.c_void_p
INT = ctypes.c_int
INT64 = ctypes.c_int64


class KernelUnavailable(RuntimeError):
    pass


def _cache_dir() -> Path:
    root = os.environ.get("LIQUIDGS_CACHE_DIR")
    return Path(root) if root else Path.home() / ".cache" / "liquidgs"


def _cpu_signature() -> str:
    """What -march=native depends on, so a cache shared across machines never runs foreign code."""
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
        wanted = [line for line in lines if line.startswith(("model name", "flags"))][:2]
        return "\n".join(wanted) or platform.processor()
    except OSError:
        return platform.processor() or platform.machine()


Defines = tuple[tuple[str, float], ...]
"""Compile-time constants (macro name, value) a library is built with: the Python module that
owns a constant passes it, so a kernel never holds its own copy."""


def define_flags(defines: Defines) -> list[str]:
    # repr: the shortest literal that reads back as the same double.
    return [f"-D{name}={float(value)!r}" for name, value in defines]


def _compile(compiler: str, sources: tuple[Path, ...], target: Path, defines: Defines) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as scratch:
        built = Path(scratch) / target.name
        command = [compiler, *FLAGS, *define_flags(defines), *(str(source) for source in sources), "-o", str(built)]
        result = subprocess.run(command, capture_output=True, text=True, check=False)
        if result.returncode != 0:
            first = (result.stderr.strip().splitlines() or ["no output"])[0]
            raise KernelUnavailable(f"{compiler} failed on {', '.join(s.name for s in sources)}: {first}")
        os.replace(built, target)  # atomic: concurrent first uses each build, one file wins


_outcomes: dict[tuple, ctypes.CDLL | KernelUnavailable] = {}


def load(
    name: str, sources: tuple[Path, ...], declare: Callable[[ctypes.CDLL], None], defines: Defines = ()
) -> ctypes.CDLL:
    """The library `name` built from `sources` with `defines`, after `declare` set its functions' argtypes.

    Raises KernelUnavailable with the reason when it cannot be built or loaded; the outcome,
    either way, is kept for the process, so a missing compiler is looked for once.
    """
    key = (name, sources, defines)
    if key not in _outcomes:
        try:
            _outcomes[key] = _build_and_load(name, sources, declare, defines)
        except KernelUnavailable as err:
            _outcomes[key] = err
    outcome = _outcomes[key]
    if isinstance(outcome, KernelUnavailable):
        raise outcome
    return outcome


def unavailable_reason(
    name: str, sources: tuple[Path, ...], declare: Callable[[ctypes.CDLL], None], defines: Defines = ()
) -> str | None:
    """None when `load` gives the library, else why it cannot."""
    try:
        load(name, sources, declare, defines)
    except KernelUnavailable as err:
        return str(err)
    return None


def _build_and_load(
    name: str, sources: tuple[Path, ...], declare: Callable[[ctypes.CDLL], None], defines: Defines
) -> ctypes.CDLL:
    if os.environ.get(DISABLE_VARIABLE, "1") == "0":
        raise KernelUnavailable(f"{DISABLE_VARIABLE}=0")
    missing = [source.name for source in sources if not source.is_file()]
    if missing:
        raise KernelUnavailable(f"{', '.join(missing)} not installed")
    compiler = os.environ.get("CXX") or shutil.which("c++") or shutil.which("g++")
    if compiler is None:
        raise KernelUnavailable("no C++ compiler found (set CXX or install g++)")
    try:
        version = subprocess.run([compiler, "--version"], capture_output=True, text=True, check=False).stdout
    except OSError as err:
        raise KernelUnavailable(f"cannot run {compiler}: {err.strerror}") from None
    texts = [source.read_text() for source in sources]
    key = hashlib.sha256(
        b"\0".join(s.encode() for s in (*texts, " ".join([*FLAGS, *define_flags(defines)]), version, _cpu_signature()))
    ).hexdigest()[:16]
    target = _cache_dir() / f"{name}-{key}.so"
    if not target.is_file():
        try:
            _compile(compiler, sources, target, defines)
        except OSError as err:
            raise KernelUnavailable(f"cannot build in {target.parent}: {err.strerror or err}") from None
    try:
        library = ctypes.CDLL(str(target))
    except OSError as err:
        raise KernelUnavailable(f"cannot load {target}: {err}") from None
    declare(library)
    return library


def pointer(tensor: Tensor) -> int:
    if not tensor.is_contiguous():
        raise ValueError("a compiled CPU kernel needs contiguous tensors")
    return tensor.data_ptr()


def suffix(tensor: Tensor) -> str:
    """The kernels' name suffix for a float32 / float64 tensor."""
    return "f64" if tensor.dtype.itemsize == 8 else "f32"


_reported: set[str] = set()


def report_fallback(what: str, reason: str, instead: str) -> None:
    """One line on stderr the first time a reason sends `what` to its torch path."""
    if (what, reason) not in _reported:
        _reported.add((what, reason))
        print(f"liquidgs: compiled {what} unavailable ({reason}); using {instead}", file=sys.stderr)
