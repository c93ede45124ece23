"""Clips COLMAP cannot solve: one line saying what failed and what to try, and no scene left behind.

(A blank wall is in test_data_video.py's bad-input test.)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from liquidgs.cli import main as cli
from liquidgs.data.synthetic import render_rgba
from liquidgs.media import write_video
from video_scene import BACKGROUND, FOCAL, FPS, HEIGHT, WIDTH, moving_ball, render_handheld_video, sweeping_camera


def one_line_failure(capsys, args: list[str], out: Path) -> str:
    assert cli([*args, "--out", str(out), "--threads", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert not out.exists() and not list(out.parent.glob(f".{out.name}*"))
    return err


@pytest.mark.slow  # three COLMAP attempts, about 20 s of CPU
def test_a_camera_turning_in_place_is_named_as_the_cause_after_every_attempt(tmp_path, capsys):
    K = np.array([[FOCAL, 0.0, WIDTH / 2], [0.0, FOCAL, HEIGHT / 2], [0.0, 0.0, 1.0]])
    prims = [moving_ball(0.3), *BACKGROUND]
    poses = sweeping_camera(16, baseline=0.0, pan_degrees=30.0)
    images = [render_rgba(prims, K, pose, WIDTH, HEIGHT, 1)[..., :3] for pose in poses]
    clip = tmp_path / "pan.mp4"
    write_video(clip, images, fps=FPS)
    args = ["data", "video", str(clip), "--frames", "16", "--out", str(tmp_path / "scene"), "--threads", "1"]
    assert cli([*args, "--mapper", "incremental"]) == 2
    out, err = capsys.readouterr()
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not list(tmp_path.glob("*scene*"))
    assert "the camera seems to turn in place" in err and "walk sideways around the subject" in err
    assert "[COLMAP tried: default, exhaustive matching, relaxed initial pair]" in err
    # No attempt, the relaxed one included, passes off a model of the pan as a solve.
    for number, name in enumerate(("default", "exhaustive matching", "relaxed initial pair"), 1):
        assert f"attempt {number} of 3 ({name}) refused: " in out, out
    assert "succeeded" not in out


@pytest.mark.slow  # COLMAP on 10 frames, about 4 s of CPU
def test_a_short_pan_whose_depth_comes_from_a_made_up_lens_is_refused(tmp_path, capsys):
    """On 10 frames of the same pan, exhaustive matching gives COLMAP a model of 6 frames and 501 points - with
    a radial distortion of k1 +1.08 that no phone has. Re-run with the distortion held at 0 it triangulates
    5 points: the depth came from the lens, and the clip is refused as the camera turning in place."""
    K = np.array([[FOCAL, 0.0, WIDTH / 2], [0.0, FOCAL, HEIGHT / 2], [0.0, 0.0, 1.0]])
    prims = [moving_ball(0.3), *BACKGROUND]
    poses = sweeping_camera(10, baseline=0.0, pan_degrees=30.0)
    clip = tmp_path / "pan.mp4"
    write_video(clip, [render_rgba(prims, K, pose, WIDTH, HEIGHT, 1)[..., :3] for pose in poses], fps=FPS)
    args = ["data", "video", str(clip), "--frames", "10", "--mapper", "incremental"]
    err = one_line_failure(capsys, args, tmp_path / "scene")
    assert "the camera seems to turn in place" in err and "COLMAP made up depth the frames do not show" in err
    assert "k1 +1.0" in err or "k1 +1.1" in err, err


@pytest.mark.parametrize("frames", ["2", "3"])
def test_too_few_frames_are_refused_before_colmap(frames, tmp_path, capsys):
    clip = tmp_path / "clip.mp4"
    write_video(clip, [np.full((48, 64, 3), 90, np.uint8)] * 6, fps=FPS)
    err = one_line_failure(capsys, ["data", "video", str(clip), "--frames", frames], tmp_path / "scene")
    assert f"--frames must be at least 4 (COLMAP needs that many), got {frames}" in err


def test_a_three_frame_video_or_image_folder_is_refused(tmp_path, capsys):
    video = render_handheld_video(tmp_path / "short.mp4", 3)
    err = one_line_failure(capsys, ["data", "video", str(video.path)], tmp_path / "scene")
    assert "short.mp4: gives 3 frame(s); solving cameras needs at least 4" in err
    folder = tmp_path / "images"
    folder.mkdir()
    for index, image in enumerate(video.images):
        Image.fromarray(image).save(folder / f"{index}.png")
    err = one_line_failure(capsys, ["data", "images", str(folder)], tmp_path / "scene2")
    assert "gives 3 frame(s); solving cameras needs at least 4 (more images)" in err


def test_a_still_image_repeated_is_refused_before_colmap(tmp_path, capsys):
    video = render_handheld_video(tmp_path / "one.mp4", 4)
    clip = tmp_path / "still.mp4"
    write_video(clip, [video.images[1]] * 12, fps=FPS)
    err = one_line_failure(capsys, ["data", "video", str(clip), "--frames", "12"], tmp_path / "scene")
    assert "still.mp4: its 12 frames show one still picture" in err and "film while walking around" in err
    assert "features:" not in capsys.readouterr().out


@pytest.mark.slow  # COLMAP's attempts on 16 frames, about 30 s of CPU
def test_a_cut_between_two_shots_is_named_with_its_frames(tmp_path, capsys):
    first = render_handheld_video(tmp_path / "first.mp4", 8).images
    # The second shot: a camera sliding over a wholly different textured picture.
    rng = np.random.default_rng(0)
    picture = np.kron(rng.integers(0, 256, (HEIGHT // 4 + 2, WIDTH // 4 + 12, 3)), np.ones((4, 4, 1))).astype(np.uint8)
    second = [np.ascontiguousarray(picture[4 : HEIGHT + 4, 5 * n : 5 * n + WIDTH]) for n in range(8)]
    folder = tmp_path / "images"
    folder.mkdir()
    for index, image in enumerate([*first, *second]):
        Image.fromarray(image).save(folder / f"{index:02d}.png")
    err = one_line_failure(capsys, ["data", "images", str(folder)], tmp_path / "scene")
    assert "no frame up to 000007 shares verified matches with any frame from 000008 on" in err, err
    assert "a cut (two shots)" in err and "register each shot on its own" in err
