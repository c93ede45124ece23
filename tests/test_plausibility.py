"""The phone-camera checks on a camera solve: each warning names what is off, the frames, and what to try."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from liquidgs.data.plausibility import lens_warnings, path_warnings, points_warnings


@pytest.mark.parametrize(
    ("params", "expected"),
    [
        ([640.0, 320.0, 180.0, 0.02], []),  # a phone's main camera: f 1.0x the longer side
        ([330.0, 320.0, 180.0, -0.2], []),  # ultra-wide, barrel
        ([300.0, 320.0, 180.0, 0.0], ["focal length 300 px is 0.47x the longer side of 640 px"]),
        ([2000.0, 320.0, 180.0, 0.0], ["focal length 2000 px is 3.12x"]),
        ([965.0, 360.0, 203.0, 0.35], ["radial distortion k1 +0.350 is beyond a phone's"]),  # the dog clip
        ([640.0, 320.0, 180.0, -0.26], ["radial distortion k1 -0.260"]),
    ],
)
def test_the_lens_is_held_to_a_phones(params, expected):
    width = 720 if params[0] == 965.0 else 640
    warnings = lens_warnings("SIMPLE_RADIAL", params, width, 360)
    assert len(warnings) == len(expected), warnings
    for warning, start in zip(warnings, expected):
        assert warning.startswith(start), warning


def test_a_jump_in_the_camera_path_names_the_frames():
    names = [f"{n:06d}" for n in range(20)]
    centres = np.stack([np.linspace(0.0, 1.9, 20), np.zeros(20), np.zeros(20)], axis=1)
    assert path_warnings(names, centres) == []
    centres[12:] += [0.0, 0.6, 0.0]  # 6x the 0.1 step between frames 11 and 12
    (warning,) = path_warnings(names, centres)
    assert "between frames 000011->000012:" in warning and "sample more frames" in warning
    centres[12:] -= [0.0, 0.35, 0.0]  # under 5x: a fast, but smooth, move
    assert path_warnings(names, centres) == []


def test_frames_that_see_few_points_are_named():
    names = ["a", "b", "c", "d"]
    assert points_warnings(names, [500, 30, 400, 300]) == []
    (warning,) = points_warnings(names, [500, 29, 400, 3])
    assert warning.startswith("2 frame(s) see fewer than 30 triangulated points") and ": b, d;" in warning


class _Camera:
    model_name, width, height = "SIMPLE_RADIAL", 368, 480

    def __init__(self, k1: float):
        self.params = [505.0, 184.0, 240.0, k1]


class _Model:
    """What colmap._with_lens_held reads of a pycolmap Reconstruction, with its warnings."""

    def __init__(self, k1: float, warnings: list[str]):
        self.cameras, self.warnings = {1: _Camera(k1)}, warnings


def _lens_held(monkeypatch, suspect: _Model, held: _Model | Exception):
    """colmap._with_lens_held with the re-run's mapping and checks replaced: (the Solved, the re-run's attempts)."""
    from liquidgs.data import colmap
    from liquidgs.data.stage_times import StageTimes

    reruns = []

    def fake_map(pycolmap, database, frames, sparse, attempt, total, options, log):
        reruns.append(attempt)
        return held, False

    def fake_check(model, total, share):
        if isinstance(model, Exception):
            raise model

    monkeypatch.setattr(colmap, "_map", fake_map)
    monkeypatch.setattr(colmap, "check_model", fake_check)
    monkeypatch.setattr(colmap, "model_warnings", lambda model: model.warnings)
    attempt = colmap.Attempt("incremental mapper", "sequential", "the first")
    solved = colmap._with_lens_held(None, None, None, Path("/nonexistent"), suspect, attempt, suspect.warnings, 80,
                                    colmap.SolveOptions(), lambda line: None, [], StageTimes())  # fmt: skip
    return solved, reruns


def test_a_lens_like_a_phones_is_not_run_again(monkeypatch):
    suspect = _Model(-0.05, ["a jump in the camera path"])
    solved, reruns = _lens_held(monkeypatch, suspect, _Model(0.0, []))
    assert reruns == [] and solved.model is suspect and solved.warnings == ["a jump in the camera path"]


def test_a_suspect_lens_is_run_again_held_and_the_better_model_is_used(monkeypatch):
    suspect = _Model(0.7, ["radial distortion k1 +0.700 is beyond a phone's"])
    better = _Model(0.0, [])
    solved, reruns = _lens_held(monkeypatch, suspect, better)
    assert [attempt.hold_distortion for attempt in reruns] == [True]
    assert solved.model is better and solved.attempt == "lens held" and solved.warnings == []
    assert [record["result"] for record in solved.attempts] == ["used"]
    worse = _Model(0.0, ["one", "two"])  # more warnings held than fitted: the fitted lens stays
    solved, _ = _lens_held(monkeypatch, suspect, worse)
    assert solved.model is suspect and solved.attempt == "incremental mapper"


def test_a_suspect_lens_whose_held_re_run_finds_no_depth_is_refused(monkeypatch):
    from liquidgs.data.colmap import NoDepthError, SolveError

    suspect = _Model(1.08, ["radial distortion k1 +1.080 is beyond a phone's"])
    with pytest.raises(NoDepthError, match=r"k1 \+1\.080, not a phone's\) COLMAP made up depth"):
        _lens_held(monkeypatch, suspect, NoDepthError("the camera seems to turn in place"))
    solved, _ = _lens_held(monkeypatch, suspect, SolveError("COLMAP registered only 3 of 80 frames"))
    assert solved.model is suspect  # refused for another reason: the fitted model stays, with its warnings
