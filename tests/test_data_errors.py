"""Bad input: each broken copy of a small scene is refused in one line naming the file and field."""

from __future__ import annotations

import json
import shutil
import struct
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from liquidgs import cli
from liquidgs.data import DEFAULT_SYNTHETIC_SCENE, DataConfig, check_dataset, generate_synthetic, load_dataset
from liquidgs.errors import DataError


@pytest.fixture(scope="module")
def pristine(tmp_path_factory) -> Path:
    return generate_synthetic(DEFAULT_SYNTHETIC_SCENE, tmp_path_factory.mktemp("pristine"), size=16, frames=8)


def edit_json(path: Path, change: Callable[[dict], None]) -> None:
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def write_png(path: Path, size: int) -> None:
    Image.fromarray(np.full((size, size, 4), 200, np.uint8), "RGBA").save(path)


def set_matrix(index: int, value) -> Callable[[dict], None]:
    def change(data: dict) -> None:
        data["frames"][index]["transform_matrix"] = value

    return change


def scaled_rotation(data: dict) -> None:
    matrix = np.array(data["frames"][0]["transform_matrix"])
    matrix[:3, :3] *= 1.5
    data["frames"][0]["transform_matrix"] = matrix.tolist()


def nan_entry(data: dict) -> None:
    data["frames"][0]["transform_matrix"][1][2] = float("nan")  # json writes NaN, which Python reads back


TRAIN = "transforms_train.json"
# (layout, change applied to the copy, file named, field named, words of the message)
CASES = {
    "missing image": (
        "dnerf",
        lambda r: (r / "train/r_001.png").unlink(),
        TRAIN,
        "frames[1].file_path",
        "not found",
    ),
    "unreadable image": (
        "dnerf",
        lambda r: (r / "train/r_002.png").write_bytes(b"not a png"),
        TRAIN,
        "frames[2].file_path",
        "unreadable",
    ),
    "truncated png": (
        "dnerf",
        lambda r: truncate(r / "train/r_000.png"),
        TRAIN,
        "frames[0].file_path",
        "truncated",
    ),
    "malformed json": (
        "dnerf",
        lambda r: (r / TRAIN).write_text('{"camera_angle_x": 0.69,'),
        TRAIN,
        None,
        "malformed JSON",
    ),
    "missing camera_angle_x": (
        "dnerf",
        lambda r: edit_json(r / TRAIN, lambda d: d.pop("camera_angle_x")),
        TRAIN,
        "camera_angle_x",
        "missing",
    ),
    "missing time": (
        "dnerf",
        lambda r: edit_json(r / TRAIN, lambda d: d["frames"][1].pop("time")),
        TRAIN,
        "frames[1].time",
        "missing",
    ),
    "time outside [0,1]": (
        "dnerf",
        lambda r: edit_json(r / TRAIN, lambda d: d["frames"][0].update(time=1.5)),
        TRAIN,
        "frames[0].time",
        "outside [0.0, 1.0]",
    ),
    "matrix not 4x4": (
        "dnerf",
        lambda r: edit_json(r / TRAIN, set_matrix(0, [[1, 0, 0, 0]] * 3)),
        TRAIN,
        "frames[0].transform_matrix",
        "shape [4, 4]",
    ),
    "non-finite matrix": (
        "dnerf",
        lambda r: edit_json(r / TRAIN, nan_entry),
        TRAIN,
        "frames[0].transform_matrix",
        "non-finite",
    ),
    "non-orthonormal rotation": (
        "dnerf",
        lambda r: edit_json(r / TRAIN, scaled_rotation),
        TRAIN,
        "frames[0].transform_matrix",
        "not orthonormal",
    ),
    "images of different sizes": (
        "dnerf",
        lambda r: write_png(r / "train/r_001.png", 32),
        TRAIN,
        "frames[1].file_path",
        "one size",
    ),
    "empty split": (
        "dnerf",
        lambda r: edit_json(r / "transforms_test.json", lambda d: d.update(frames=[])),
        "transforms_test.json",
        "frames",
        "empty split",
    ),
    "missing split file": (
        "dnerf",
        lambda r: (r / "transforms_test.json").unlink(),
        "transforms_test.json",
        None,
        "file not found",
    ),
    "id without camera file": (
        "nerfies",
        lambda r: (r / "camera/0001.json").unlink(),
        "dataset.json",
        "train_ids",
        "no camera file",
    ),
    "missing time_id": (
        "nerfies",
        lambda r: edit_json(r / "metadata.json", lambda d: d["0003"].pop("time_id")),
        "metadata.json",
        "0003.time_id",
        "missing",
    ),
    "metadata without the id": (
        "nerfies",
        lambda r: edit_json(r / "metadata.json", lambda d: d.pop("0004")),
        "metadata.json",
        "0004",
        "missing",
    ),
    "missing rgb image": (
        "nerfies",
        lambda r: (r / "rgb/1x/0004.png").unlink(),
        "dataset.json",
        "val_ids",
        "not found",
    ),
    "truncated rgb image": (
        "nerfies",
        lambda r: truncate(r / "rgb/1x/0000.png"),
        "dataset.json",
        "train_ids",
        "truncated",
    ),
    "camera missing focal_length": (
        "nerfies",
        lambda r: edit_json(r / "camera/0002.json", lambda d: d.pop("focal_length")),
        "0002.json",
        "focal_length",
        "missing",
    ),
    "camera orientation not a rotation": (
        "nerfies",
        lambda r: edit_json(r / "camera/0000.json", lambda d: d.update(orientation=[[2, 0, 0], [0, 1, 0], [0, 0, 1]])),
        "0000.json",
        "orientation",
        "not orthonormal",
    ),
    "image not matching image_size": (
        "nerfies",
        lambda r: write_png(r / "rgb/1x/0002.png", 32),
        "0002.json",
        "image_size",
        "expected 16x16",
    ),
    "empty train_ids": (
        "nerfies",
        lambda r: edit_json(r / "dataset.json", lambda d: d.update(train_ids=[])),
        "dataset.json",
        "train_ids",
        "empty train split for preset 'nerfds'",
    ),
    "malformed scene.json": (
        "nerfies",
        lambda r: (r / "scene.json").write_text("scale: 1"),
        "scene.json",
        None,
        "malformed JSON",
    ),
    "negative scale": (
        "nerfies",
        lambda r: edit_json(r / "scene.json", lambda d: d.update(scale=-1)),
        "scene.json",
        "scale",
        "positive",
    ),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_is_one_line_naming_file_and_field(case, pristine, tmp_path, capsys):
    layout, change, file_name, field, words = CASES[case]
    root = tmp_path / "scene"
    shutil.copytree(pristine / layout, root)
    change(root)

    with pytest.raises(DataError) as raised:
        load_dataset(DataConfig(path=root))
    message = str(raised.value)
    assert file_name in message and words in message
    if field is not None:
        assert f"field '{field}'" in message

    assert cli.main(["data", "check", str(root)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert message in err


def corrupt_pixel_data(path: Path) -> None:
    """Flip bytes inside IDAT and fix its CRC: the chunk walk passes, only inflating fails."""
    data = bytearray(path.read_bytes())
    start = data.index(b"IDAT") - 4
    length = struct.unpack(">I", data[start : start + 4])[0]
    body = slice(start + 8, start + 8 + length)
    data[body] = bytes(data[body])[:2] + bytes(b ^ 0x5A for b in data[body][2:])
    data[body.stop : body.stop + 4] = struct.pack(">I", zlib.crc32(data[start + 4 : body.stop]))
    path.write_bytes(bytes(data))


def test_pixel_corruption_is_caught_by_check_and_on_first_use(pristine, tmp_path):
    root = tmp_path / "scene"
    shutil.copytree(pristine / "dnerf", root)
    corrupt_pixel_data(root / "train/r_003.png")
    ds = load_dataset(DataConfig(path=root))  # structure and CRCs are intact
    with pytest.raises(DataError, match=r"r_003\.png: cannot decode image"):
        check_dataset(DataConfig(path=root))
    with pytest.raises(DataError, match=r"r_003\.png: cannot decode image"):
        ds.train[3].image()


def test_format_detection_uses_files_not_names(pristine, tmp_path):
    both = tmp_path / "nerfies_looking_name"
    shutil.copytree(pristine / "dnerf", both)
    assert load_dataset(DataConfig(path=both)).format == "dnerf"
    shutil.copy(pristine / "nerfies" / "dataset.json", both)
    with pytest.raises(DataError, match="holds both"):
        load_dataset(DataConfig(path=both))
    with pytest.raises(DataError, match="neither transforms_train.json"):
        load_dataset(DataConfig(path=tmp_path))
    with pytest.raises(DataError, match="dataset folder not found"):
        load_dataset(DataConfig(path=tmp_path / "absent"))


def test_distortion_is_reported_by_check_and_warned_on_load(pristine, tmp_path):
    root = tmp_path / "scene"
    shutil.copytree(pristine / "nerfies", root)
    edit_json(root / "camera/0001.json", lambda d: d.pop("tangential_distortion") and d.update(tangential=[0.01, 0]))
    with pytest.warns(UserWarning, match="nonzero lens distortion"):
        load_dataset(DataConfig(path=root))
    lines = check_dataset(DataConfig(path=root)).lines()
    assert any(line.startswith("warning:") and "camera/0001.json" in line for line in lines)


def test_hyper_nerf_interp_capture_is_read_with_the_interp_split(pristine, tmp_path):
    """A HyperNeRF interp capture: empty val_ids, pixel_aspect_ratio, radial + tangential distortion."""
    root = tmp_path / "interp"
    shutil.copytree(pristine / "nerfies", root)
    edit_json(root / "dataset.json", lambda d: d.update(val_ids=[]))
    for camera in (root / "camera").glob("*.json"):
        edit_json(camera, lambda d: d.update(pixel_aspect_ratio=1.0, radial_distortion=[0.01, -0.002, 0.0],
                                             tangential_distortion=[0.0005, -0.0003]))  # fmt: skip
    ids = json.loads((root / "dataset.json").read_text())["ids"]
    with pytest.warns(UserWarning) as caught:
        ds = load_dataset(DataConfig(path=root))
    assert [f.name for f in ds.train] == ids[::4] and [f.name for f in ds.test] == ids[2::4]
    assert any("empty val_ids, so split 'auto' reads it as an interp capture" in str(w.message) for w in caught)
    with pytest.raises(DataError, match=r"empty test split for preset 'nerfds' \(.*use --split interp\)"):
        load_dataset(DataConfig(path=root, split="nerfds"))
