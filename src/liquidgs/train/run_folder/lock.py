"""One writer per run folder: an exclusive fcntl.flock on DIR/.liquidgs.lock (LOCK_NAME).

The operating system releases the lock when its process ends, however it ends, so a killed
run never leaves a stale lock. The holder writes its PID into the file so that a second
writer's error can name it. Readers (eval, render, export) take no lock; `writer_pid` tells
a run in progress (a live writer holds the lock) from a stopped one.
"""

from __future__ import annotations

import fcntl
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from liquidgs.atomic import disk_full
from liquidgs.errors import LiquidGSError
from liquidgs.train.run_folder.layout import LOCK_NAME

# A writer retries this long: a writer_pid() probe holds the lock for microseconds.
_ACQUIRE_SECONDS = 1.0


class RunFolderLocked(LiquidGSError):
    pass


def _read_pid(fd: int) -> int | None:
    try:
        return int(os.pread(fd, 32, 0).decode().strip())
    except (OSError, ValueError):
        return None


def _missing_ancestors(folder: Path) -> list[Path]:
    """folder and those of its parents that do not exist yet, deepest first."""
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    return missing


def _acquire(lock_path: Path) -> int:
    deadline = time.monotonic() + _ACQUIRE_SECONDS
    while True:
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _read_pid(fd)
            os.close(fd)
            if time.monotonic() > deadline:
                raise RunFolderLocked(
                    f"{lock_path.parent}: another process (PID {holder if holder else 'unknown'}) is writing "
                    "this run folder; wait for it to end or choose another --out"
                ) from None
            time.sleep(0.05)
            continue
        try:
            same_file = os.stat(lock_path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same_file = False
        if same_file:  # else the previous holder removed it between our open and flock
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            except BaseException as err:  # a full disk: no lock file is left behind
                lock_path.unlink(missing_ok=True)
                os.close(fd)
                if disk_full(err):
                    raise LiquidGSError(
                        f"no space left on {lock_path.parent} while writing {lock_path.name}; nothing was written"
                    ) from None
                raise
            return fd
        os.close(fd)


@contextmanager
def run_folder_lock(run_dir: str | Path) -> Iterator[Path]:
    """Hold the run folder's writer lock (creating the folder); raises RunFolderLocked if taken.

    Folders this call created are removed again if nothing was written into them.
    """
    run_dir = Path(run_dir)
    created = _missing_ancestors(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    lock_path = run_dir / LOCK_NAME
    try:
        fd = _acquire(lock_path)
    except BaseException:
        _remove_empty(created)
        raise
    try:
        yield run_dir
    finally:
        lock_path.unlink(missing_ok=True)  # while still held, so no writer can take a file on its way out
        os.close(fd)
        _remove_empty(created)


def _remove_empty(folders: list[Path]) -> None:
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:  # not empty (the run wrote something) or already gone
            return


def writer_pid(run_dir: str | Path) -> int | None:
    """The PID of the live process writing run_dir, or None when no process holds its lock.

    0 when a writer holds the lock but has not recorded its PID yet (a moment after taking it).
    """
    try:
        fd = os.open(Path(run_dir) / LOCK_NAME, os.O_RDONLY)
    except (FileNotFoundError, NotADirectoryError):
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _read_pid(fd) or 0
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)
