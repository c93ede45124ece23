"""Atomic file writes: a temporary file in the target's folder, then os.replace.

A reader (or a crash) never sees a half-written file; results.json written this way is the
only "done" marker of a run. A process killed mid-write leaves its temporary behind
(`.<stem>.<random>.tmp<suffix>`); `temporaries_of` finds them so the folder's next writer
can remove them.
"""

from __future__ import annotations

import errno
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

from liquidgs.errors import LiquidGSError

_DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def _temporary_name_parts(path: Path) -> tuple[str, str]:
    return f".{path.stem}.", f".tmp{path.suffix}"


def temporaries_of(path: str | Path) -> list[Path]:
    """Temporaries that write_atomic(path) left behind (a process killed mid-write)."""
    path = Path(path)
    prefix, suffix = _temporary_name_parts(path)
    return sorted(p for p in path.parent.glob(f"{prefix}*{suffix}") if p.is_file())


def write_atomic(path: str | Path, writer: Callable[[Path], None]) -> Path:
    """Call writer(tmp_path), then move tmp_path over path. The tmp file is removed on failure.

    The temporary name keeps the target's extension, since some writers (ffmpeg) pick the
    container from it. A full disk is one clear error; the previous file at `path` is kept.
    """
    path = Path(path)
    prefix, suffix = _temporary_name_parts(path)
    tmp: Path | None = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=path.parent)
        os.close(fd)
        tmp = Path(name)
        # mkstemp makes the file 0600; results are meant to be shared like any other file.
        os.chmod(tmp, 0o666 & ~_UMASK)
        writer(tmp)
        os.replace(tmp, path)
    except BaseException as err:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        if disk_full(err):
            kept = "the previous file is kept" if path.exists() else "nothing was written"
            raise LiquidGSError(f"no space left on {path.parent} while writing {path.name}; {kept}") from None
        raise
    return path


def disk_full(err: BaseException) -> bool:
    """Whether `err` is, or was raised while handling, a full disk or quota: torch's zip writer
    turns the OSError(ENOSPC) of its file into a RuntimeError ("unexpected pos") raised in its
    except clause, so the OSError is only the RuntimeError's context."""
    seen: set[int] = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, OSError) and err.errno in _DISK_FULL:
            return True
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return False


def write_text_atomic(path: str | Path, text: str) -> Path:
    return write_atomic(path, lambda tmp: tmp.write_text(text))


def write_json_atomic(path: str | Path, obj) -> Path:
    return write_text_atomic(path, json.dumps(obj, indent=2, sort_keys=False) + "\n")
