"""Frames for the own-video pipeline: decoded from a video (ffmpeg from imageio-ffmpeg) or read
from a folder of images, scaled to a longest side, and saved as PNGs at full ("1x") size.

Every frame is cropped at its right and bottom edge to sides divisible by 4, so that the
Nerfies layout's rgb/2x and rgb/4x images are exact area averages of rgb/1x.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from liquidgs.data.colmap import MIN_REGISTERED_FRAMES
from liquidgs.data.validate import open_image
from liquidgs.errors import ConfigError, DataError
from liquidgs.media import save_frame_png

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
SIDE_MULTIPLE = 4  # the coarsest rgb/<k>x folder written


@dataclass(frozen=True)
class ExtractedFrame:
    """One frame saved as <frames folder>/<id>.png."""

    id: str
    time_id: int
    """Video: the frame's number in the decoded stream (so time is its timestamp, normalised);
    image folder: its position in name order."""
    source: str
    """Where it came from, for messages: 'video frame 17' or the image's file name."""
    mask_name: str
    """Its mask's file name in a --mask-dynamic folder: <id>.png for a video, the image's stem + .png."""
    scaled_size: tuple[int, int]
    """(width, height) after scaling, before the crop to multiples of SIDE_MULTIPLE."""


Log = Callable[[str], None]


def crop_to_multiple(image: np.ndarray) -> np.ndarray:
    height, width = image.shape[:2]
    return image[: height - height % SIDE_MULTIPLE, : width - width % SIDE_MULTIPLE]


def select_every(native_fps: float, fps: float, count: int) -> list[int]:
    """Frame numbers that sample a `native_fps` stream of `count` frames at `fps`: the first
    frame of each 1/fps interval."""
    if fps >= native_fps:
        return list(range(count))
    buckets = np.floor(np.arange(count) * fps / native_fps + 1e-9)
    return [0, *(int(n) for n in np.flatnonzero(np.diff(buckets) > 0) + 1)]


def select_evenly(count: int, frames: int) -> list[int]:
    """`frames` frame numbers spread evenly over a stream of `count` frames, first and last included."""
    if frames >= count:
        return list(range(count))
    return sorted({int(round(n)) for n in np.linspace(0, count - 1, frames)})


def extract_video_frames(
    video: Path, out_dir: Path, *, fps: float | None, frames: int | None, max_size: int, log: Log
) -> list[ExtractedFrame]:
    """Decode `video`, keep the frames `fps` or `frames` selects, save them as out_dir/<id>.png."""
    import imageio_ffmpeg

    if not video.is_file():
        raise DataError(video, "video file not found")
    if video.stat().st_size == 0:
        raise DataError(video, "is an empty file, not a video")
    try:
        count, _ = imageio_ffmpeg.count_frames_and_secs(str(video))
    except (RuntimeError, OSError):
        count = 0
    if not count:
        raise DataError(video, "ffmpeg decodes no video frames from it; is it a video (mp4, mov, mkv, ...)?")

    # Fit inside max_size x max_size, aspect kept; 'area' averages pixels when shrinking.
    scale = f"scale='min({max_size},iw)':'min({max_size},ih)':force_original_aspect_ratio=decrease:flags=area"
    reader = imageio_ffmpeg.read_frames(str(video), output_params=["-vf", scale])
    ffmpeg_logger = logging.getLogger("imageio_ffmpeg")
    level = ffmpeg_logger.level
    ffmpeg_logger.setLevel(logging.ERROR)  # it warns that scaled frames differ from the source size
    try:
        meta = next(reader)
        width, height = meta["size"]
        native_fps = float(meta.get("fps") or 0.0)
        if fps is not None and native_fps <= 0:
            raise DataError(video, "the video states no frame rate, so --fps cannot sample it; use --frames N")
        wanted = select_every(native_fps, fps, count) if fps is not None else select_evenly(count, frames or count)
        keep = set(wanted)
        log(
            f"extraction: {video.name}: {count} frames, {native_fps:g} fps, {width}x{height} after scaling; "
            f"keeping {len(wanted)}"
        )
        extracted: list[ExtractedFrame] = []
        for number, data in enumerate(reader):
            if number not in keep:
                continue
            image = np.frombuffer(data, dtype=np.uint8).reshape(height, width, 3)
            frame = ExtractedFrame(
                id=f"{number:06d}",
                time_id=number,
                source=f"video frame {number}",
                mask_name=f"{number:06d}.png",
                scaled_size=(width, height),
            )
            save_frame_png(crop_to_multiple(image), out_dir / f"{frame.id}.png")
            extracted.append(frame)
            if len(extracted) % 25 == 0:
                log(f"extraction: {len(extracted)}/{len(wanted)} frames")
    except (OSError, RuntimeError) as err:
        raise DataError(video, f"ffmpeg cannot decode it ({' '.join(str(err).split())[:200]})") from None
    finally:
        reader.close()
        ffmpeg_logger.setLevel(level)
    if not extracted:
        raise DataError(video, "ffmpeg decoded no frames from it")
    _check_count(video, extracted, "--fps or --frames")
    log(f"extraction: {len(extracted)} frames saved")
    return extracted


def _natural_key(name: str) -> list[object]:
    """frame2 before frame10."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def image_files(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise DataError(folder, "image folder not found" if not folder.exists() else "is not a folder")
    files = sorted(
        (p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES),
        key=lambda p: _natural_key(p.name),
    )
    if not files:
        raise DataError(folder, f"holds no images ({', '.join(IMAGE_SUFFIXES)})")
    return files


def collect_image_frames(folder: Path, out_dir: Path, *, max_size: int, log: Log) -> list[ExtractedFrame]:
    """The images of `folder` in name order, scaled to max_size and saved as out_dir/<id>.png."""
    files = image_files(folder)
    log(f"images: {len(files)} in {folder} (name order is time order)")
    extracted: list[ExtractedFrame] = []
    first_size: tuple[int, int] | None = None
    saved = np.zeros((0, 0))
    for position, path in enumerate(files):
        image = open_image(path, "RGB")
        if first_size is None:
            first_size = image.size
        elif image.size != first_size:
            raise DataError(
                path,
                f"is {image.size[0]}x{image.size[1]} but {files[0].name} is {first_size[0]}x{first_size[1]}; "
                "one shared camera needs one image size",
            )
        factor = max(image.size) / max_size
        if factor > 1:
            size = (max(1, round(image.size[0] / factor)), max(1, round(image.size[1] / factor)))
            image = image.resize(size, Image.Resampling.BOX)
        frame = ExtractedFrame(
            id=f"{position:06d}",
            time_id=position,
            source=path.name,
            mask_name=f"{path.stem}.png",
            scaled_size=image.size,
        )
        saved = crop_to_multiple(np.asarray(image))
        save_frame_png(saved, out_dir / f"{frame.id}.png")
        extracted.append(frame)
    _check_count(folder, extracted, "more images")
    log(f"images: {len(extracted)} frames saved at {saved.shape[1]}x{saved.shape[0]}")
    return extracted


def _check_count(source: Path, frames: list[ExtractedFrame], remedy: str) -> None:
    if len(frames) < MIN_REGISTERED_FRAMES:
        raise DataError(
            source, f"gives {len(frames)} frame(s); solving cameras needs at least {MIN_REGISTERED_FRAMES} ({remedy})"
        )


STILL_LEVELS = 1.0
"""Neighbouring frames whose mean absolute difference is under this many grey levels show the same picture."""


def check_changes(source: Path, frames_dir: Path, frames: list[ExtractedFrame]) -> None:
    """Refuse frames that are all one picture (a still image repeated): nothing for COLMAP to solve. A blank
    picture is left to COLMAP, whose refusal (no features) says what to film instead."""
    largest = 0.0
    previous = None
    for frame in frames:
        with Image.open(frames_dir / f"{frame.id}.png") as decoded:
            current = np.asarray(decoded.convert("L"), dtype=np.int16)
        if previous is None and current.std() < STILL_LEVELS:
            return
        if previous is not None:
            largest = max(largest, float(np.abs(current - previous).mean()))
            if largest >= STILL_LEVELS:
                return
        previous = current
    raise DataError(
        source,
        f"its {len(frames)} frames show one still picture (neighbouring frames differ by at most {largest:.2f} "
        "grey levels on average): a still image, not a moving camera; film while walking around the subject",
    )


def check_sampling(fps: float | None, frames: int | None, max_size: int) -> None:
    if fps is not None and frames is not None:
        raise ConfigError("give --fps or --frames, not both")
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise ConfigError(f"--fps must be a positive number, got {fps}")
    if frames is not None and frames < MIN_REGISTERED_FRAMES:
        raise ConfigError(f"--frames must be at least {MIN_REGISTERED_FRAMES} (COLMAP needs that many), got {frames}")
    if max_size < 32:
        raise ConfigError(f"--max-size must be at least 32 pixels, got {max_size}")
