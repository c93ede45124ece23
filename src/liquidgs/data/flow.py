"""A capture's optical flow and motion masks in its scene folder: computed, checked and read.

For a scene in the Nerfies layout (what `data video` / `data images` write), at one image scale
(rgb/<k>x, the training resolution), compute_scene_flow writes:

- flow between each train frame and the next train frame in time, forward and backward
  (data.optical_flow: DIS), with each direction's forward-backward consistency: a pixel whose flow
  and the flow back from where it lands do not cancel (an occlusion, a failure) is inconsistent;
- tracks: the flow of TRACK_STEP consecutive pairs chained (chain_flow) into the flow from each
  train frame to the train frame TRACK_STEP later and back - point tracks over TRACK_STEP + 1 frames,
  each kept where every link is consistent and inside the image and the chained flow is consistent
  with the chain back, so a track is cut where it is occluded or leaves the frame;
- a motion mask for every frame, train and test (data.motion_masks: what the cameras' motion cannot
  explain; test frames never feed training, their flow serves only their own mask).

Layout, in the scene folder:

    flow/<k>x/flow.json          FLOW_FORMAT: size, preset, threshold, the pairs, and the SHA-256 of
                                 every image and camera file the flow was computed from (stale flow
                                 is refused by `data check` and every reader)
    flow/<k>x/pairs/<a>--<b>.npz forward (a -> b) and backward (b -> a) flow, float16 [H, W, 2] in
                                 pixels, and forward_consistent / backward_consistent, bool [H, W]:
                                 for each pair of neighbouring train frames, and for each track
                                 (flow.json's "tracks", absent in flow computed before them)
    flow/<k>x/masks/<id>.png     the motion mask, 255 inside (the masks `eval --mask` reads)

flow/<k>x is built under a hidden name and renamed into place (atomic.build_atomically): complete or
absent, an older one replaced only by a complete one. The flow folder
is derived from the frames and cameras, so it is not part of a run's scene print (adding flow to a
scene leaves the runs trained on it valid); flow.json's own hashes say when it is stale.
"""

from __future__ import annotations

import functools
import json
import time
import warnings
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from liquidgs.atomic import build_atomically, write_json_atomic
from liquidgs.data.loading import CAPTURE_FORMATS, detect_format, load_dataset
from liquidgs.data.motion_masks import (
    FRAME_STEP,
    MIN_REGION_SHARE,
    MIN_TEXTURE,
    MOTION_THRESHOLD_PX,
    PARALLAX_PX,
    camera_motion_error,
    median_depth,
    motion_mask,
    textured,
)
from liquidgs.data.nerfies import RGB_FOLDER, camera_path, read_camera, read_scale
from liquidgs.data.optical_flow import DIS_PRESET, chain_flow, consistent, optical_flow
from liquidgs.data.scene import DataConfig, Frame, SceneDataset
from liquidgs.errors import DataError, LiquidGSError
from liquidgs.file_hash import file_sha256

FLOW_FOLDER = "flow"
FLOW_FILE = "flow.json"
FLOW_FORMAT = "liquidgs-flow-1"
PAIRS_FOLDER = "pairs"
MASKS_FOLDER = "masks"
TRACK_STEP = 3
"""Tracks chain this many pairs of neighbouring train frames: the same step as the masks', so a
track spans what a mask compares (docs/results/real-clips.md: what training on them gave)."""
MIN_TRAIN_FRAMES = 2

Log = Callable[[str], None]


def _pair_arrays(forward: np.ndarray, backward: np.ndarray, forward_valid=None, backward_valid=None) -> dict:
    """A pair file's arrays; each direction consistent with the other (and valid where given)."""
    forward_consistent, backward_consistent = consistent(forward, backward), consistent(backward, forward)
    if forward_valid is not None:
        forward_consistent &= forward_valid
        backward_consistent &= backward_valid
    return {"forward": forward.astype(np.float16), "backward": backward.astype(np.float16),
            "forward_consistent": forward_consistent, "backward_consistent": backward_consistent}  # fmt: skip


@dataclass
class FlowSummary:
    folder: Path
    pairs: int
    tracks: int
    masks: int
    size: tuple[int, int]
    seconds: float
    mean_moving_share: float


def flow_folder(scene: Path, factor: int) -> Path:
    return Path(scene) / FLOW_FOLDER / f"{factor}x"


def has_flow(data: DataConfig) -> bool:
    """Whether a run on `data` finds optical flow at the scale it reads its frames at: a capture with
    flow/<k>x/flow.json there (whether that flow is current is checked where it is read). False where
    the folder cannot say (not a scene yet: the data's own check says why)."""
    try:
        data_format = data.format if data.format != "auto" else detect_format(data.path)
        if data_format not in CAPTURE_FORMATS:
            return False
        return (flow_folder(data.path, read_scale(data)) / FLOW_FILE).is_file()
    except LiquidGSError:
        return False


def _sources(dataset: SceneDataset, frames: list[Frame]) -> dict[str, str]:
    """Every file the flow of `frames` is computed from (images and camera files), by its path in the
    scene folder, with its SHA-256."""
    root = dataset.root
    files = {}
    for frame in frames:
        for path in (frame.image_path, camera_path(root, frame.name)):
            if path.is_file():
                files[path.relative_to(root).as_posix()] = file_sha256(path)
    return files


def image_scale(scene: Path, frames: list[Frame]) -> int:
    """k of the scale the frames were read at (1/k of the camera files' size: rgb/<k>x, or a coarser
    scale area-averaged from a finer folder), the same for all of them."""
    scales = set()
    for frame in frames:
        camera_file = camera_path(Path(scene), frame.name)
        if frame.image_path.parent.parent.name != RGB_FOLDER or not camera_file.is_file():
            raise LiquidGSError(
                f"optical flow reads a Nerfies-layout scene (rgb/<k>x/<id>.png); {frame.image_path} is not"
            )
        full_width = read_camera(camera_file).image_size[0]
        scales.add(round(full_width / frame.camera.width))
    if len(scales) != 1:
        raise DataError(scene, f"frames read at several scales {sorted(scales)}: optical flow needs one")
    return scales.pop()


def _time_order(frames: list[Frame]) -> list[Frame]:
    return sorted(frames, key=lambda f: (f.time, f.name))


def _neighbours(frame: Frame, train: list[Frame]) -> list[Frame]:
    """The train frames FRAME_STEP train frames before and after `frame` in time (itself excluded),
    or the furthest there is on a side with fewer."""
    before = [f for f in train if f is not frame and (f.time, f.name) < (frame.time, frame.name)]
    after = [f for f in train if f is not frame and (f.time, f.name) > (frame.time, frame.name)]
    return [*before[-FRAME_STEP:][:1], *after[:FRAME_STEP][-1:]]


def _load_scene(scene: Path, downscale: int | None) -> SceneDataset:
    with warnings.catch_warnings():  # what training must hear of (distortion, a fixed camera) is not flow's
        warnings.simplefilter("ignore")
        return load_dataset(DataConfig(path=Path(scene), format="nerfies", downscale=downscale, cache_images=0))


def scene_image_size(scene: Path) -> tuple[int, int]:
    """(width, height) of a Nerfies-layout scene's full-size (rgb/1x) frames."""
    frame = _load_scene(scene, 1).train[0]
    return frame.camera.width, frame.camera.height


def compute_scene_flow(scene: Path, downscale: int | None, log: Log | None = None) -> FlowSummary:
    """Flow and motion masks of `scene` at rgb/<downscale>x (None: the split's default), written to
    flow/<k>x whole; an existing flow/<k>x is replaced only once the new one is complete."""
    started = time.perf_counter()
    log = log or (lambda line: None)
    dataset = _load_scene(scene, downscale)
    train = _time_order(dataset.train)
    everything = _time_order([*dataset.train, *dataset.test])
    if len(train) < MIN_TRAIN_FRAMES:
        raise DataError(
            scene, f"optical flow needs at least {MIN_TRAIN_FRAMES} train frames, the scene has {len(train)}"
        )
    sizes = {(f.camera.width, f.camera.height) for f in everything}
    if len(sizes) != 1:
        raise DataError(scene, f"frames of mixed sizes {sorted(sizes)}: optical flow needs one size")
    factor = image_scale(scene, everything)
    width, height = sizes.pop()
    points = dataset.points.double().numpy() if dataset.points is not None else None
    out = flow_folder(scene, factor)
    neighbours = {frame.name: _neighbours(frame, train) for frame in everything}
    uses = Counter(frozenset((name, other.name)) for name, others in neighbours.items() for other in others)
    flows: dict[tuple[str, str], np.ndarray] = {}  # a train frame and its neighbour share a pair's flow

    @functools.lru_cache(maxsize=2 * FRAME_STEP + 2)  # the frames a mask compares, decoded once
    def image_of(frame: Frame) -> np.ndarray:
        return frame.image_uint8()

    def flow_of(a: Frame, b: Frame) -> np.ndarray:
        if (a.name, b.name) not in flows:
            flows[(a.name, b.name)] = optical_flow(image_of(a), image_of(b))
        return flows[(a.name, b.name)]

    pairs = list(zip(train[:-1], train[1:], strict=True))
    tracks = list(zip(train[:-TRACK_STEP], train[TRACK_STEP:], strict=True))

    def build(building: Path) -> list[float]:
        (building / PAIRS_FOLDER).mkdir()
        (building / MASKS_FOLDER).mkdir()
        links = []  # the last TRACK_STEP pairs' arrays, float32 flow
        for i, (a, b) in enumerate(pairs):
            image_a, image_b = image_of(a), image_of(b)
            forward, backward = optical_flow(image_a, image_b), optical_flow(image_b, image_a)
            arrays = _pair_arrays(forward, backward)
            np.savez_compressed(building / PAIRS_FOLDER / f"{a.name}--{b.name}.npz", **arrays)
            links = [*links, {**arrays, "forward": forward, "backward": backward}][-TRACK_STEP:]
            if len(links) == TRACK_STEP:  # the track from TRACK_STEP frames back to b, and back
                along, along_valid = chain_flow(*_link_arrays(links, "forward"))
                back, back_valid = chain_flow(*_link_arrays(links[::-1], "backward"))
                start = train[i + 1 - TRACK_STEP]
                np.savez_compressed(building / PAIRS_FOLDER / f"{start.name}--{b.name}.npz",
                                    **_pair_arrays(along, back, along_valid, back_valid))  # fmt: skip
            if (i + 1) % 10 == 0 or i + 1 == len(pairs):
                log(f"flow: {i + 1}/{len(pairs)} pairs of train frames and the tracks ending there")
        shares = []
        for i, frame in enumerate(everything):
            depth = median_depth(frame.camera, points)
            errors = []
            for other in neighbours[frame.name]:
                forward, backward = flow_of(frame, other), flow_of(other, frame)
                error = camera_motion_error(forward, frame.camera, other.camera, depth)
                errors.append((error, consistent(forward, backward)))
            mask = motion_mask(errors, textured(image_of(frame)))
            shares.append(float(mask.mean()))
            _write_png(building / MASKS_FOLDER / f"{frame.name}.png", mask)
            for other in neighbours[frame.name]:  # kept until the other end's mask has used it too
                pair = frozenset((frame.name, other.name))
                uses[pair] -= 1
                if not uses[pair]:
                    flows.pop((frame.name, other.name), None)
                    flows.pop((other.name, frame.name), None)
            if (i + 1) % 10 == 0 or i + 1 == len(everything):
                log(f"flow: {i + 1}/{len(everything)} motion masks")
        record = {
            "format": FLOW_FORMAT,
            "scale": factor,
            "size": [width, height],
            "preset": DIS_PRESET,
            "threshold_px": MOTION_THRESHOLD_PX,
            "parallax_px": PARALLAX_PX,
            "min_region_share": MIN_REGION_SHARE,
            "min_texture": MIN_TEXTURE,
            "frame_step": FRAME_STEP,
            "pairs": [[a.name, b.name] for a, b in pairs],
            "track_step": TRACK_STEP,
            "tracks": [[a.name, b.name] for a, b in tracks],
            "masks": [frame.name for frame in everything],
            "sources": _sources(dataset, everything),
        }
        write_json_atomic(building / FLOW_FILE, record)
        return shares

    shares = build_atomically(out, build, replace=True)
    seconds = time.perf_counter() - started
    return FlowSummary(out, len(pairs), len(tracks), len(everything), (width, height), seconds,
                       float(np.mean(shares)))  # fmt: skip


def _link_arrays(links: list[dict], direction: str) -> tuple[list[np.ndarray], list[np.ndarray]]:
    return [link[direction] for link in links], [link[f"{direction}_consistent"] for link in links]


def _write_png(path: Path, mask: np.ndarray) -> None:
    from PIL import Image

    Image.fromarray((mask * 255).astype(np.uint8)).save(path)


def check_flow(scene: Path, factor: int) -> list[str]:
    """What is wrong with flow/<factor>x of `scene`, one line each naming the file (empty: nothing)."""
    folder = flow_folder(scene, factor)
    path = folder / FLOW_FILE
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        return [f"{path}: unreadable ({err})"]
    if not isinstance(record, dict) or record.get("format") != FLOW_FORMAT:
        return [f"{path}: field 'format': not {FLOW_FORMAT}"]
    size, pairs, masks, sources = (record.get(k) for k in ("size", "pairs", "masks", "sources"))
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) for v in size)):
        return [f"{path}: field 'size': not [width, height]"]
    if not (isinstance(pairs, list) and isinstance(masks, list) and isinstance(sources, dict)):
        return [f"{path}: fields 'pairs', 'masks', 'sources': missing or malformed"]
    problems = []
    for name, digest in sources.items():
        source = Path(scene) / name
        if not source.is_file():
            problems.append(f"{source}: missing, but the flow in {folder} was computed from it")
        elif file_sha256(source) != digest:
            problems.append(f"{source}: changed since the flow in {folder} was computed from it (stale flow)")
        if problems:
            return problems + [f"recompute it: liquidgs data flow {scene}"]
    tracks = record.get("tracks", [])
    if not isinstance(tracks, list):
        return [f"{path}: field 'tracks': not a list of pairs"]
    step = record.get("track_step")
    if "tracks" in record and not (isinstance(step, int) and not isinstance(step, bool) and step >= 1):
        return [f"{path}: field 'track_step': not the number of pairs each track chains"]
    width, height = size
    for pair in [*pairs, *tracks]:
        file = folder / PAIRS_FOLDER / f"{pair[0]}--{pair[1]}.npz"
        problems += _check_pair(file, width, height)
    for name in masks:
        problems += _check_mask(folder / MASKS_FOLDER / f"{name}.png", width, height)
    return problems


def _check_pair(file: Path, width: int, height: int) -> list[str]:
    try:
        with np.load(file) as data:
            arrays = {key: data[key] for key in ("forward", "backward", "forward_consistent", "backward_consistent")}
    except (OSError, ValueError, KeyError) as err:
        return [f"{file}: unreadable flow ({err})"]
    for key in ("forward", "backward"):
        if arrays[key].shape != (height, width, 2):
            return [f"{file}: field '{key}': shape {arrays[key].shape}, expected {(height, width, 2)}"]
        if not np.isfinite(arrays[key]).all():
            return [f"{file}: field '{key}': {int((~np.isfinite(arrays[key])).sum())} non-finite values"]
    return []


def _check_mask(file: Path, width: int, height: int) -> list[str]:
    from PIL import Image

    try:
        with Image.open(file) as image:
            size = image.size
    except OSError as err:
        return [f"{file}: unreadable mask ({err})"]
    return [] if size == (width, height) else [f"{file}: {size[0]}x{size[1]}, the flow is {width}x{height}"]


def check_scene_flow(scene: Path) -> list[str]:
    """`data check`'s lines for every flow/<k>x of `scene`; the first problem is a DataError."""
    lines = []
    for folder in sorted((Path(scene) / FLOW_FOLDER).glob("*x")):
        if not folder.is_dir() or not folder.name[:-1].isdigit():
            continue
        problems = check_flow(scene, int(folder.name[:-1]))
        if problems:
            raise LiquidGSError(problems[0])
        record = json.loads((folder / FLOW_FILE).read_text())
        width, height = record["size"]
        tracks = record.get("tracks")
        tracks = f", {len(tracks)} tracks over {record['track_step'] + 1} frames" if tracks is not None else ""
        lines.append(
            f"flow:       {folder.name}: {len(record['pairs'])} pairs{tracks}, {len(record['masks'])} motion masks "
            f"at {width}x{height}, computed from the frames and cameras as they are"
        )
    return lines


AUTO_MASKS = "auto"
"""`eval --mask auto`: the scene's own motion masks."""


def scene_motion_masks(scene: Path, views: list[Frame]) -> Path:
    """flow/<k>x/masks of `scene` at the scale `views` were read at, checked first (missing or stale:
    one line)."""
    return checked_flow_folder(scene, image_scale(scene, views), "motion masks") / MASKS_FOLDER


def read_motion_masks(scene: Path, frames: list[Frame]) -> tuple[Path, np.ndarray]:
    """The masks folder and bool [F, H, W]: the motion masks of `frames` at the scale they were read
    at (checked first: missing or stale flow is one line)."""
    from PIL import Image

    folder = scene_motion_masks(scene, frames)
    masks = []
    for frame in frames:
        path = folder / f"{frame.name}.png"
        if not path.is_file():
            raise DataError(path, f"no motion mask for frame '{frame.name}'; compute them again: liquidgs data flow")
        masks.append(np.asarray(Image.open(path)) > 127)
    return folder, np.stack(masks)


def checked_flow_folder(scene: Path, factor: int, what: str) -> Path:
    """flow/<factor>x of `scene`, refused in one line where it is missing (naming the command that
    makes it) or stale."""
    folder = flow_folder(scene, factor)
    if not (folder / FLOW_FILE).is_file():
        raise DataError(
            folder, f"no {what} at this scale; compute them: liquidgs data flow {scene} --downscale {factor}"
        )
    problems = check_flow(scene, factor)
    if problems:
        raise LiquidGSError(problems[0])
    return folder


@dataclass
class FlowPair:
    """The measured flow between two train frames (names), at the training scale: neighbours, or the
    ends of a track (`track`, chained over TRACK_STEP pairs)."""

    first: str
    second: str
    forward: np.ndarray  # [H, W, 2] float32, first -> second
    backward: np.ndarray  # second -> first
    forward_consistent: np.ndarray  # [H, W] bool
    backward_consistent: np.ndarray
    track: bool = False


def read_flow_pairs(scene: Path, factor: int, tracks: bool = False) -> list[FlowPair]:
    """flow/<factor>x's pairs of neighbouring train frames of `scene`, and its tracks where asked,
    checked first (missing or stale: one line)."""
    folder = checked_flow_folder(scene, factor, "optical flow")
    record = json.loads((folder / FLOW_FILE).read_text())
    pairs = []
    wanted = [(names, False) for names in record["pairs"]]
    if tracks:
        wanted += [(names, True) for names in record.get("tracks", [])]
    for (first, second), track in wanted:
        with np.load(folder / PAIRS_FOLDER / f"{first}--{second}.npz") as data:
            flows = [data[key].astype(np.float32) for key in ("forward", "backward")]
            consistency = data["forward_consistent"], data["backward_consistent"]
            pairs.append(FlowPair(first, second, *flows, *consistency, track=track))
    return pairs
