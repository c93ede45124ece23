"""Wall and CPU seconds per stage of a run (features, matching, mapping, ...), for the log and capture.json.

CPU time is this process's (every thread: COLMAP's, OpenCV's) plus its finished children's (ffmpeg),
so on a shared machine it says how much work a stage was where wall time says how long it waited.
"""

from __future__ import annotations

import resource
import time
from collections.abc import Iterator
from contextlib import contextmanager


def cpu_seconds() -> float:
    total = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        usage = resource.getrusage(who)
        total += usage.ru_utime + usage.ru_stime
    return total


class StageTimes:
    """Seconds per stage, summed over every time a stage runs (matching and mapping run per attempt).
    A stage run inside another is counted as itself only: its seconds are taken off the enclosing one."""

    def __init__(self) -> None:
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self._open: list[str] = []

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        wall, cpu = time.perf_counter(), cpu_seconds()
        self._open.append(name)
        try:
            yield
        finally:
            self._open.pop()
            spent_wall, spent_cpu = time.perf_counter() - wall, cpu_seconds() - cpu
            self.wall[name] = self.wall.get(name, 0.0) + spent_wall
            self.cpu[name] = self.cpu.get(name, 0.0) + spent_cpu
            if self._open:
                outer = self._open[-1]
                self.wall[outer] = self.wall.get(outer, 0.0) - spent_wall
                self.cpu[outer] = self.cpu.get(outer, 0.0) - spent_cpu

    def merge(self, other: StageTimes) -> None:
        for name in other.wall:
            self.wall[name] = self.wall.get(name, 0.0) + other.wall[name]
            self.cpu[name] = self.cpu.get(name, 0.0) + other.cpu[name]

    def record(self) -> dict[str, dict[str, float]]:
        """{"wall": {stage: s}, "cpu": {stage: s}}, rounded to 10 ms, for capture.json."""
        return {
            "wall": {name: round(value, 2) for name, value in self.wall.items()},
            "cpu": {name: round(value, 2) for name, value in self.cpu.items()},
        }

    def line(self) -> str:
        """'features 4.9 s (9.7 s CPU), matching ...; total 31.2 s (40.1 s CPU)'."""
        stages = ", ".join(f"{name} {self.wall[name]:.1f} s ({self.cpu[name]:.1f} s CPU)" for name in self.wall)
        return f"{stages}; total {sum(self.wall.values()):.1f} s ({sum(self.cpu.values()):.1f} s CPU)"
