"""`liquidgs data video` / `data images` on a rendered handheld video whose cameras are known.

Measured on the 2-core CPU (pycolmap 4.2.1), 32 frames at 200x152 through H.264, every frame
registered; after a similarity onto the truth, the camera centres are off by 0.0056 RMS over a
4.47-long path (0.12%) and the orientations by at most 0.19 degrees with one COLMAP thread (as
here); 0.0071-0.0076 and 0.33 degrees with all cores. The focal length (190 px) is the loosest:
196.0 px with one thread, 202.8 with all cores, as it trades off against the fitted radial
distortion on a 56-degree field of view. The tolerances leave 2-3x room on the worst.

The same video rendered through a phone-like barrel lens (SIMPLE_RADIAL, k1 = -0.15; 16 frames):
COLMAP recovers the lens, `data video` undistorts the frames into a pinhole camera (camera files
with zero distortion), `--keep-distortion` keeps them and k1, and `data undistort` on the kept
scene writes the same scene as the default run.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from liquidgs.data import DataConfig, check_dataset, load_dataset
from liquidgs.data.capture import CaptureSettings, capture_scene
from liquidgs.data.colmap import SolveOptions
from liquidgs.data.optical_flow import chain_flow
from liquidgs.data.pose_accuracy import scene_poses, score_poses, score_scenes, similarity
from liquidgs.data.synthetic import render_rgba
from liquidgs.data.video import extract_video_frames
from liquidgs.media import write_video
from shared_data import require_module
from tiny_runs import run_cli
from video_scene import FOCAL, Lens, render_handheld_video, scene_at

FRAMES = 32
MAX_PATH_ERROR = 0.005  # aligned camera-centre RMSE, as a share of the true path's length
MAX_ROTATION_ERROR_DEG = 1.0
MAX_FOCAL_ERROR = 0.15
IMAGES = 20  # the image-folder run: the first 20 frames, and a blank one among them
BLANK_AT = 10
PHONE_LENS = Lens(k1=-0.15)  # barrel distortion as a phone's main camera shows it; SIMPLE_RADIAL's model
DISTORTED_FRAMES = 16

# COLMAP on rendered videos in the fixtures and two 500-iteration trainings, about 30 s for the
# file: left out of `make test-fast`.
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def handheld(tmp_path_factory):
    return render_handheld_video(tmp_path_factory.mktemp("video") / "handheld.mp4", FRAMES)


@pytest.fixture(scope="module")
def pycolmap():
    """COLMAP's wheels, which solve the cameras (the colmap / dev extra)."""
    return require_module("pycolmap")


def register_handheld(handheld, out: Path, *extra: str) -> tuple[Path, str]:
    """`data video` on the rendered clip, all its frames at 200 px, one COLMAP thread: (scene, stdout)."""
    code, stdout, stderr = run_cli(
        ["data", "video", str(handheld.path), "--out", str(out), "--frames", str(FRAMES), "--max-size", "200",
         "--threads", "1", *extra]
    )  # fmt: skip
    assert code == 0, stderr
    return out, stdout


@pytest.fixture(scope="module")
def video_scene(pycolmap, handheld, tmp_path_factory):
    return register_handheld(handheld, tmp_path_factory.mktemp("scenes") / "handheld")


@pytest.fixture(scope="module")
def old_pipeline_scene(pycolmap, handheld, tmp_path_factory):
    """The same video through the pipeline as it was: the incremental mapper, features everywhere."""
    out = tmp_path_factory.mktemp("scenes") / "old"
    return register_handheld(handheld, out, "--mapper", "incremental", "--no-flow", "--keyframe-every", "1")


@pytest.fixture(scope="module")
def flow_masked_scene(pycolmap, handheld, tmp_path_factory):
    """The old pipeline with --mask-moving: no features where the two-view motion masks see motion."""
    out = tmp_path_factory.mktemp("scenes") / "masked"
    return register_handheld(handheld, out, "--mapper", "incremental", "--mask-moving", "--no-flow")


@pytest.fixture(scope="module")
def image_scene(pycolmap, handheld, tmp_path_factory):
    """The first frames as an image folder with a blank frame among them, and masks of the figure."""
    root = tmp_path_factory.mktemp("images")
    images, masks = root / "images", root / "masks"
    images.mkdir()
    masks.mkdir()
    sources = list(range(BLANK_AT)) + [None] + list(range(BLANK_AT, IMAGES - 1))
    for position, source in enumerate(sources):
        name = f"frame{position}.png"  # natural order: frame2 before frame10
        if source is None:
            Image.new("RGB", handheld.images[0].shape[1::-1], (128, 128, 128)).save(images / name)
            Image.new("L", handheld.images[0].shape[1::-1], 0).save(masks / name)
        else:
            Image.fromarray(handheld.images[source]).save(images / name)
            Image.fromarray(handheld.dynamic_masks[source].astype(np.uint8) * 255).save(masks / name)
    out = root / "scene"
    # --keep-distortion: the keypoints stay where COLMAP found them, on the frames as rendered, so
    # that they can be checked against the rendered masks.
    code, stdout, stderr = run_cli(
        ["data", "images", str(images), "--out", str(out), "--mask-dynamic", str(masks), "--threads", "1",
         "--keep-distortion", "--no-flow"]
    )  # fmt: skip
    assert code == 0, stderr
    return out, stdout, sources


@pytest.fixture(scope="module")
def distorted_scenes(pycolmap, tmp_path_factory):
    """The handheld video through PHONE_LENS, made into a scene by default and with --keep-distortion, both
    with the incremental mapper: the global one recovers this lens less well (measured: undistorted frames
    off their pinhole render by 16.6 at the border and 12.6 at the centre, against 13.5 and 11.0), so that
    undistorting buys 2.8 at the border where the test holds the incremental mapper to 5."""
    root = tmp_path_factory.mktemp("distorted")
    video = render_handheld_video(root / "phone.mp4", DISTORTED_FRAMES, PHONE_LENS)
    scenes, stdouts = {}, {}
    for name, extra in (("undistorted", []), ("kept", ["--keep-distortion"])):
        scenes[name] = root / name
        code, stdouts[name], stderr = run_cli(
            ["data", "video", str(video.path), "--out", str(scenes[name]), "--frames", str(DISTORTED_FRAMES),
             "--max-size", "200", "--threads", "1", "--mapper", "incremental", *extra]
        )  # fmt: skip
        assert code == 0, stderr
    return video, scenes, stdouts


def cameras(scene: Path) -> tuple[list[str], np.ndarray, np.ndarray]:
    ids = json.loads((scene / "dataset.json").read_text())["ids"]
    files = [json.loads((scene / "camera" / f"{i}.json").read_text()) for i in ids]
    return ids, np.array([f["position"] for f in files]), np.array([f["orientation"] for f in files])


def centre_error(scene: Path, truth: np.ndarray, frame_of_id) -> tuple[float, float]:
    """(RMSE of the camera centres after a similarity onto the truth, length of the true path)."""
    ids, centres, _ = cameras(scene)
    true_centres = truth[[frame_of_id(i) for i in ids], :3, 3]
    scale, rotation, shift = similarity(centres, true_centres)
    moved = centres @ (scale * rotation).T + shift
    rmse = float(np.sqrt(np.mean(np.sum((moved - true_centres) ** 2, axis=1))))
    return rmse, float(np.sum(np.linalg.norm(np.diff(true_centres, axis=0), axis=1)))


def test_every_frame_is_registered_and_the_stages_report_counts(video_scene):
    out, stdout = video_scene
    capture = json.loads((out / "capture.json").read_text())
    assert capture["frames_total"] == capture["frames_registered"] == FRAMES and capture["dropped"] == []
    assert capture["camera_solve"]["attempt"] == "global mapper" and len(capture["camera_solve"]["attempts"]) == 1
    assert "camera solve: attempt 1 of 4 (global mapper) succeeded" in stdout
    assert capture["camera_solve"]["warnings"] == [] and "warning" not in stdout
    # COLMAP solves every second frame and the last (17 of 32: every third would leave fewer than 16); the 15
    # between are placed, none left out.
    keyframes = capture["camera_solve"]["keyframes"]
    assert keyframes["every"] == 2 and keyframes["keyframes"] == 17 and keyframes["placed"] == FRAMES - 17
    assert keyframes["unplaced"] == [] and keyframes["fewest_inliers"] >= 30
    assert " in 17 frames from" in stdout
    logged = ("extraction:", "features:", "matching (sequential):", "mapping (global):", "placing:", "writing:")
    for stage in logged:
        assert stage in stdout, stdout
    # Every stage timed, wall and CPU, in the log and in capture.json.
    stages = ["extraction", "features", "matching", "mapping", "placing", "undistortion", "writing", "flow"]
    assert list(capture["seconds"]) == list(capture["cpu_seconds"]) == stages
    assert all(value >= 0 for value in [*capture["seconds"].values(), *capture["cpu_seconds"].values()])
    assert capture["cpu_seconds"]["features"] > 0 and capture["seconds"]["mapping"] > 0
    time_line = next(line for line in stdout.splitlines() if line.startswith("time: extraction"))
    assert time_line.count("s CPU)") == len(stages) + 1  # each stage, and the total
    assert f"done: {FRAMES}/{FRAMES} frames registered, mean reprojection error" in stdout
    assert capture["mean_reprojection_error_px"] < 1.0
    assert f"train: liquidgs train --data {out} --field mlp" in stdout
    assert not [p for p in out.parent.iterdir() if ".partial-" in p.name]


def orientation_errors(scene: Path, truth: np.ndarray, frame_of_id) -> np.ndarray:
    """Degrees between each camera's orientation and the truth's, after the best common rotation."""
    # With x_true = s R x_ours + t, the true world->camera rotation is ours times R^T. R from the
    # orientations themselves (the centres lie near a plane, which leaves it loose).
    ids, _, orientations = cameras(scene)
    truths = truth[[frame_of_id(i) for i in ids], :3, :3].transpose(0, 2, 1)
    u, _, vt = np.linalg.svd(np.einsum("nji,njk->ik", truths, orientations))
    rotation = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    cosines = (np.einsum("nji,njk,lk->nil", truths, orientations, rotation).trace(axis1=1, axis2=2) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cosines, -1.0, 1.0)))


def test_camera_centres_and_orientations_match_the_truth_after_a_similarity(video_scene, handheld):
    out, _ = video_scene
    rmse, path_length = centre_error(out, handheld.cam_to_world, int)
    print(f"aligned camera-centre RMSE {rmse:.4f} over a path of {path_length:.3f}")
    assert rmse <= MAX_PATH_ERROR * path_length, (rmse, path_length)
    errors = orientation_errors(out, handheld.cam_to_world, int)
    print("orientation errors (deg):", errors.max())
    assert errors.max() <= MAX_ROTATION_ERROR_DEG, errors

    focal = json.loads((out / "camera" / "000000.json").read_text())["focal_length"]
    assert abs(focal / FOCAL - 1.0) <= MAX_FOCAL_ERROR, focal


def test_times_follow_frame_order_and_data_check_passes_at_every_scale(video_scene):
    out, _ = video_scene
    metadata = json.loads((out / "metadata.json").read_text())
    assert [metadata[i]["time_id"] for i in sorted(metadata)] == list(range(FRAMES))
    width, height = json.loads((out / "camera" / "000000.json").read_text())["image_size"]
    assert width % 4 == 0 and height % 4 == 0 and width <= 200 * 1.1 and height <= 152 * 1.1, (width, height)
    for downscale in (1, 2, 4):
        report = check_dataset(DataConfig(path=out, downscale=downscale))
        frames = sorted(report.dataset.train + report.dataset.test, key=lambda frame: frame.name)
        times = [frame.time for frame in frames]
        assert times == pytest.approx([n / (FRAMES - 1) for n in range(FRAMES)])
        assert report.images_decoded == FRAMES
        assert (frames[0].camera.width, frames[0].camera.height) == (width // downscale, height // downscale)
    dataset = json.loads((out / "dataset.json").read_text())
    assert dataset["val_ids"] == [f"{n:06d}" for n in range(4, FRAMES, 8)]  # every 8th, stated in docs/own-video.md
    assert json.loads((out / "capture.json").read_text())["holdout_every"] == 8
    code, stdout, _ = run_cli(["data", "check", str(out)])
    assert code == 0 and f"frames:     train {FRAMES - 4}, test 4" in stdout


def test_an_image_folder_drops_the_frame_colmap_cannot_register_and_keeps_the_others_times(image_scene, handheld):
    out, stdout, sources = image_scene
    capture = json.loads((out / "capture.json").read_text())
    assert capture["dropped"] == [{"id": f"{BLANK_AT:06d}", "source": f"frame{BLANK_AT}.png"}], capture
    assert f"done: {IMAGES - 1}/{IMAGES} frames registered (1 dropped" in stdout
    assert f"dropped: frame{BLANK_AT}.png" in stdout
    with pytest.warns(UserWarning, match="nonzero lens distortion"):  # made with --keep-distortion
        dataset = load_dataset(DataConfig(path=out))
    times = {frame.name: frame.time for frame in dataset.train + dataset.test}
    assert len(times) == IMAGES - 1 and f"{BLANK_AT:06d}" not in times
    assert times == pytest.approx({f"{n:06d}": n / (IMAGES - 1) for n in range(IMAGES) if n != BLANK_AT})
    rmse, path_length = centre_error(out, handheld.cam_to_world, lambda image_id: sources[int(image_id)])
    assert rmse <= MAX_PATH_ERROR * path_length, (rmse, path_length)


def keypoints_on_figure(scene: Path, handheld, frame_of_id) -> int:
    """Keypoints (COLMAP's model keeps every one) on the pixels the moving figure covers."""
    model = require_module("pycolmap").Reconstruction(scene / "colmap" / "sparse")
    count = 0
    for image in model.images.values():
        mask = handheld.dynamic_masks[frame_of_id(Path(image.name).stem)]
        xy = np.array([point.xy for point in image.points2D]).astype(int)
        count += int(mask[xy[:, 1], xy[:, 0]].sum())
    return count


def test_no_flow_leaves_the_scene_without_flow(image_scene):
    out, stdout, _ = image_scene
    assert not (out / "flow").exists() and "flow" not in stdout.split("time:")[1].splitlines()[0]


def test_mask_dynamic_keeps_every_feature_off_the_moving_figure(image_scene, old_pipeline_scene, handheld):
    out, stdout, sources = image_scene
    assert "masks: 20 frames" in stdout
    assert keypoints_on_figure(old_pipeline_scene[0], handheld, int) >= 100  # unmasked: many
    assert keypoints_on_figure(out, handheld, lambda image_id: sources[int(image_id)]) == 0


def test_flow_masks_keep_some_features_off_the_moving_figure(flow_masked_scene, old_pipeline_scene, handheld):
    """No masks given: the two-view motion masks of data.motion_masks keep COLMAP's features off some of the ball.
    Measured (one thread): 1392 keypoints on it with the masks, 1727 without (-19%): like the scene's
    masks (test_the_scene_has_flow_and_motion_masks_that_find_the_ball) they miss the ball where it
    rolls the way the camera slides, along the epipolar lines."""
    out, stdout = flow_masked_scene
    assert "feature masks: " in stdout and "% of pixels seen moving on average (no features there)" in stdout
    assert json.loads((out / "capture.json").read_text())["feature_masks"] == "flow"
    assert json.loads((old_pipeline_scene[0] / "capture.json").read_text())["feature_masks"] == "none"
    masked, unmasked = (keypoints_on_figure(scene, handheld, int) for scene in (out, old_pipeline_scene[0]))
    print(f"keypoints on the ball: {masked} with flow masks, {unmasked} without")
    assert masked <= 0.9 * unmasked, (masked, unmasked)


def test_the_global_mapper_is_as_accurate_as_the_old_pipeline_against_the_truth(
    video_scene, old_pipeline_scene, handheld
):
    """The issue's bar: centre RMS and relative rotation within 10% of the old pipeline's (or better).
    Measured (one thread, shared 2-core VM): global 0.0034 (0.08% of the path), 0.064 degrees mean;
    incremental 0.0041, 0.075 degrees. With --mask-moving both were worse: 0.0051 and 0.0059. With the
    verification seeded (91eb5f0; before, each run drew its own RANSAC samples): global 0.0044, 0.080;
    incremental 0.0053, 0.096. The global mapper's bundle adjustment without its fixed-rotation stage
    (GLOBAL_BA_WITHOUT_FIXED_ROTATIONS): 0.0044, 0.080 again."""
    truth = handheld.cam_to_world
    scores = {}
    for name, (scene, _) in (("new", video_scene), ("old", old_pipeline_scene)):
        poses = scene_poses(scene)
        scores[name] = score_poses(np.stack(list(poses.values())), truth[[int(i) for i in poses]])
        print(name, scores[name].describe())
    assert scores["new"].frames == scores["old"].frames == FRAMES
    assert scores["new"].centre_rms <= 1.1 * scores["old"].centre_rms
    assert scores["new"].relative_rotation_mean_deg <= 1.1 * scores["old"].relative_rotation_mean_deg


def test_matching_along_the_flow_is_as_accurate_as_the_old_pipeline(video_scene, old_pipeline_scene, handheld,
                                                                    tmp_path):  # fmt: skip
    """--matcher flow (data.flow_matches): each feature compared only with those near where the optical flow
    carries it, every pair verified at 1 px; within 10% of the old pipeline against the truth, as the
    default is. Measured (one thread): 0.0040 (0.09% of the path), 0.070 degrees mean (0.069 without the
    bundle adjustment's fixed-rotation stage); the incremental mapper's run beside it 0.0053, 0.096 (the
    verification seeded, 91eb5f0)."""
    out, stdout = register_handheld(handheld, tmp_path / "flow", "--matcher", "flow", "--no-flow")
    assert "matching (flow): " in stdout and "attempt 1 of 4 (global mapper): flow matching" in stdout
    truth = handheld.cam_to_world
    scores = {}
    for name, scene in (("flow", out), ("old", old_pipeline_scene[0])):
        poses = scene_poses(scene)
        scores[name] = score_poses(np.stack(list(poses.values())), truth[[int(i) for i in poses]])
        print(name, scores[name].describe())
    assert scores["flow"].frames == FRAMES
    assert scores["flow"].centre_rms <= 1.1 * scores["old"].centre_rms
    assert scores["flow"].relative_rotation_mean_deg <= 1.1 * scores["old"].relative_rotation_mean_deg


def keypoints_per_frame(stdout: str) -> float:
    """From the log's 'features: N SIFT keypoints in M frames ...' line."""
    words = next(line for line in stdout.splitlines() if line.startswith("features: ")).split()
    return int(words[1]) / int(words[5])


def test_fast_features_take_coarser_keypoints_and_still_find_the_cameras(video_scene, handheld, tmp_path):
    """--fast-features skips COLMAP's doubled first octave: far fewer keypoints (the finest scale is gone),
    and cameras still within the tolerances against the truth. Measured (one thread): 193 keypoints a frame
    against 865, the poses 0.17% of the path and 0.30 degrees mean from the default run's."""
    out, stdout = register_handheld(handheld, tmp_path / "fast", "--fast-features", "--no-flow")
    assert "from the frames as they are (--fast-features)" in stdout and "doubled" in video_scene[1]
    fast, default = keypoints_per_frame(stdout), keypoints_per_frame(video_scene[1])
    print(f"keypoints a frame: {fast:.0f} fast, {default:.0f} default")
    assert fast < 0.5 * default, (fast, default)
    poses = scene_poses(out)
    score = score_poses(np.stack(list(poses.values())), handheld.cam_to_world[[int(i) for i in poses]])
    print(score.describe())
    assert score.frames == FRAMES and score.centre_rms_share <= MAX_PATH_ERROR
    assert score.relative_rotation_max_deg <= MAX_ROTATION_ERROR_DEG


def test_every_attempt_stops_at_its_deadline_and_says_so(pycolmap, handheld, old_pipeline_scene, tmp_path):
    """The incremental mapper on the 32 frames takes seconds of CPU with one thread (the old pipeline's
    run: measured 3-4 s); a deadline of 1 s stops each attempt's mapping, and the refusal says why."""
    cpu = json.loads((old_pipeline_scene[0] / "capture.json").read_text())["cpu_seconds"]["mapping"]
    assert cpu > 1.5, cpu  # the premise: one attempt's mapping takes longer than the deadline
    out = tmp_path / "scene"
    code, stdout, stderr = run_cli(
        ["data", "video", str(handheld.path), "--out", str(out), "--frames", str(FRAMES), "--max-size", "200",
         "--threads", "1", "--mapper", "incremental", "--no-flow", "--no-mask-moving", "--deadline", "1",
         "--keyframe-every", "1"]
    )  # fmt: skip
    assert code == 2 and not out.exists()
    stopped = [line for line in stdout.splitlines() if line.startswith("mapping (incremental):")]
    assert len(stopped) == 3 and all(line.endswith("; stopped at its deadline of 1 s)") for line in stopped), stdout
    seconds = [float(line.rsplit("(", 1)[1].split(" s;")[0]) for line in stopped]
    assert max(seconds) < 1.0 + 3.0, seconds  # COLMAP checks its clock between frames
    assert "next: attempt 2 of 3 will try every pair of frames matched" in stdout
    # Refused for the deadline whether what it had registered passed the other checks or not.
    assert "stopped at the deadline of 1 s" in stderr and "--deadline SECONDS gives it longer" in stderr
    assert len(stderr.strip().splitlines()) == 1, stderr


def test_frames_the_keyframes_cannot_place_send_colmap_to_every_frame(pycolmap, handheld, video_scene, tmp_path,
                                                                     monkeypatch):  # fmt: skip
    """With no frame between keyframes allowed to stay unplaced and placing made to fail, COLMAP solves every
    frame, reusing the keyframes' features: every frame registered, the keyframes' attempt recorded first."""
    import liquidgs.data.colmap as colmap

    monkeypatch.setattr(colmap, "MAX_UNPLACED_SHARE", 0.0)
    monkeypatch.setattr("liquidgs.data.keyframes.MIN_INLIERS", 10**6)  # no frame rests on enough points
    out, stdout = register_handheld(handheld, tmp_path / "scene", "--no-flow")
    capture = json.loads((out / "capture.json").read_text())
    assert "placing: 15 of the 15 frames between keyframes could not be placed" in stdout, stdout
    assert "next: COLMAP solves every frame" in stdout
    assert capture["frames_registered"] == FRAMES and capture["camera_solve"]["keyframes"] is None
    attempts = capture["camera_solve"]["attempts"]
    assert [a.get("frames") for a in attempts] == ["keyframes", None] and attempts[1]["result"] == "used"
    # The keyframes' 17 frames kept their features: only the other 15 were extracted again.
    assert " in 32 frames from" in stdout and stdout.count("features: ") == 2
    assert capture["cpu_seconds"]["placing"] >= 0 and "every-frame" not in str(list(out.iterdir()))
    # The same cameras as a solve of every frame from the start, to COLMAP's run-to-run spread.
    whole, _ = register_handheld(handheld, tmp_path / "whole", "--no-flow", "--keyframe-every", "1")
    assert score_scenes(out, whole).relative_rotation_mean_deg < 0.05


def test_extraction_samples_frames_and_applies_a_phone_rotation(handheld, tmp_path):
    import imageio_ffmpeg

    rotated = tmp_path / "portrait.mp4"  # the same stream, with a phone's "display rotation" tag
    subprocess.run(
        [imageio_ffmpeg.get_ffmpeg_exe(), "-loglevel", "error", "-display_rotation", "90", "-i", str(handheld.path),
         "-c", "copy", str(rotated)], check=True,
    )  # fmt: skip
    lines: list[str] = []
    for name, video, fps, frames, ids, size in (
        ("evenly", handheld.path, None, 5, [0, 8, 16, 23, 31], (200, 152)),
        ("fps", handheld.path, 3.0, None, list(range(0, FRAMES, 4)), (100, 76)),  # 12 fps video
        ("portrait", rotated, None, 5, [0, 8, 16, 23, 31], (152, 200)),
    ):
        folder = tmp_path / name
        folder.mkdir()
        kept = extract_video_frames(video, folder, fps=fps, frames=frames, max_size=max(size), log=lines.append)
        assert [frame.time_id for frame in kept] == ids and [frame.id for frame in kept] == [f"{n:06d}" for n in ids]
        assert Image.open(folder / "000000.png").size == size
    upright = np.asarray(Image.open(tmp_path / "evenly" / "000008.png"), dtype=float)
    portrait = np.asarray(Image.open(tmp_path / "portrait" / "000008.png"), dtype=float)
    assert np.abs(portrait - np.rot90(upright)).mean() < 1.0  # same pixels, turned a quarter
    assert "extraction: portrait.mp4: 32 frames, 12 fps, 152x200 after scaling; keeping 5" in lines


def test_bad_inputs_are_one_line_and_leave_nothing(pycolmap, tmp_path):
    blank = tmp_path / "wall.mp4"
    write_video(blank, [np.full((120, 160, 3), 170, np.uint8)] * 16, fps=12)
    (tmp_path / "empty.mp4").write_bytes(b"")
    (tmp_path / "notes.mp4").write_text("not a video\n")
    cases = {
        "empty.mp4": "is an empty file, not a video",
        "notes.mp4": "ffmpeg decodes no video frames from it",
        "wall.mp4": "COLMAP found no features in any of the 16 frames",
        "missing.mp4": "video file not found",
    }
    for name, message in cases.items():
        out = tmp_path / f"out-{name}"
        code, _, stderr = run_cli(["data", "video", str(tmp_path / name), "--out", str(out), "--threads", "1"])
        assert code == 2 and message in stderr and stderr.count("\n") == 1, (name, stderr)
        assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty.mp4", "notes.mp4", "wall.mp4"]

    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "keep.txt").write_text("mine")
    code, _, stderr = run_cli(["data", "video", str(blank), "--out", str(taken)])
    assert code == 2 and "already exists and is not an empty folder" in stderr
    assert [p.name for p in taken.iterdir()] == ["keep.txt"]

    both = ["--fps", "2", "--frames", "5"]
    code, _, stderr = run_cli(["data", "video", str(blank), "--out", str(tmp_path / "o"), *both])
    assert code == 2 and "give --fps or --frames, not both" in stderr


def test_a_missing_pycolmap_is_one_line_with_the_install_command(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "pycolmap", None)  # import pycolmap now raises ImportError
    code, _, stderr = run_cli(["data", "images", str(tmp_path), "--out", str(tmp_path / "o")])
    assert "pip install pycolmap (or, in the clone, pip install -e '.[colmap]')" in stderr
    assert code == 2 and stderr.count("\n") == 1


@pytest.mark.slow
def test_a_short_training_on_the_scene_beats_the_static_model(video_scene, tmp_path, one_torch_thread):
    """The tiny preset cut to 500 iterations at 1/4 size (50x38), the COLMAP points as the only
    Gaussians (no densification, so the field's cost stays small), MLP against static, camera
    refinement and exposure compensation on as for every capture, the motion regularisers off:
    the scene the pipeline made carries motion a field learns. Measured: static 26.46 dB, MLP 27.02
    with the motion settings off; with the MLP's sizes held (and no motion term, as before the
    stillness term was its default) it scored 26.52 at this length, with the neighbour regularisers
    at 0.5 as well 26.33: its gain here is in resizing Gaussians (docs/training.md). The aligned score is
    not asserted here, so its evaluation is cut to 10 steps (tests/test_camera_opt.py holds it)."""
    out, _ = video_scene
    psnr = {}
    for field in ("static", "mlp"):
        code, _, stderr = run_cli(
            ["train", "--data", str(out), "--field", field, "--motion.apply", "off", "--preset", "tiny",
             "--iterations", "500",
             "--downscale", "4", "--densify.start", "1000", "--eval.start", "500", "--eval.fps-frames", "2",
             "--eval.lpips-backbone", "alex", "--cameras.align-steps", "10", "--out", str(tmp_path / field)]
        )  # fmt: skip
        assert code == 0, stderr
        psnr[field] = json.loads((tmp_path / field / "results.json").read_text())["final"]["psnr"]
    print("final test PSNR:", psnr)
    assert psnr["mlp"] >= psnr["static"] + 0.2, psnr
    # The scene's own motion masks score the run, once they exist at its scale (data video made 1x).
    code, _, stderr = run_cli(["eval", "--run", str(tmp_path / "mlp"), "--mask", "auto"])
    assert code == 2 and f"compute them: liquidgs data flow {out} --downscale 4" in stderr
    assert run_cli(["data", "flow", str(out), "--downscale", "4"])[0] == 0
    code, stdout, stderr = run_cli(["eval", "--run", str(tmp_path / "mlp"), "--mask", "auto"])
    assert code == 0, stderr
    masked = json.loads((tmp_path / "mlp" / "eval.json").read_text())["masked"]
    assert masked["masks"] == str(out / "flow" / "4x" / "masks") and "inside the masks" in stdout


def ball_masks(scene: Path, handheld) -> list[tuple[np.ndarray, np.ndarray]]:
    """(motion mask, the ball's true mask) of every frame, the truth cropped as undistortion cropped
    the frames (centred)."""
    pairs = []
    for mask_file in sorted((scene / "flow" / "1x" / "masks").glob("*.png")):
        mask = np.asarray(Image.open(mask_file)) > 0
        truth = handheld.dynamic_masks[int(mask_file.stem)]
        top, left = (truth.shape[0] - mask.shape[0]) // 2, (truth.shape[1] - mask.shape[1]) // 2
        pairs.append((mask, truth[top : top + mask.shape[0], left : left + mask.shape[1]]))
    return pairs


def test_the_scene_has_flow_and_motion_masks_that_find_the_ball(video_scene, handheld):
    """Measured (32 frames at 196x148, one COLMAP thread): the masks flag 0.65% of the still pixels on
    average (4.1% at worst), and 60% of what they flag is the ball; they find 22% of it - the ball
    rolls the way the camera slides, along the epipolar lines, where no two-view test can see it."""
    out, stdout = video_scene
    folder = out / "flow" / "1x"
    record = json.loads((folder / "flow.json").read_text())
    dataset = json.loads((out / "dataset.json").read_text())
    assert [pair[0] for pair in record["pairs"]] == dataset["train_ids"][:-1]
    assert [pair[1] for pair in record["pairs"]] == dataset["train_ids"][1:]
    assert sorted(record["masks"]) == sorted(dataset["ids"]) and len(list((folder / "masks").iterdir())) == FRAMES
    with np.load(folder / "pairs" / f"{record['pairs'][0][0]}--{record['pairs'][0][1]}.npz") as pair:
        assert pair["forward"].shape == (*record["size"][::-1], 2) and pair["forward_consistent"].mean() > 0.8
    checked = run_cli(["data", "check", str(out)])[1]
    assert "flow " in stdout and checked.count("flow:       1x: 27 pairs, 25 tracks over 4 frames, 32 motion") == 1
    # A track is its three pairs chained: from each train frame to the third after it, and back.
    train = dataset["train_ids"]
    assert record["track_step"] == 3 and record["tracks"] == [[a, b] for a, b in zip(train[:-3], train[3:])]
    links = [np.load(folder / "pairs" / f"{a}--{b}.npz") for a, b in record["pairs"][:3]]
    with np.load(folder / "pairs" / f"{train[0]}--{train[3]}.npz") as track:
        forward = [link["forward"].astype(np.float32) for link in links]
        chained, kept = chain_flow(forward, [link["forward_consistent"] for link in links])
        error = np.abs(track["forward"] - chained).max(axis=-1)  # the links are read back as float16
        assert np.percentile(error[kept], 99) < 0.05
        # Consistent only where every link was: the track was chained from the links in float32, these are read
        # back in float16, so a chain's end may fall on the other side of a link mask's edge (measured: 1 pixel
        # of 29,008).
        assert (track["forward_consistent"] & ~kept).mean() < 1e-3
        assert 0.5 < track["forward_consistent"].mean() <= kept.mean() and track["backward_consistent"].mean() > 0.5
    pairs = ball_masks(out, handheld)
    still = np.mean([(mask & ~truth).mean() for mask, truth in pairs])
    flagged = [(mask & truth).sum() / mask.sum() for mask, truth in pairs if mask.any()]
    assert still < 0.015 and np.mean(flagged) > 0.45 and len(flagged) >= FRAMES // 2, (still, flagged)


def test_stale_flow_is_one_line_and_data_flow_makes_it_fresh_or_leaves_it_whole(video_scene, tmp_path, monkeypatch):
    import shutil

    from liquidgs.data import flow

    scene = Path(shutil.copytree(video_scene[0], tmp_path / "scene"))
    image = scene / "rgb" / "1x" / "000003.png"
    pixels = np.asarray(Image.open(image)).copy()
    pixels[0, 0] ^= 1
    Image.fromarray(pixels).save(image)
    code, _, stderr = run_cli(["data", "check", str(scene)])
    assert code == 2 and stderr.strip().splitlines() == [
        f"liquidgs data: error: {image}: changed since the flow in {scene / 'flow' / '1x'} was computed from it "
        "(stale flow)"
    ]
    before = {p: p.read_bytes() for p in sorted((scene / "flow").rglob("*")) if p.is_file()}
    calls = []

    def interrupted(a, b):
        calls.append(1)
        if len(calls) > 5:
            raise KeyboardInterrupt
        return flow_of(a, b)

    flow_of = flow.optical_flow
    monkeypatch.setattr(flow, "optical_flow", interrupted)
    assert run_cli(["data", "flow", str(scene)])[0] == 130
    after = {p: p.read_bytes() for p in sorted((scene / "flow").rglob("*")) if p.is_file()}
    assert after == before and not [p for p in (scene / "flow").iterdir() if p.name.startswith(".")]  # no partial
    monkeypatch.setattr(flow, "optical_flow", flow_of)
    assert run_cli(["data", "flow", str(scene)])[0] == 0
    assert run_cli(["data", "check", str(scene)])[0] == 0


def test_the_flow_loss_trains_on_a_capture_with_flow_and_is_one_line_without(video_scene, tmp_path, puppet_scene):
    out, _ = video_scene
    flags = ["--field", "mlp", "--preset", "tiny", "--iterations", "30", "--warmup", "10", "--eval.start", "30",
             "--eval.fps-frames", "1", "--cameras.align-steps", "5", "--flow.weight", "0.02"]  # fmt: skip
    code, _, stderr = run_cli(
        ["train", "--data", str(out), "--downscale", "1", *flags, "--out", str(tmp_path / "flow")]
    )
    assert code == 0, stderr
    assert "weight: 0.02" in (tmp_path / "flow" / "config.yml").read_text()
    for data, scale, message in ((out, "2", f"no optical flow at this scale; compute them: liquidgs data flow {out}"),
                                 (puppet_scene, "1", "the optical-flow loss needs a capture with flow")):  # fmt: skip
        code, _, stderr = run_cli(
            ["train", "--data", str(data), "--downscale", scale, *flags, "--out", str(tmp_path / "x")]
        )
        assert code == 2 and message in stderr and len(stderr.strip().splitlines()) == 1, stderr
        assert not (tmp_path / "x").exists()


def test_flow_at_a_scale_without_its_own_rgb_folder_is_named_by_that_scale(video_scene, tmp_path):
    """rgb/1x area-averaged by 3 (there is no rgb/3x): flow/3x, at a third of the size; it used to be
    written as flow/1x, the folder the frames were read from."""
    import shutil

    scene = Path(shutil.copytree(video_scene[0], tmp_path / "scene", ignore=shutil.ignore_patterns("flow")))
    assert run_cli(["data", "flow", str(scene), "--downscale", "3"])[0] == 0
    width, height = json.loads((scene / "camera" / "000000.json").read_text())["image_size"]
    assert [p.name for p in (scene / "flow").iterdir()] == ["3x"]
    assert json.loads((scene / "flow" / "3x" / "flow.json").read_text())["size"] == [width // 3, height // 3]


def test_flow_needs_two_train_frames_and_refuses_other_layouts(video_scene, tmp_path, puppet_scene):
    import shutil

    scene = Path(shutil.copytree(video_scene[0], tmp_path / "scene", ignore=shutil.ignore_patterns("flow")))
    dataset = json.loads((scene / "dataset.json").read_text())
    dataset["train_ids"] = dataset["train_ids"][:1]
    (scene / "dataset.json").write_text(json.dumps(dataset))
    code, _, stderr = run_cli(["data", "flow", str(scene)])
    assert code == 2 and "optical flow needs at least 2 train frames, the scene has 1" in stderr
    assert not (scene / "flow").exists()
    code, _, stderr = run_cli(["data", "flow", str(puppet_scene)])  # D-NeRF: no Nerfies layout
    assert code == 2 and len(stderr.strip().splitlines()) == 1 and "Traceback" not in stderr


def test_bad_image_folders_and_masks_are_one_line_naming_the_file(pycolmap, handheld, tmp_path):
    images = tmp_path / "images"
    images.mkdir()
    for n in range(4):  # the fewest frames COLMAP is run on
        Image.fromarray(handheld.images[n]).save(images / f"{n}.png")
    masks = tmp_path / "masks"
    masks.mkdir()
    Image.fromarray(handheld.dynamic_masks[0].astype(np.uint8) * 255).save(masks / "0.png")
    out = str(tmp_path / "o")
    code, _, stderr = run_cli(["data", "images", str(images), "--out", out, "--mask-dynamic", str(masks)])
    assert code == 2 and f"{masks / '1.png'}: --mask-dynamic: no mask for 1.png" in stderr, stderr

    (images / "3.png").write_bytes(b"\x89PNG\r\n\x1a\n truncated")
    code, _, stderr = run_cli(["data", "images", str(images), "--out", out])
    assert code == 2 and f"{images / '3.png'}: cannot decode image" in stderr and stderr.count("\n") == 1
    Image.new("RGB", (64, 48)).save(images / "3.png")
    code, _, stderr = run_cli(["data", "images", str(images), "--out", out])
    assert code == 2 and "is 64x48 but 0.png is 200x152; one shared camera needs one image size" in stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["images", "masks"]


def test_an_interrupt_mid_run_leaves_no_scene_and_no_partial_folder(pycolmap, handheld, tmp_path):
    images = tmp_path / "images"
    images.mkdir()
    for n in range(4):
        Image.fromarray(handheld.images[n]).save(images / f"{n}.png")

    def interrupt_at_features(line: str) -> None:
        if line.startswith("features:"):
            raise KeyboardInterrupt

    settings = CaptureSettings(solve=SolveOptions(threads=1))
    with pytest.raises(KeyboardInterrupt):
        capture_scene(images, tmp_path / "scene", settings, interrupt_at_features, video=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["images"]


def camera_files(scene: Path) -> dict[str, dict]:
    ids = json.loads((scene / "dataset.json").read_text())["ids"]
    return {image_id: json.loads((scene / "camera" / f"{image_id}.json").read_text()) for image_id in ids}


def border_and_centre_error(scene: Path, video, frame_ids: list[str]) -> tuple[float, float]:
    """Mean |frame - pinhole render of the true camera with the scene's intrinsics| (8-bit levels)
    in a 25-30 px band along the border and inside it, over the given frames."""
    border, centre = [], []
    for image_id in frame_ids:
        camera = json.loads((scene / "camera" / f"{image_id}.json").read_text())
        (width, height), focal, (cx, cy) = camera["image_size"], camera["focal_length"], camera["principal_point"]
        K = np.array([[focal, 0.0, cx], [0.0, focal * camera["pixel_aspect_ratio"], cy], [0.0, 0.0, 1.0]])
        frame = int(image_id)
        truth = render_rgba(scene_at(frame / (DISTORTED_FRAMES - 1)), K, video.cam_to_world[frame], width, height, 3)
        image = np.asarray(Image.open(scene / "rgb" / "1x" / f"{image_id}.png"), dtype=float)
        error = np.abs(image - truth[..., :3]).mean(axis=-1)
        band = np.ones_like(error, dtype=bool)
        band[25:-25, 30:-30] = False
        border.append(error[band].mean())
        centre.append(error[~band].mean())
    return float(np.mean(border)), float(np.mean(centre))


def test_a_distorted_video_gives_pinhole_cameras_and_undistorted_frames(distorted_scenes):
    video, scenes, stdouts = distorted_scenes
    out = scenes["undistorted"]
    files = camera_files(out)
    assert len(files) == DISTORTED_FRAMES
    width, height = files["000000"]["image_size"]
    for camera in files.values():
        assert camera["radial_distortion"] == [0.0, 0.0, 0.0] and camera["tangential_distortion"] == [0.0, 0.0]
        assert camera["image_size"] == [width, height] and camera["pixel_aspect_ratio"] == 1.0
        assert camera["focal_length"] == pytest.approx(FOCAL, rel=0.03)
    # Undistorting a barrel lens stretches the edges out: the valid pixels span a wider image.
    assert width % 4 == 0 and height % 4 == 0 and width > 200 and height >= 148, (width, height)
    capture = json.loads((out / "capture.json").read_text())
    lens = capture["undistortion"]["from"]
    assert lens["model"] == "SIMPLE_RADIAL" and lens["params"][3] == pytest.approx(PHONE_LENS.k1, abs=0.03), lens
    assert capture["undistortion"]["to"]["size"] == capture["image_size"] == [width, height]
    assert "undistortion: SIMPLE_RADIAL 200x152" in stdouts["undistorted"]
    report = check_dataset(DataConfig(path=out, downscale=4))
    camera = report.dataset.train[0].camera
    assert report.dataset.warnings == [] and (camera.width, camera.height) == (width // 4, height // 4)

    rmse, path_length = centre_error(out, video.cam_to_world, int)
    assert rmse <= MAX_PATH_ERROR * path_length, (rmse, path_length)
    assert orientation_errors(out, video.cam_to_world, int).max() <= MAX_ROTATION_ERROR_DEG

    # Each frame against a pinhole render of its true camera with the written intrinsics. Near the
    # border, where the lens moved pixels by 4-8 px, the undistorted frames match it nearly as well
    # as at the centre (where H.264 and COLMAP's focal length set the floor); the frames kept
    # distorted, which training would treat as pinhole, do not.
    frame_ids = ["000000", "000005", "000010", "000015"]
    border, centre = border_and_centre_error(out, video, frame_ids)
    kept_border, kept_centre = border_and_centre_error(scenes["kept"], video, frame_ids)
    print(f"undistorted: border {border:.2f}, centre {centre:.2f}; kept: border {kept_border:.2f}, "
          f"centre {kept_centre:.2f}")  # fmt: skip
    assert border <= centre + 5.0 and kept_border >= border + 5.0, (border, centre, kept_border, kept_centre)


def test_keep_distortion_keeps_the_frames_the_lens_and_the_same_poses(distorted_scenes):
    _, scenes, _ = distorted_scenes
    kept, undistorted = camera_files(scenes["kept"]), camera_files(scenes["undistorted"])
    assert kept.keys() == undistorted.keys()
    for image_id, camera in kept.items():
        assert camera["radial_distortion"][0] == pytest.approx(PHONE_LENS.k1, abs=0.03), camera
        assert camera["image_size"] == [200, 152] and camera["principal_point"] == [100.0, 76.0]
        # Undistortion moves pixels, not cameras.
        assert camera["orientation"] == undistorted[image_id]["orientation"]
        assert camera["position"] == undistorted[image_id]["position"]
        assert camera["focal_length"] == undistorted[image_id]["focal_length"]
    assert np.array_equal(np.load(scenes["kept"] / "points.npy"), np.load(scenes["undistorted"] / "points.npy"))
    assert json.loads((scenes["kept"] / "capture.json").read_text())["undistortion"] is None
    assert Image.open(scenes["kept"] / "rgb" / "1x" / "000000.png").size == (200, 152)
    warnings = check_dataset(DataConfig(path=scenes["kept"])).dataset.warnings
    assert any("nonzero lens distortion" in warning for warning in warnings), warnings


def test_data_undistort_of_the_kept_scene_writes_the_default_scene(distorted_scenes, tmp_path):
    _, scenes, _ = distorted_scenes
    out = tmp_path / "undistorted-later"
    code, stdout, stderr = run_cli(["data", "undistort", str(scenes["kept"]), "--out", str(out)])
    assert code == 0, stderr
    assert f"done: {DISTORTED_FRAMES} frames undistorted into pinhole cameras" in stdout
    assert "not carried over" in stdout and "capture.json, colmap/" in stdout
    default = scenes["undistorted"]
    later, direct = camera_files(out), camera_files(default)
    assert later.keys() == direct.keys()
    for image_id, camera in later.items():
        for key, value in camera.items():
            assert np.allclose(value, direct[image_id][key], rtol=1e-9, atol=1e-9), (image_id, key)
        for factor in (1, 2, 4):
            ours = np.asarray(Image.open(out / "rgb" / f"{factor}x" / f"{image_id}.png"), dtype=int)
            theirs = np.asarray(Image.open(default / "rgb" / f"{factor}x" / f"{image_id}.png"), dtype=int)
            assert ours.shape == theirs.shape and np.abs(ours - theirs).max() <= 1, (image_id, factor)
    for name in ("dataset.json", "metadata.json", "scene.json", "points.npy"):
        assert (out / name).read_bytes() == (scenes["kept"] / name).read_bytes(), name
    assert sorted(p.name for p in out.iterdir()) == ["camera", "dataset.json", "metadata.json", "points.npy",
                                                      "rgb", "scene.json"]  # fmt: skip
    code, stdout, _ = run_cli(["data", "check", str(out)])
    assert code == 0 and "all OK" in stdout
