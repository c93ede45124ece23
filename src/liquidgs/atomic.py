"""The one writer of liquidgs' files: a temporary in the target's folder, then os.replace; and
folders (a baked scene, a PLY sequence, a web export) built under a hidden name beside their
place and renamed into it whole.

A reader (or a crash) never sees a half-written file or folder; results.json written this way is
the only "done" marker of a run. A full disk, a read-only file system or a missing permission is
one line naming the file (WriteRefused), with the previous file or folder kept.

A process killed mid-write (kill -9) leaves its temporary (`.<stem>.<host>-<pid>-<random>.tmp<suffix>`)
or build folder (`.<name>.partial-<host>-<pid>-<random>`) behind; the next write into that folder
removes those whose writer is dead (remove_stale).
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import secrets
import shutil
import socket
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from liquidgs.errors import LiquidGSError

_DISK_FULL = (errno.ENOSPC, errno.EDQUOT)
_REFUSALS = {
    errno.ENOSPC: "no space left on",
    errno.EDQUOT: "disk quota exceeded on",
    errno.EROFS: "read-only file system at",
    errno.EACCES: "no permission to write in",
}
_HOST = hashlib.sha1(socket.gethostname().encode()).hexdigest()[:8]
_STALE_FILE = re.compile(r"\..+\.(?P<host>[0-9a-f]{8})-(?P<pid>\d+)-[a-z0-9_]{8}\.tmp(\.[^.]*)?")
_STALE_FOLDER = re.compile(r"\..+\.(partial|replaced)-(?P<host>[0-9a-f]{8})-(?P<pid>\d+)-[0-9a-f]{8}")
_swept: set[tuple[int, Path]] = set()

Built = TypeVar("Built")


class WriteRefused(LiquidGSError):
    """The file system refused a write (full, read-only, no permission); what was there is kept."""

    def __init__(self, message: str, reason: str, path: Path):
        super().__init__(message)
        self.reason, self.path = reason, path


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def _owner() -> str:
    """The writer's host and PID, carried in its temporaries' names so remove_stale can tell a dead
    writer's leftovers from a live one's (read at each write: a forked child is another writer)."""
    return f"{_HOST}-{os.getpid()}"


def _temporary_name_parts(path: Path) -> tuple[str, str]:
    return f".{path.stem}.", f".tmp{path.suffix}"


def temporaries_of(path: str | Path) -> list[Path]:
    """Temporaries that write_atomic(path) left behind (a process killed mid-write)."""
    path = Path(path)
    prefix, suffix = _temporary_name_parts(path)
    return sorted(p for p in path.parent.glob(f"{prefix}*{suffix}") if p.is_file())


def _writer_dead(match: re.Match) -> bool:
    """The leftover's name says which host and PID wrote it. Only a writer on this host is judged,
    and only dead when no process has its PID; a PID taken by a later process, or a writer on another
    host sharing the folder (a network file system), keeps the leftover: a live writer's temporary is
    never removed, at the cost of a rare leftover kept. (Containers sharing a folder must not share a
    hostname, or a PID of one would be looked up in the other.)"""
    if match["host"] != _HOST:
        return False
    try:
        os.kill(int(match["pid"]), 0)
    except (ProcessLookupError, OverflowError):  # no such process; a PID no process can have
        return True
    except PermissionError:  # alive, under another user
        return False
    return False


def remove_stale(folder: str | Path) -> list[Path]:
    """Remove the temporaries and hidden build folders in `folder` whose writer is dead; returns them."""
    removed = []
    try:
        entries = list(Path(folder).iterdir())
    except (FileNotFoundError, NotADirectoryError):
        return removed
    for entry in entries:
        is_dir = entry.is_dir() and not entry.is_symlink()
        match = (_STALE_FOLDER if is_dir else _STALE_FILE).fullmatch(entry.name)
        if match is None or not _writer_dead(match):
            continue
        if is_dir:
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)
        removed.append(entry)
    return removed


def _sweep_once(folder: Path) -> None:
    """remove_stale(folder) at this process's first write there: leftovers of dead writers do not
    appear while it writes, and a folder of many frames is not listed once per frame."""
    key = (os.getpid(), folder.absolute())
    if key not in _swept:
        _swept.add(key)
        remove_stale(folder)


def _refusal(err: BaseException, region: Path) -> tuple[str, Path | None] | None:
    """(reason, file) when `err`, or an error it was raised while handling, is the file system
    refusing a write in `region`: a full disk anywhere; read-only or no permission only for a file
    in region or a folder on its way (not, say, a source file that could not be read)."""
    for cause in _chain(err):
        if isinstance(cause, WriteRefused):
            return cause.reason, cause.path
        if isinstance(cause, OSError) and cause.errno in _REFUSALS:
            where = Path(cause.filename) if isinstance(cause.filename, (str, os.PathLike)) else None
            on_the_way = where is None or where.is_relative_to(region) or region.is_relative_to(where)
            if cause.errno in _DISK_FULL or on_the_way:
                return _REFUSALS[cause.errno], where
    return None


def _chain(err: BaseException | None):
    """`err` and the errors it was raised from or while handling: torch's zip writer turns the
    OSError(ENOSPC) of its file into a RuntimeError ("unexpected pos") raised in its except
    clause, so the OSError is only the RuntimeError's context."""
    seen: set[int] = set()
    while err is not None and id(err) not in seen:
        yield err
        seen.add(id(err))
        err = err.__cause__ or err.__context__


def disk_full(err: BaseException) -> bool:
    """Whether `err`, or an error it was raised while handling, is a full disk or quota."""
    return any(isinstance(cause, OSError) and cause.errno in _DISK_FULL for cause in _chain(err))


def write_atomic(path: str | Path, writer: Callable[[Path], None]) -> Path:
    """Call writer(tmp_path), then move tmp_path over path. The tmp file is removed on failure.

    The temporary name keeps the target's extension, since some writers (ffmpeg) pick the
    container from it. A full disk, a read-only file system or no permission is one WriteRefused
    naming the file; the previous file at `path` is kept.
    """
    path = Path(path)
    prefix, suffix = _temporary_name_parts(path)
    tmp: Path | None = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        _sweep_once(path.parent)
        fd, name = tempfile.mkstemp(prefix=f"{prefix}{_owner()}-", suffix=suffix, dir=path.parent)
        os.close(fd)
        tmp = Path(name)
        # mkstemp makes the file 0600; results are meant to be shared like any other file.
        os.chmod(tmp, 0o666 & ~_UMASK)
        writer(tmp)
        os.replace(tmp, path)
    except BaseException as err:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        refused = _refusal(err, path.parent)
        if refused is not None:
            reason, kept = refused[0], "the previous file is kept" if path.is_file() else "nothing was written"
            raise WriteRefused(f"{reason} {path.parent} while writing {path.name}; {kept}", reason, path) from None
        raise
    return path


def build_atomically(out: Path, build: Callable[[Path], Built], replace: bool = False) -> Built:
    """build(folder) in a hidden .<name>.partial-* folder beside `out`, renamed to `out` when it
    returns; removed on any failure or interrupt. Without `replace`, `out` must be absent or an
    empty folder (data.capture.refuse_taken); with it, an older `out` is replaced whole, and only
    once the new one is complete. A refused write names the file as it would be in `out`."""
    building = out.parent / f".{out.name}.partial-{_owner()}-{secrets.token_hex(4)}"
    old = out.parent / f".{out.name}.replaced-{_owner()}-{secrets.token_hex(4)}"
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        _sweep_once(out.parent)
        building.mkdir()  # not mkdtemp: its 0700 would stay on the folder
        result = build(building)
        if replace and out.exists():
            # Two renames: `out` is absent between them, never part old and part new.
            os.rename(out, old)
            os.rename(building, out)
            shutil.rmtree(old, ignore_errors=True)  # what stays is a leftover for remove_stale
        else:
            if out.exists():
                out.rmdir()  # empty, checked by refuse_taken; rename needs the name free
            os.rename(building, out)
    except BaseException as err:
        shutil.rmtree(building, ignore_errors=True)
        if old.exists() and not out.exists():
            os.rename(old, out)  # the new one failed to take its place: the older one goes back
        refused = _refusal(err, building)
        if refused is not None:
            reason, where = refused
            inside = where is not None and where.is_relative_to(building)
            shown = out / where.relative_to(building) if inside else out
            kept = f"the previous {out.name} is kept" if out.exists() else "nothing was written"
            name = shown.relative_to(out.parent)
            raise WriteRefused(f"{reason} {out.parent} while writing {name}; {kept}", reason, shown) from None
        raise
    return result


def write_text_atomic(path: str | Path, text: str) -> Path:
    return write_atomic(path, lambda tmp: tmp.write_text(text))


def write_json_atomic(path: str | Path, obj) -> Path:
    return write_text_atomic(path, json.dumps(obj, indent=2, sort_keys=False) + "\n")


def save_torch_atomic(path: str | Path, obj) -> Path:
    """torch.save(obj) to `path` through write_atomic."""
    import torch  # here: commands that never save tensors do not import torch for it

    def save(tmp: Path) -> None:
        # Through a Python file object, so a full disk raises an OSError(ENOSPC) that write_atomic
        # finds; given a path, torch's C++ writer reports only "unexpected pos", without the errno.
        with open(tmp, "wb") as file:
            torch.save(obj, file)

    return write_atomic(path, save)
