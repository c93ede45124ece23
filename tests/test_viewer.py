"""`liquidgs view`, camera paths and `liquidgs render --camera-path`, on one small trained 'sde' run.

The browser tests drive headless Chromium (Debian's `chromium`, installed by
scripts/setup_browser.sh) with Playwright against a viewer on 127.0.0.1 at a free port, and
read every picture from the browser's screenshots, which are kept under test-artifacts/viewer/.
"""

from __future__ import annotations

import io
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest
import torch
from PIL import Image

from browser import launched_chromium
from liquidgs.cli import main as cli
from liquidgs.commands.train import resolve_config, train
from liquidgs.data import generate_synthetic
from liquidgs.media import to_uint8
from liquidgs.render.camera_path import PathCamera, read_camera_path, write_camera_path

REPO = Path(__file__).resolve().parents[1]
ARTIFACTS = Path(os.environ.get("LIQUIDGS_TEST_ARTIFACTS", REPO / "test-artifacts")) / "viewer"
VIEWER_FLAGS = ["--disable-gpu", "--disable-quic", "--disable-sync"]
VIEWPORT = {"width": 1400, "height": 700}


@pytest.fixture(autouse=True)
def _one_thread(one_torch_thread):
    yield


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("viewer")
    scene = Path(generate_synthetic("spinner", root / "spinner", size=40, frames=16, seed=2)) / "dnerf"
    out = root / "sde"
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    cfg, run = resolve_config(
        ["--data", str(scene), "--field", "sde", "--preset", "tiny", "--iterations", "80", "--warmup", "10",
         "--init-points", "1000", "--eval.start", "80", "--eval.fps-frames", "2", "--out", str(out)]
    )  # fmt: skip
    train(cfg, run)
    torch.set_num_threads(threads)
    return out


@pytest.fixture(scope="module")
def test_renders(run_dir) -> Path:
    """What `liquidgs render` writes for the test cameras (the viewer must show the same)."""
    assert cli(["render", "--run", str(run_dir), "--sweep-frames", "1", "--orbit-frames", "1"]) == 0
    return run_dir / "renders" / "test"


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# ----- camera paths ---------------------------------------------------------------------------


def dataset_keyframe(frame, time: float) -> PathCamera:
    camera = frame.camera
    c2w = np.linalg.inv(camera.viewmat.double().numpy())
    return PathCamera(c2w, math.degrees(2 * math.atan(0.5 * camera.height / float(camera.K[1, 1]))), time)


def test_camera_path_round_trip_and_render(run_dir, test_renders, tmp_path):
    from liquidgs.train.dataset import load_run_dataset
    from liquidgs.train.run import load_run

    run = load_run(run_dir)
    frames = load_run_dataset(run.config).test
    first, last = dataset_keyframe(frames[0], frames[0].time), dataset_keyframe(frames[1], 1.0)
    width, height = frames[0].camera.width, frames[0].camera.height
    path_file = write_camera_path(tmp_path / "path.json", [first, last], width, height, 4, 1.0)
    record = json.loads(path_file.read_text())
    assert [len(record["camera_path"]), len(record["keyframes"])] == [4, 2]
    assert set(record["camera_path"][0]) == {"camera_to_world", "fov", "aspect", "render_time"}
    # nerfstudio's axes: the camera looks down -z, so the third column is minus the OpenCV forward axis.
    stored = np.array(record["camera_path"][0]["camera_to_world"]).reshape(4, 4)
    np.testing.assert_allclose(stored[:3, 2], -first.camera_to_world[:3, 2], atol=1e-9)

    path = read_camera_path(path_file)
    assert [c.time for c in path.frames] == pytest.approx([frames[0].time, (2 * frames[0].time + 1) / 3,
                                                           (frames[0].time + 2) / 3, 1.0])  # fmt: skip
    start, end = path.frames[0].camera(width, height), path.frames[-1].camera(width, height)
    torch.testing.assert_close(start.viewmat, frames[0].camera.viewmat, atol=1e-5, rtol=0)
    torch.testing.assert_close(end.viewmat, frames[1].camera.viewmat, atol=1e-5, rtol=0)
    torch.testing.assert_close(start.K, frames[0].camera.K)
    assert (start.width, start.height) == (width, height)

    assert cli(["render", "--run", str(run_dir), "--camera-path", str(path_file), "--out", str(tmp_path)]) == 0
    video = imageio.mimread(tmp_path / "path.mp4")
    assert len(video) == 4
    expected = np.asarray(Image.open(test_renders / "render" / f"{frames[0].name}.png"), dtype=np.float32)
    assert np.abs(video[0].astype(np.float32) - expected).mean() < 3.0  # H.264 against the PNG
    assert np.abs(video[0].astype(np.float32) - video[-1].astype(np.float32)).mean() > 1.0


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (lambda r: r.pop("render_width"), "field 'render_width': missing"),
        (lambda r: r["camera_path"][1].pop("render_time"), "field 'camera_path[1].render_time': missing"),
        (lambda r: r["camera_path"][0].update(fov=0), "field 'camera_path[0].fov': 0 is outside"),
        (lambda r: r["camera_path"][0]["camera_to_world"].pop(), "field 'camera_path[0].camera_to_world': expected 16"),
        (lambda r: r["camera_path"][0].update(camera_to_world=[2.0] * 16), "is not a rotation"),
    ],
)
def test_bad_camera_path_is_one_line_naming_the_field(run_dir, tmp_path, capsys, change, expected):
    path_file = write_camera_path(tmp_path / "path.json", [PathCamera(np.eye(4), 50.0, 0.5)] * 2, 32, 32, 2, 1.0)
    record = json.loads(path_file.read_text())
    change(record)
    path_file.write_text(json.dumps(record))
    assert cli(["render", "--run", str(run_dir), "--camera-path", str(path_file)]) == 2
    line = one_error_line(capsys)
    assert str(path_file) in line and expected in line, line


# ----- the command without a browser ----------------------------------------------------------


def test_bad_input_is_one_line_before_the_server_starts(run_dir, tmp_path, capsys, monkeypatch):
    from liquidgs.viewer import server

    def no_server(*args, **kwargs):
        raise AssertionError("the server started")

    monkeypatch.setattr(server.Viewer, "__init__", no_server)
    unfinished = tmp_path / "unfinished"
    shutil.copytree(run_dir, unfinished, ignore=shutil.ignore_patterns("renders"))
    (unfinished / "results.json").unlink()
    no_checkpoint = tmp_path / "no_checkpoint"
    no_checkpoint.mkdir()
    shutil.copy(run_dir / "config.yml", no_checkpoint / "config.yml")
    not_a_ply = tmp_path / "scene.ply"
    not_a_ply.write_text("hello")
    cases = [
        (["--run", str(unfinished)], f"{unfinished}: not a finished liquidgs run (unfinished run: checkpoint at"),
        (["--run", str(no_checkpoint)], f"{no_checkpoint}: the run has no checkpoint yet"),
        (["--run", str(tmp_path)], f"{tmp_path}: not a liquidgs run folder"),
        (["--ply", str(not_a_ply)], f"{not_a_ply}: not a readable 3DGS PLY"),
        (["--ply", str(tmp_path / "missing")], "missing: does not exist"),
        (["--run", str(run_dir), "--ply", str(not_a_ply)], "give --run DIR (one or more) or --ply PATH"),
        (["--run", str(run_dir), "--host", "203.0.113.7"], "--host 203.0.113.7: cannot listen there"),
        (["--run", str(run_dir), "--port", "70000"], "--port must be between 0 and 65535"),
    ]
    for flags, expected in cases:
        assert cli(["view", *flags]) == 2
        line = one_error_line(capsys)
        assert line.startswith("liquidgs view: error: ") and expected in line, line


def test_benchmark_prints_the_render_loop_frame_rate(run_dir, capsys):
    assert cli(["view", "--run", str(run_dir), "--port", "0", "--resolution", "64", "--benchmark", "3"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["rest"]["width"] == 64 and record["moving"]["width"] == 32
    assert record["rest"]["fps"] > 0 and record["moving"]["fps"] > 0


def test_ply_sequence_renders_the_baked_run(run_dir, tmp_path, capsys):
    from liquidgs.viewer.scenes import PlyScene, load_runs
    from liquidgs.viewer.server import letterbox

    assert cli(["export", "--run", str(run_dir), "--out", str(tmp_path), "--sequence", "3"]) == 0
    run = load_runs([run_dir])[0]
    ply = PlyScene(tmp_path / "sequence", run.background)
    assert [f.name for f in ply.files] == ["frame_0000.ply", "frame_0001.ply", "frame_0002.ply"]
    camera, _ = letterbox(run.dataset.test[0], 48, 40)
    for t in (0.0, 0.5, 1.0):
        torch.testing.assert_close(ply.render(camera, t), run.render(camera, t), atol=2e-3, rtol=0)
    assert (ply.render(camera, 0.0) - ply.render(camera, 1.0)).abs().mean() > 1e-3
    # The command serves it (here: its benchmark, through the same viewer).
    capsys.readouterr()
    flags = ["--port", "0", "--resolution", "32", "--benchmark", "2"]
    assert cli(["view", "--ply", str(tmp_path / "sequence"), *flags]) == 0
    assert json.loads(capsys.readouterr().out)["scene"] == "sequence"


def test_uncertainty_is_the_estimate_render_writes(run_dir, tmp_path):
    """Same seed, same camera: the viewer's heat map is the std `render --uncertainty-samples` writes."""
    from liquidgs.commands.render import monte_carlo_views
    from liquidgs.viewer.scenes import load_runs
    from liquidgs.viewer.server import heat_map, letterbox

    scene = load_runs([run_dir])[0]
    frame = scene.dataset.test[0]
    camera, _ = letterbox(frame, frame.camera.width, frame.camera.height)
    torch.manual_seed(7)
    std = scene.uncertainty(camera, frame.time, 4)
    torch.manual_seed(7)
    monte_carlo_views(scene.run, [frame], 4, scene.background, tmp_path, None)
    written = json.loads((tmp_path / "uncertainty.json").read_text())["views"][frame.name]
    assert float(std.max()) == pytest.approx(written["max_std"], rel=1e-6) and written["max_std"] > 0
    assert float(std.mean()) == pytest.approx(written["mean_std"], rel=1e-6)
    image, peak = heat_map(std)
    assert peak == pytest.approx(written["max_std"], rel=1e-6)
    assert image.shape == (frame.camera.height, frame.camera.width, 3)


@pytest.mark.slow
def test_command_binds_to_localhost_and_ctrl_c_stops_it(run_dir):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO / "src"), os.environ.get("PYTHONPATH")]))}
    process = subprocess.Popen(
        [sys.executable, "-m", "liquidgs.cli", "view", "--run", str(run_dir), "--port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    try:
        line = process.stdout.readline()
        assert line.startswith("liquidgs view: open http://127.0.0.1:"), line
        url = line.split()[3]
        with urllib.request.urlopen(url, timeout=30) as page:
            assert page.status == 200 and b"<html" in page.read().lower()
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=30)
    finally:
        process.kill()
    assert process.returncode == 0 and "liquidgs view: stopped" in out
    assert "Traceback" not in err, err


# ----- in a real browser ----------------------------------------------------------------------


@pytest.fixture(scope="module")
def browser():
    yield from launched_chromium(VIEWER_FLAGS)


def wait_for(condition, what: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


class Screen:
    """Screenshots of the viewer's canvas, taken once the picture the viewer last sent is on screen."""

    def __init__(self, page, viewer):
        self.page, self.viewer = page, viewer

    def grab(self) -> np.ndarray:
        canvas = self.page.locator("canvas").first.bounding_box()  # the picture, without the docked panel
        return np.asarray(Image.open(io.BytesIO(self.page.screenshot(clip=canvas))).convert("RGB"))

    def settled(self, name: str, sent: int, **expected) -> np.ndarray:
        """Wait for a resting frame sent after `sent` with the expected properties, then for the
        browser to show it (two equal screenshots in a row), and keep the screenshot."""

        def done() -> bool:
            last = self.viewer.last_sent or {}
            return (
                self.viewer.frames_sent > sent
                and not last.get("moving", True)
                and all(last.get(k) == v for k, v in expected.items())
            )

        wait_for(done, f"a frame with {expected}")
        previous = self.grab()
        for _ in range(50):
            self.page.wait_for_timeout(150)
            current = self.grab()
            if np.array_equal(current, previous):
                break
            previous = current
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        Image.fromarray(current).save(ARTIFACTS / f"{name}.png")
        return current


def box_in_screenshot(screenshot: np.ndarray, viewer, frame) -> np.ndarray:
    """The dataset camera's part of the picture, resized to the camera's image size."""
    from liquidgs.viewer.server import fit_size, letterbox

    height, width = screenshot.shape[:2]
    render_w, render_h = fit_size(width / height, viewer.max_side)
    _, (x0, y0, box_w, box_h) = letterbox(frame, render_w, render_h)
    sx, sy = width / render_w, height / render_h
    crop = screenshot[round(y0 * sy) : round((y0 + box_h) * sy), round(x0 * sx) : round((x0 + box_w) * sx)]
    size = (frame.camera.width, frame.camera.height)
    return np.asarray(Image.fromarray(crop).resize(size, Image.BOX), dtype=np.float32)


def mean_difference(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.abs(a.astype(np.float32) - b.astype(np.float32)).mean())


@pytest.mark.slow
def test_viewer_in_a_real_browser(browser, run_dir, test_renders, tmp_path):
    from liquidgs.viewer.scenes import load_runs
    from liquidgs.viewer.server import Viewer

    # The same run twice stands in for two runs of one scene (switching, side by side).
    viewer = Viewer(load_runs([run_dir, run_dir]), port=0, camera_path_file=tmp_path / "path.json")
    page = browser.new_page(viewport=VIEWPORT)
    problems = []
    page.on("console", lambda message: message.type == "error" and problems.append(message.text))
    page.on("pageerror", lambda error: problems.append(str(error)))
    try:
        assert viewer.url.startswith("http://127.0.0.1:")
        page.goto(viewer.url)
        screen = Screen(page, viewer)
        test_frames = [f for name, f in viewer.cameras.items() if name.startswith("test")]
        first, second = test_frames[0], test_frames[1]

        # The page opens at the first test camera at its frame time. Chromium's software WebGL
        # makes viser show a notice over the picture: close it.
        page.locator(".mantine-Notification-root").first.wait_for(timeout=30_000)
        for close in page.locator(".mantine-Notification-root button").all():
            close.click()
        start = screen.settled("01_first_test_camera", 0, snapped=first.name, mode="render", time=first.time)
        assert not problems, problems
        # The time slider changes the picture; moving it back restores it.
        other_time = 1.0 if first.time < 0.5 else 0.0
        viewer.time_slider.value = other_time
        moved = screen.settled("02_other_time", viewer.frames_sent, time=other_time)
        assert mean_difference(box_in_screenshot(moved, viewer, first), box_in_screenshot(start, viewer, first)) > 1.0
        viewer.time_slider.value = first.time
        back = screen.settled("03_time_back", viewer.frames_sent, time=first.time)
        assert mean_difference(back, start) < 0.1

        # Jump to another test camera with the GUI's button: the view `liquidgs render` writes for it.
        viewer.camera_choice.value = next(name for name, f in viewer.cameras.items() if f is second)
        sent = viewer.frames_sent
        page.get_by_role("button", name="Go to camera").click()
        jumped = screen.settled("04_jump_to_test_camera", sent, snapped=second.name, mode="render", time=second.time)
        expected = np.asarray(Image.open(test_renders / "render" / f"{second.name}.png"), dtype=np.float32)
        ours = box_in_screenshot(jumped, viewer, second)
        Image.fromarray(ours.astype(np.uint8)).save(ARTIFACTS / "04_jump_to_test_camera_box.png")
        assert mean_difference(ours, expected) < 6.0, mean_difference(ours, expected)
        # The ground truth toggled over the render.
        viewer.ground_truth.value = True
        truth_shot = screen.settled("05_ground_truth", viewer.frames_sent, mode="ground truth")
        truth = np.asarray(Image.open(test_renders / "gt" / f"{second.name}.png"), dtype=np.float32)
        truth_box = box_in_screenshot(truth_shot, viewer, second)
        assert mean_difference(truth_box, truth) < 6.0
        viewer.ground_truth.value = False

        # The uncertainty heat map of the sde run, and two runs side by side.
        viewer.uncertainty.value = True
        heat = screen.settled("06_uncertainty", viewer.frames_sent, mode="uncertainty")
        assert viewer.last_sent["peak_std"] > 0 and mean_difference(heat, jumped) > 1.0
        viewer.uncertainty.value = False
        viewer.side_by_side.value = True
        screen.settled("07_side_by_side", viewer.frames_sent, mode="side by side")
        viewer.side_by_side.value = False

        # Playback: time advances; without loop it stops at 1.
        viewer.sweep_seconds.value = 1.0
        viewer.play.value = True
        wait_for(lambda: viewer.time_slider.value != second.time, "playback to move the time")
        viewer.loop.value = False
        wait_for(lambda: not viewer.play.value, "playback to stop at the end without loop")
        assert viewer.time_slider.value == 1.0
        viewer.time_slider.value = second.time

        # Record two keyframes with the GUI's buttons, save the path, render it.
        page.get_by_role("button", name="Add keyframe").click()
        wait_for(lambda: len(viewer.keyframes) == 1, "the first keyframe")
        viewer.time_slider.value = other_time
        page.get_by_role("button", name="Add keyframe").click()
        wait_for(lambda: len(viewer.keyframes) == 2, "the second keyframe")
        viewer.path_seconds.value, viewer.path_fps.value = 1.0, 3
        page.get_by_role("button", name="Save camera path").click()
        wait_for(lambda: (tmp_path / "path.json").is_file(), "the saved camera path")
        assert not problems, problems
    finally:
        page.close()
        viewer.stop()
    path = read_camera_path(tmp_path / "path.json")
    assert [c.time for c in path.frames] == pytest.approx([second.time, (second.time + other_time) / 2, other_time])
    path_file = str(tmp_path / "path.json")
    assert cli(["render", "--run", str(run_dir), "--camera-path", path_file, "--out", str(tmp_path)]) == 0
    video = imageio.mimread(tmp_path / "path.mp4")
    even = (path.height + path.height % 2, path.width + path.width % 2)  # yuv420p pads odd sides
    assert len(video) == 3 and video[0].shape[:2] == even
    # Each frame is the run at that frame's camera and render_time (H.264 aside).
    scene = load_runs([run_dir])[0]
    for i in (0, -1):
        camera = path.frames[i]
        expected = scene.run.render(camera.camera(path.width, path.height), camera.time, scene.background).rgb
        assert mean_difference(video[i][: path.height, : path.width], to_uint8(expected)) < 2.0
    assert mean_difference(video[0], video[-1]) > 0.1
