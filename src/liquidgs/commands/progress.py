"""Progress a person can follow: rich's live bar on a terminal; where the output goes to a file or a
pipe (a job in the background, its log), plain lines instead - one at the start, one at most every
PLAIN_INTERVAL_S seconds, one at the end - each with the counts, elapsed time and ETA, flushed as
written. rich prints nothing of a live bar to a file until it stops, so a long run's log stayed empty.

Pipelines of stages that print a line per step (data video, images, flow, undistort) log through a
StageLog: their lines as before, and, where the output is not a terminal, a line whenever a stage
has been silent for PLAIN_INTERVAL_S (COLMAP's feature extraction and matching report nothing
while they run, for minutes on a long clip)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

PLAIN_INTERVAL_S = 30.0
"""Seconds between two plain progress lines (updates in between are not printed)."""


def clock(seconds: float) -> str:
    seconds = int(seconds)
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


class PlainProgress:
    """What liquidgs uses of rich.progress.Progress (add_task, update, console, a context), printing
    `line(task)` - task: description, completed, total and the fields given - as plain lines."""

    def __init__(self, console: Console, line: Callable[[dict], str], every_update: bool = False):
        self.console = console
        self._line = line
        self._every_update = every_update
        self._tasks: list[dict] = []

    def __enter__(self) -> PlainProgress:
        return self

    def __exit__(self, *exc) -> None:
        for task in self._tasks:
            if task["_printed_at"] != task["completed"]:  # the last state, if not printed yet
                self._print(task)

    def add_task(self, description: str, total: int, completed: int = 0, **fields) -> int:
        now = time.monotonic()
        # The printer's own state sits under keys starting with "_", apart from the caller's fields
        # (the experiment's field is called "last").
        self._tasks.append({**fields, "description": description, "total": total, "completed": completed,
                            "_started": now, "_start_completed": completed, "_printed_time": now,
                            "_printed_at": None})  # fmt: skip
        self._print(self._tasks[-1])
        return len(self._tasks) - 1

    def update(self, task_id: int, completed: int | None = None, advance: int = 0, **fields) -> None:
        task = self._tasks[task_id]
        task["completed"] = (task["completed"] if completed is None else completed) + advance
        task.update(fields)
        now = time.monotonic()
        if self._every_update or now - task["_printed_time"] >= PLAIN_INTERVAL_S or task["completed"] >= task["total"]:
            self._print(task)

    def _print(self, task: dict) -> None:
        now = time.monotonic()
        task["_printed_time"], task["_printed_at"] = now, task["completed"]
        elapsed = now - task["_started"]
        done = task["completed"] - task["_start_completed"]
        left = task["total"] - task["completed"]
        eta = clock(elapsed / done * left) if done > 0 else "-"
        self.console.print(
            f"{self._line(task)}  elapsed {clock(elapsed)}  ETA {eta}", highlight=False, markup=False, soft_wrap=True
        )
        self.console.file.flush()


def progress_for(
    console: Console, counts: str, fields: str, line: Callable[[dict], str], every_update=False, eta: str = "ETA"
):
    """Rich's bar where `console` is a terminal - the description, the bar, `counts`, elapsed time, `eta`
    and the remaining time, then `fields` (rich column templates) -; else PlainProgress printing `line(task)`."""
    if not console.is_terminal:
        return PlainProgress(console, line, every_update)
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn(counts),
        TimeElapsedColumn(),
        TextColumn(eta),
        TimeRemainingColumn(),
        TextColumn(fields),
        console=console,
    )


class StageLog:
    """A pipeline's log (`log(line)`), each line printed and flushed as it comes. Used as a context,
    where `console` is not a terminal, it also prints `<name>: still running (last: <the last line>)`
    with the elapsed time after every PLAIN_INTERVAL_S without a line, from a thread: the silent
    stages are native calls that release the GIL."""

    def __init__(self, console: Console, name: str):
        self.console = console
        self._name = name
        self._lock = threading.Lock()
        self._started = self._last = time.monotonic()
        self._last_line = "started"
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None

    def __call__(self, line: str) -> None:
        with self._lock:
            self._last, self._last_line = time.monotonic(), line
            self._print(line)

    def __enter__(self) -> StageLog:
        if not self.console.is_terminal:
            self._ticker = threading.Thread(target=self._tick, name=f"{self._name} progress", daemon=True)
            self._ticker.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()

    def _tick(self) -> None:
        while not self._stop.wait(min(PLAIN_INTERVAL_S, 1.0)):
            with self._lock:
                now = time.monotonic()
                if now - self._last < PLAIN_INTERVAL_S:
                    continue
                self._last = now
                line = f"{self._name}: still running (last: {self._last_line})  elapsed {clock(now - self._started)}"
                try:
                    self._print(line)
                except OSError:  # the reader is gone: the command meets it at its own next line (cli: 141)
                    return

    def _print(self, line: str) -> None:
        self.console.print(line, highlight=False, markup=False, emoji=False, soft_wrap=True)
        self.console.file.flush()
