"""Atomic file writes: a temporary file in the target's folder, then os.replace.

A reader (or a crash) never sees a half-written file; results.json written this way is the
only "done" marker of a run.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def write_atomic(path: str | Path, writer: Callable[[Path], None]) -> Path:
    """Call writer(tmp_path), then move tmp_path over path. The tmp file is removed on failure.

    The temporary name keeps the target's extension, since some writers (ffmpeg) pick the
    container from it.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    # mkstemp makes the file 0600; results are meant to be shared like any other file.
    os.chmod(tmp, 0o666 & ~_UMASK)
    try:
        writer(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_text_atomic(path: str | Path, text: str) -> Path:
    return write_atomic(path, lambda tmp: tmp.write_text(text))


def write_json_atomic(path: str | Path, obj) -> Path:
    return write_text_atomic(path, json.dumps(obj, indent=2, sort_keys=False) + "\n")
