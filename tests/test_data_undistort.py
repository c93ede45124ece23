"""`liquidgs data undistort`: a Nerfies scene rendered through a known lens -> pinhole cameras.

The scene: the handheld test video's bouncing ball and floor in front of a checkered wall (straight
edges everywhere), 4 frames at 160x120 seen through a lens with every Nerfies coefficient set
(k1, k2, k3, p1, p2; FULL_OPENCV in COLMAP), a pixel aspect ratio of 1.05 and a principal point
off the centre. The ray caster renders it through the lens (tests/video_scene.py); the
undistorted images are compared with the same ray caster's pinhole render of the true camera
with the written intrinsics, which no code under test touches.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from liquidgs.data import DataConfig, check_dataset, generate_synthetic
from liquidgs.data.colmap import Undistorter
from liquidgs.data.nerfies import NerfiesCamera, camera_json
from liquidgs.data.synthetic import Primitive, render_rgba
from tiny_runs import run_cli
from video_scene import BACKGROUND, Lens, camera_path, moving_ball, render_through_lens

WIDTH, HEIGHT = 160, 120
FOCAL, ASPECT, CENTRE = 150.0, 1.05, (82.3, 58.9)
LENS = Lens(k1=-0.12, k2=0.03, k3=0.01, p1=0.002, p2=-0.003)
FRAMES = 4
# Checkered wall; its half thickness is no multiple of the checker period, so the checker's cell
# edges stay off its faces.
WALL = Primitive("wall", "box", (9.0, 0.21, 3.0), ((0.1, 0.1, 0.15), (0.95, 0.9, 0.8)), "checker", 0.3,
                 np.eye(3), np.array([0.0, 2.6, 0.6]))  # fmt: skip


def prims(frame: int) -> list[Primitive]:
    return [moving_ball(frame / (FRAMES - 1)), WALL, BACKGROUND[1]]


def K_of(focal: float, aspect: float, centre) -> np.ndarray:
    return np.array([[focal, 0.0, centre[0]], [0.0, focal * aspect, centre[1]], [0.0, 0.0, 1.0]])


def write_scene(root: Path, lens: Lens, skew: float = 0.0) -> Path:
    """The Nerfies layout with rgb/1x and rgb/2x, camera files carrying `lens`."""
    poses = camera_path(FRAMES)
    ids = [f"f{n}" for n in range(FRAMES)]
    for folder in ("camera", "rgb/1x", "rgb/2x"):
        (root / folder).mkdir(parents=True)
    for n, (image_id, pose) in enumerate(zip(ids, poses)):
        rgb = render_through_lens(prims(n), K_of(FOCAL, ASPECT, CENTRE), pose, WIDTH, HEIGHT, lens)[..., :3]
        Image.fromarray(rgb).save(root / "rgb" / "1x" / f"{image_id}.png")
        Image.fromarray(rgb).reduce(2).save(root / "rgb" / "2x" / f"{image_id}.png")
        camera = NerfiesCamera(
            rotation=pose[:3, :3].T,
            position=pose[:3, 3],
            focal_length=FOCAL,
            pixel_aspect_ratio=ASPECT,
            principal_point=np.array(CENTRE),
            skew=skew,
            image_size=(WIDTH, HEIGHT),
            distortion=np.array([lens.k1, lens.k2, lens.k3, lens.p1, lens.p2]),
        )
        (root / "camera" / f"{image_id}.json").write_text(json.dumps(camera_json(camera)))
    dataset = {"count": FRAMES, "num_exemplars": 3, "ids": ids, "train_ids": ids[:2] + ids[3:], "val_ids": ids[2:3]}
    (root / "dataset.json").write_text(json.dumps(dataset))
    metadata = {image_id: {"time_id": n, "warp_id": n, "appearance_id": n, "camera_id": 0} for n, image_id in
                enumerate(ids)}  # fmt: skip
    (root / "metadata.json").write_text(json.dumps(metadata))
    (root / "scene.json").write_text(json.dumps({"center": [0.0, 0.5, 0.0], "scale": 1.0}))
    points = np.random.default_rng(0).uniform(-1.0, 1.0, (50, 6)).astype(np.float32)
    np.save(root / "points.npy", points)
    return root


@pytest.fixture(scope="module")
def distorted(tmp_path_factory) -> Path:
    return write_scene(tmp_path_factory.mktemp("nerfies") / "distorted", LENS)


@pytest.fixture(scope="module")
def undistorted(distorted) -> tuple[Path, str]:
    out = distorted.parent / "undistorted"
    code, stdout, stderr = run_cli(["data", "undistort", str(distorted), "--out", str(out)])
    assert code == 0, stderr
    return out, stdout


def render_error(scene: Path, image_id: str, K: np.ndarray, size: tuple[int, int]) -> float:
    """Mean |rgb/1x image - pinhole render of the true camera with K| in 8-bit levels, both under a
    3x3 box blur: bilinear resampling alone leaves ~7 levels along the sharp texture edges, which the
    blur takes away, while a misregistration by half a pixel still leaves 7-8 (measured)."""
    frame = int(image_id[1:])
    truth = render_rgba(prims(frame), K, camera_path(FRAMES)[frame], *size, supersample=4)[..., :3]
    image = np.asarray(Image.open(scene / "rgb" / "1x" / f"{image_id}.png"))
    return float(np.abs(box_blur(image) - box_blur(truth))[2:-2, 2:-2].mean())


def box_blur(image: np.ndarray) -> np.ndarray:
    padded = np.pad(image.astype(float), ((1, 1), (1, 1), (0, 0)), mode="edge")
    height, width = image.shape[:2]
    return sum(padded[i : i + height, j : j + width] for i in range(3) for j in range(3)) / 9.0


@pytest.mark.slow
def test_the_cameras_become_pinhole_and_the_images_match_a_pinhole_render(distorted, undistorted):
    out, stdout = undistorted
    assert "undistortion (rgb/1x): FULL_OPENCV 160x120" in stdout and "-> PINHOLE" in stdout
    assert f"done: {FRAMES} frames undistorted into pinhole cameras" in stdout
    size = None
    for n in range(FRAMES):
        camera = json.loads((out / "camera" / f"f{n}.json").read_text())
        original = json.loads((distorted / "camera" / f"f{n}.json").read_text())
        assert camera["radial_distortion"] == [0.0, 0.0, 0.0] and camera["tangential_distortion"] == [0.0, 0.0]
        # COLMAP keeps the focal lengths (so the pixel aspect) and crops to the valid pixels.
        assert camera["focal_length"] == pytest.approx(FOCAL) and camera["pixel_aspect_ratio"] == pytest.approx(ASPECT)
        assert camera["orientation"] == original["orientation"] and camera["position"] == original["position"]
        size = tuple(camera["image_size"])
        assert size[0] % 2 == 0 and size[1] % 2 == 0  # rgb/2x is an exact half
        K = K_of(camera["focal_length"], camera["pixel_aspect_ratio"], camera["principal_point"])
        error = render_error(out, f"f{n}", K, size)
        # Without undistortion, the rasteriser would take the distorted image for this pinhole one.
        as_is = render_error(distorted, f"f{n}", K_of(FOCAL, ASPECT, CENTRE), (WIDTH, HEIGHT))
        print(f"f{n}: {size}, undistorted {error:.2f}, distorted as pinhole {as_is:.2f}")
        assert error <= 5.0 and error <= as_is / 2.5, (error, as_is)
        full = Image.open(out / "rgb" / "1x" / f"f{n}.png")
        half = np.asarray(Image.open(out / "rgb" / "2x" / f"f{n}.png"))
        assert np.array_equal(half, np.asarray(full.reduce(2)))
    for name in ("dataset.json", "metadata.json", "scene.json", "points.npy"):
        assert (out / name).read_bytes() == (distorted / name).read_bytes(), name
    for downscale in (1, 2):
        report = check_dataset(DataConfig(path=out, downscale=downscale))
        assert report.dataset.warnings == [] and report.images_decoded == FRAMES
        camera = report.dataset.train[0].camera
        assert (camera.width, camera.height) == (size[0] // downscale, size[1] // downscale)
    code, stdout, _ = run_cli(["data", "check", str(out)])
    assert code == 0 and "all OK" in stdout


def test_a_scene_without_distortion_is_refused_in_one_line_and_nothing_is_written(tmp_path):
    scene = generate_synthetic("spinner", tmp_path / "synth", size=32, frames=8, seed=0) / "nerfies"
    out = tmp_path / "out"
    code, _, stderr = run_cli(["data", "undistort", str(scene), "--out", str(out)])
    assert code == 2 and stderr.count("\n") == 1, stderr
    assert f"{scene / 'camera'}: no lens distortion to remove" in stderr
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["synth"]


def test_bad_scenes_and_outputs_are_one_line_and_leave_nothing(distorted, tmp_path):
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "keep.txt").write_text("mine")
    bad = tmp_path / "bad"
    shutil.copytree(distorted, bad)
    camera = json.loads((bad / "camera" / "f1.json").read_text())
    (bad / "camera" / "f1.json").write_text(json.dumps({**camera, "radial_distortion": "strong"}))
    skewed = write_scene(tmp_path / "skewed", Lens(k1=-0.1), skew=0.5)
    dnerf = generate_synthetic("spinner", tmp_path / "synth", size=32, frames=8, seed=0) / "dnerf"
    cases = [
        (tmp_path / "absent", tmp_path / "o1", f"{tmp_path / 'absent'}: scene folder not found"),
        (dnerf, tmp_path / "o2", "is a D-NeRF scene"),
        (bad, tmp_path / "o3", f"{bad / 'camera' / 'f1.json'}: field 'radial_distortion': expected a list"),
        (skewed, tmp_path / "o4", f"{skewed / 'camera' / 'f0.json'}: field 'skew': skew 0.5"),
        (distorted, taken, f"--out {taken}: already exists and is not an empty folder"),
    ]
    for scene, out, message in cases:
        code, _, stderr = run_cli(["data", "undistort", str(scene), "--out", str(out)])
        assert code == 2 and message in stderr and stderr.count("\n") == 1, (scene, stderr)
    assert [p.name for p in taken.iterdir()] == ["keep.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad", "skewed", "synth", "taken"]


def test_an_interrupt_while_writing_leaves_no_scene_and_no_partial_folder(distorted, tmp_path, monkeypatch):
    calls = []
    warp = Undistorter.image

    def interrupt_on_the_third_image(self, pixels):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return warp(self, pixels)

    monkeypatch.setattr(Undistorter, "image", interrupt_on_the_third_image)
    code, _, stderr = run_cli(["data", "undistort", str(distorted), "--out", str(tmp_path / "out")])
    assert code == 130 and len(calls) == 3, stderr
    assert list(tmp_path.iterdir()) == []
