"""The phone-camera checks on a camera solve: each warning names what is off, the frames, and what to try."""

from __future__ import annotations

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
