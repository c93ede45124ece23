"""Stage timing: each stage's own seconds, a stage inside another taken off the enclosing one."""

from __future__ import annotations

import time

from liquidgs.data.stage_times import StageTimes


def busy(seconds: float) -> None:
    end = time.process_time() + seconds
    while time.process_time() < end:
        pass


def test_a_nested_stage_counts_once_and_repeated_stages_add_up():
    times = StageTimes()
    with times.stage("writing"):
        busy(0.05)
        with times.stage("undistortion"):
            busy(0.15)
    with times.stage("writing"):
        busy(0.05)
    assert list(times.wall) == ["undistortion", "writing"]
    assert 0.14 <= times.cpu["undistortion"] <= 0.3 and 0.09 <= times.cpu["writing"] < 0.15, times.cpu
    assert times.wall["writing"] >= 0.09 and times.wall["undistortion"] >= 0.14
    record = times.record()
    assert set(record) == {"wall", "cpu"} and record["cpu"]["writing"] == round(times.cpu["writing"], 2)
    assert times.line().count("s CPU)") == 3 and "; total " in times.line()
