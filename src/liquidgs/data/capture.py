"""Your own capture -> a scene in the Nerfies layout: frames, COLMAP cameras, splits, times, points.

The registered frames are undistorted into a pinhole camera by COLMAP's own undistorter (the
rasteriser is pinhole), cropped to valid pixels (see colmap.undistorters), unless
keep_distortion asks for the frames as decoded and the lens's k1 in the camera files.

Everything is built in a hidden temporary folder beside the output (.<name>.partial-*) and moved
into place by one rename at the end (atomic.build_atomically, also used by `data undistort`), so a
failure or an interrupt leaves no folder that looks like a scene.
"""

from __future__ import annotations

import copy
import os
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from liquidgs.atomic import build_atomically, write_json_atomic
from liquidgs.data.colmap import (
    Log,
    SolveOptions,
    Undistorter,
    describe_camera,
    solve_cameras,
    undistorters,
)
from liquidgs.data.flow import compute_scene_flow
from liquidgs.data.motion_masks import two_view_motion_masks
from liquidgs.data.nerfies import (
    CAMERA_FOLDER,
    DATASET_FILE,
    METADATA_FILE,
    POINTS_FILE,
    SCENE_FILE,
    NerfiesCamera,
    camera_json,
    camera_path,
    rgb_folder,
)
from liquidgs.data.stage_times import StageTimes
from liquidgs.data.validate import open_image
from liquidgs.data.video import (
    SIDE_MULTIPLE,
    ExtractedFrame,
    check_changes,
    collect_image_frames,
    crop_to_multiple,
    extract_video_frames,
)
from liquidgs.errors import ConfigError, DataError
from liquidgs.media import save_frame_png

CAPTURE_FILE = "capture.json"  # how the scene was made: source, registered and dropped frames, errors
# COLMAP's model the cameras come from (every keypoint, track and camera), for COLMAP's own tools.
SPARSE_FOLDER = "colmap/sparse"
SCALES = (1, 2, 4)  # rgb/<k>x folders written
# scene.json's scale puts the median depth of what the cameras see at this distance: the D-NeRF
# cameras' distance from their object, the scale the training presets are tuned for (the fields'
# deformation and the means' learning rate are in absolute units).
VIEWING_DISTANCE = 4.0


@dataclass
class CaptureSettings:
    fps: float | None = None
    frames: int | None = None
    max_size: int = 800
    holdout_every: int = 8
    mask_dir: Path | None = None
    solve: SolveOptions = field(default_factory=SolveOptions)
    keep_distortion: bool = False
    """Write the frames as decoded, with COLMAP's k1 in the camera files (trained as if pinhole)."""
    flow: bool = True
    """Optical flow and motion masks (data.flow) at the training scale (training_downscale)."""
    mask_moving: bool = False
    """Without mask_dir: no features where the two-view motion masks (data.motion_masks) see motion."""


TRAINING_SIDE = 128
"""The quick look trains at the largest downscale that keeps the longer side at least this long."""


def training_downscale(size: tuple[int, int]) -> int:
    """The rgb/<k>x a capture of `size` (width, height at 1x) trains at in the quick look, and the
    scale its optical flow is computed at."""
    return next(k for k in (4, 2, 1) if max(size) / k >= TRAINING_SIDE or k == 1)


def held_out_views(ids: list[str], holdout_every: int) -> list[str]:
    """The registered frames held out as test views: every `holdout_every`th, from the middle of the first stride."""
    return [image_id for n, image_id in enumerate(ids) if n % holdout_every == holdout_every // 2]


@dataclass
class CaptureSummary:
    out: str
    source: str
    frames_total: int
    frames_registered: int
    dropped: list[dict[str, str]]
    """Frames COLMAP could not register: their id and where they came from."""
    train: int
    test: int
    holdout_every: int
    mean_reprojection_error_px: float
    points: int
    image_size: tuple[int, int]
    """(width, height) of rgb/1x."""
    undistortion: dict | None
    """The lens COLMAP fitted and the pinhole camera the frames were undistorted into; None
    with keep_distortion."""
    matcher: str
    """The matcher of the attempt whose model is used."""
    masked: bool
    feature_masks: str
    """What kept features off moving things: "mask-dynamic" (the user's masks), "flow" (two-view motion
    masks) or "none"."""
    camera_solve: dict
    """Which attempt's model is used ("attempt"), every attempt made ("attempts": name, matcher, mapper,
    changes, result: "used", "usable" or the refusal, warnings, seconds) and the used model's
    plausibility warnings ("warnings")."""
    seconds: dict[str, float]
    """Wall seconds per stage: extraction, features, matching, mapping, undistortion, writing, flow."""
    cpu_seconds: dict[str, float]
    """CPU seconds per stage (every thread, and ffmpeg's): the work, where wall time includes waiting."""


def refuse_taken(out: Path) -> None:
    """An output folder must not exist, or be empty: a scene is never written over anything."""
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"--out {out}: already exists and is not an empty folder; choose a new folder")


def capture_scene(source: Path, out: Path, settings: CaptureSettings, log: Log, *, video: bool) -> CaptureSummary:
    """Build the scene of `source` (a video, or a folder of images when video is False) at `out`."""
    refuse_taken(out)
    if settings.holdout_every < 2:
        raise ConfigError(f"--holdout-every must be at least 2, got {settings.holdout_every}")
    if settings.mask_dir is not None and not settings.mask_dir.is_dir():
        raise DataError(settings.mask_dir, "--mask-dynamic: mask folder not found")

    def build(building: Path) -> CaptureSummary:
        times = StageTimes()
        summary = _build(source, building, settings, log, times, video=video)
        summary.out = str(out)
        if settings.flow:
            with times.stage("flow"):
                compute_scene_flow(building, training_downscale(summary.image_size), log)
        recorded = times.record()
        summary.seconds, summary.cpu_seconds = recorded["wall"], recorded["cpu"]
        log(f"time: {times.line()}")
        write_json_atomic(building / CAPTURE_FILE, asdict(summary))
        return summary

    return build_atomically(out, build)


def _build(
    source: Path, scene: Path, settings: CaptureSettings, log: Log, times: StageTimes, *, video: bool
) -> CaptureSummary:
    work = scene / ".work"
    frames_dir = work / "frames"
    frames_dir.mkdir(parents=True)

    with times.stage("extraction"):
        if video:
            frames = extract_video_frames(
                source, frames_dir, fps=settings.fps, frames=settings.frames, max_size=settings.max_size, log=log
            )
        else:
            frames = collect_image_frames(source, frames_dir, max_size=settings.max_size, log=log)
    if len(frames) < 2:
        raise DataError(source, f"gives {len(frames)} frame; a scene needs at least 2")
    check_changes(source, frames_dir, frames)

    mask_dir = None
    if settings.mask_dir is not None:
        mask_dir = work / "masks"
        _colmap_masks(settings.mask_dir, frames, mask_dir, log)
    elif settings.mask_moving:
        mask_dir = work / "masks"
        with times.stage("feature masks"):
            _flow_masks(frames, frames_dir, mask_dir, log)

    names = [f"{frame.id}.png" for frame in frames]
    solved = solve_cameras(frames_dir, names, work, settings.solve, log, mask_dir=mask_dir)
    times.merge(solved.times)
    for warning in solved.warnings:
        log(f"warning: {warning}")

    summary = _write_scene(scene, frames, frames_dir, solved.model, settings, log, times)
    summary.matcher = solved.matcher
    summary.camera_solve = {"attempt": solved.attempt, "attempts": solved.attempts, "warnings": solved.warnings,
                            "keyframes": solved.keyframes}
    with times.stage("writing"):
        shutil.rmtree(work)
    summary.source = str(source)
    return summary


def _median_depth(model) -> float:
    """The median depth of every observed point in the camera that observes it."""
    poses = {image_id: image.cam_from_world() for image_id, image in model.images.items() if image.has_pose}
    # Depth = row 3 of the world->camera transform applied to the point.
    depth_rows = {i: np.append(pose.rotation.matrix()[2], pose.translation[2]) for i, pose in poses.items()}
    depths = [
        float(depth_rows[element.image_id] @ np.append(point.xyz, 1.0))
        for point in model.points3D.values()
        for element in point.track.elements
    ]
    return float(np.median(depths))


def _colmap_masks(user_dir: Path, frames: list[ExtractedFrame], mask_dir: Path, log: Log) -> None:
    """User masks (nonzero = moving) -> COLMAP masks (<image name>.png, zero = no features)."""
    mask_dir.mkdir()
    dynamic_share = []
    for frame in frames:
        path = user_dir / frame.mask_name
        if not path.is_file():
            raise DataError(path, f"--mask-dynamic: no mask for {frame.source} (one per frame, named {path.name})")
        mask = open_image(path, "L", "--mask-dynamic mask").resize(frame.scaled_size, Image.Resampling.NEAREST)
        dynamic = crop_to_multiple(np.asarray(mask)) > 0
        dynamic_share.append(dynamic.mean())
        Image.fromarray(np.where(dynamic, 0, 255).astype(np.uint8)).save(mask_dir / f"{frame.id}.png.png")
    log(
        f"masks: {len(frames)} frames, {100 * np.mean(dynamic_share):.1f}% of pixels marked moving on average "
        "(no features there)"
    )


def _flow_masks(frames: list[ExtractedFrame], frames_dir: Path, mask_dir: Path, log: Log) -> None:
    """COLMAP masks (zero = no features) of what moves, from flow at the training scale (two_view_motion_masks)."""
    mask_dir.mkdir()
    images = []
    for frame in frames:
        with Image.open(frames_dir / f"{frame.id}.png") as decoded:
            full_size = decoded.size
            images.append(np.asarray(decoded.convert("RGB").reduce(training_downscale(full_size))))
    masks = two_view_motion_masks(images, log)
    for frame, moving in zip(frames, masks):
        full = Image.fromarray(np.where(moving, 0, 255).astype(np.uint8)).resize(full_size, Image.Resampling.NEAREST)
        full.save(mask_dir / f"{frame.id}.png.png")
    log(
        f"feature masks: {100 * np.mean([mask.mean() for mask in masks]):.1f}% of pixels seen moving on average "
        "(no features there)"
    )


def _write_scene(
    scene: Path,
    frames: list[ExtractedFrame],
    frames_dir: Path,
    model,
    settings: CaptureSettings,
    log: Log,
    times: StageTimes,
) -> CaptureSummary:
    """The scene's files from the model; the lens's undistortion (camera and image warps) is timed as
    "undistortion", the rest as "writing"."""
    with times.stage("writing"):
        return _write_files(scene, frames, frames_dir, model, settings, log, times)


def _write_files(scene, frames, frames_dir, model, settings, log, times: StageTimes) -> CaptureSummary:
    by_name = {image.name: image for image in model.images.values() if image.has_pose}
    registered = [frame for frame in frames if f"{frame.id}.png" in by_name]
    dropped = [{"id": frame.id, "source": frame.source} for frame in frames if f"{frame.id}.png" not in by_name]
    if dropped:
        shown = ", ".join(item["source"] for item in dropped[:20]) + (" ..." if len(dropped) > 20 else "")
        log(f"writing: {len(dropped)} frame(s) COLMAP could not register are dropped: {shown}")

    error = float(model.compute_mean_reprojection_error())  # of COLMAP's own solution, before any undistortion
    # Copies: model.cameras hands out references, and the model's cameras become pinhole below.
    used = {by_name[f"{frame.id}.png"].camera_id for frame in registered}
    lens = {camera_id: copy.copy(model.cameras[camera_id]) for camera_id in sorted(used)}
    undistort: dict[int, Undistorter] = {}
    if not settings.keep_distortion:
        with times.stage("undistortion"):
            undistort = dict(zip(lens, undistorters(list(lens.values()), SIDE_MULTIPLE)))
        for camera_id, undistorter in undistort.items():
            before, after = describe_camera(lens[camera_id]), describe_camera(undistorter.pinhole)
            log(f"undistortion: {before} -> {after}, cropped to valid pixels")

    for factor in SCALES:
        rgb_folder(scene, factor).mkdir(parents=True)
    (scene / CAMERA_FOLDER).mkdir()
    for frame in registered:
        image = by_name[f"{frame.id}.png"]
        undistorter = undistort.get(image.camera_id)
        camera = undistorter.pinhole if undistorter else lens[image.camera_id]
        pose = image.cam_from_world()
        rotation = np.asarray(pose.rotation.matrix(), dtype=np.float64)
        position = -rotation.T @ np.asarray(pose.translation, dtype=np.float64)
        write_json_atomic(camera_path(scene, frame.id), camera_json(_nerfies_camera(camera, rotation, position)))
        source = frames_dir / f"{frame.id}.png"
        with Image.open(source) as decoded:
            if undistorter:
                with times.stage("undistortion"):
                    full = Image.fromarray(undistorter.image(np.asarray(decoded.convert("RGB"))))
            else:
                full = decoded
            for factor in SCALES[1:]:
                save_frame_png(full.reduce(factor), rgb_folder(scene, factor) / source.name)
            if undistorter:
                save_frame_png(full, rgb_folder(scene, 1) / source.name)
        if not undistorter:
            os.replace(source, rgb_folder(scene, 1) / source.name)

    ids = [frame.id for frame in registered]
    test_ids = held_out_views(ids, settings.holdout_every)
    held_out_ids = set(test_ids)
    train_ids = [image_id for image_id in ids if image_id not in held_out_ids]
    if not test_ids:
        raise ConfigError(
            f"--holdout-every {settings.holdout_every} holds out none of the {len(ids)} registered frames; "
            "choose a smaller value"
        )
    write_json_atomic(
        scene / DATASET_FILE,
        {"count": len(ids), "num_exemplars": len(train_ids), "ids": ids, "train_ids": train_ids, "val_ids": test_ids},
    )
    write_json_atomic(
        scene / METADATA_FILE,
        {
            frame.id: {"time_id": frame.time_id, "warp_id": n, "appearance_id": n, "camera_id": 0}
            for n, frame in enumerate(registered)
        },
    )

    xyz = np.array([point.xyz for point in model.points3D.values()], dtype=np.float64).reshape(-1, 3)
    colors = np.array([point.color for point in model.points3D.values()], dtype=np.float64).reshape(-1, 3)
    center = np.median(xyz, axis=0)
    scale = VIEWING_DISTANCE / max(_median_depth(model), 1e-9)
    write_json_atomic(scene / SCENE_FILE, {"center": center.tolist(), "scale": scale})
    np.save(scene / POINTS_FILE, np.concatenate([xyz, colors / 255.0], axis=1).astype(np.float32))
    for camera_id, undistorter in undistort.items():
        _undistort_model(model, camera_id, undistorter)
    (scene / SPARSE_FOLDER).mkdir(parents=True)
    model.write(scene / SPARSE_FOLDER)

    first = model.cameras[by_name[f"{registered[0].id}.png"].camera_id]
    log(
        f"writing: {len(ids)} frames ({len(train_ids)} train, {len(test_ids)} test: every "
        f"{settings.holdout_every}th from the {settings.holdout_every // 2 + 1}th), rgb/1x 2x 4x, {len(xyz)} points"
    )
    return CaptureSummary(
        out="",
        source="",
        frames_total=len(frames),
        frames_registered=len(registered),
        dropped=dropped,
        train=len(train_ids),
        test=len(test_ids),
        holdout_every=settings.holdout_every,
        mean_reprojection_error_px=round(error, 4),
        points=len(xyz),
        image_size=(first.width, first.height),
        undistortion=_undistortion_record(lens, undistort),
        matcher=settings.solve.matcher,
        masked=settings.mask_dir is not None,
        feature_masks="mask-dynamic" if settings.mask_dir else ("flow" if settings.mask_moving else "none"),
        camera_solve={},
        seconds={},
        cpu_seconds={},
    )


def _nerfies_camera(camera, rotation: np.ndarray, position: np.ndarray) -> NerfiesCamera:
    """A COLMAP SIMPLE_RADIAL (f, cx, cy, k) or PINHOLE (fx, fy, cx, cy) camera at this pose."""
    if camera.model_name == "SIMPLE_RADIAL":
        fx, cx, cy, k1 = (float(v) for v in camera.params)
        fy = fx
    elif camera.model_name == "PINHOLE":
        fx, fy, cx, cy = (float(v) for v in camera.params)
        k1 = 0.0
    else:  # the pipeline asks COLMAP for SIMPLE_RADIAL and undistorts into PINHOLE
        raise ValueError(f"unexpected COLMAP camera model {camera.model_name}")
    return NerfiesCamera(
        rotation=rotation,
        position=position,
        focal_length=fx,
        pixel_aspect_ratio=fy / fx,
        principal_point=np.array([cx, cy]),  # COLMAP's pixel centres are at +0.5, as ours
        skew=0.0,
        image_size=(camera.width, camera.height),
        distortion=np.array([k1, 0.0, 0.0, 0.0, 0.0]),
    )


def _undistort_model(model, camera_id: int, undistorter: Undistorter) -> None:
    """COLMAP's model as seen by the undistorted frames: the pinhole camera, every keypoint moved
    with its pixel (as COLMAP's own undistorter writes its sparse model). Poses and points stay."""
    for image in model.images.values():
        if image.camera_id == camera_id and image.num_points2D():
            points = image.points2D
            moved = undistorter.points(np.array([point.xy for point in points]))
            for point, xy in zip(points, moved):
                point.xy = xy
    model.cameras[camera_id] = undistorter.pinhole


def _camera_record(camera) -> dict:
    return {"model": camera.model_name, "params": camera.params.tolist(), "size": [camera.width, camera.height]}


def _undistortion_record(lens: dict, undistort: dict[int, Undistorter]) -> dict | None:
    """capture.json's record of the undistortion (the pipeline solves one shared camera)."""
    if not undistort:
        return None
    camera_id, undistorter = next(iter(undistort.items()))
    return {
        "from": _camera_record(lens[camera_id]),
        "to": _camera_record(undistorter.pinhole),
        "border": f"cropped to valid pixels (COLMAP's blank_pixels 0), then to sides divisible by {SIDE_MULTIPLE}",
    }
