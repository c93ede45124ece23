"""Progress a person can follow: rich's live bar on a terminal; where the output goes to a file or a
pipe (a job in the background, its log), plain lines instead - one at the start, one at most every
PLAIN_INTERVAL_S seconds, one at the end - each with the counts, elapsed time and ETA, flushed as
written. rich prints nothing of a live bar to a file until it stops, so a long run's log stayed empty."""

from __future__ import annotations

import time
from collections.abc import Callable

from rich.console import Console
from rich.progress import Progress

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
            if task["printed_at"] != task["completed"]:  # the last state, if not printed yet
                self._print(task)

    def add_task(self, description: str, total: int, completed: int = 0, **fields) -> int:
        now = time.monotonic()
        self._tasks.append({"description": description, "total": total, "completed": completed, "started": now,
                            "start_completed": completed, "last": now, "printed_at": None, **fields})  # fmt: skip
        self._print(self._tasks[-1])
        return len(self._tasks) - 1

    def update(self, task_id: int, completed: int | None = None, advance: int = 0, **fields) -> None:
        task = self._tasks[task_id]
        task["completed"] = (task["completed"] if completed is None else completed) + advance
        task.update(fields)
        now = time.monotonic()
        if self._every_update or now - task["last"] >= PLAIN_INTERVAL_S or task["completed"] >= task["total"]:
            self._print(task)

    def _print(self, task: dict) -> None:
        now = time.monotonic()
        task["last"], task["printed_at"] = now, task["completed"]
        elapsed = now - task["started"]
        done = task["completed"] - task["start_completed"]
        left = task["total"] - task["completed"]
        eta = clock(elapsed / done * left) if done > 0 else "-"
        self.console.print(
            f"{self._line(task)}  elapsed {clock(elapsed)}  ETA {eta}", highlight=False, markup=False, soft_wrap=True
        )
        self.console.file.flush()


def progress_for(console: Console, live: Callable[[], Progress], line: Callable[[dict], str], every_update=False):
    """`live()`, rich's bar, where `console` is a terminal; else PlainProgress printing `line(task)`."""
    return live() if console.is_terminal else PlainProgress(console, line, every_update)
