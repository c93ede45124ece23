"""Camera poses for a folder of frames with COLMAP (the pycolmap wheels: no COLMAP build, CPU).

One shared SIMPLE_RADIAL camera (a video has one lens and one zoom), SIFT features, sequential
or exhaustive matching, incremental mapping; the largest model is kept.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from liquidgs.errors import LiquidGSError

if TYPE_CHECKING:
    import pycolmap

Matcher = Literal["sequential", "exhaustive"]
CAMERA_MODEL = "SIMPLE_RADIAL"
SEQUENTIAL_OVERLAP = 10  # each frame is matched with its next 10 (and, quadratically, 16, 32, ...)
MIN_REGISTERED_SHARE = 0.5
MIN_REGISTERED_FRAMES = 4
MIN_POINTS = 20  # fewer triangulated points than this: no usable geometry
# COLMAP drops observations above 4 px; a model whose mean is still above this has not settled.
MAX_MEAN_REPROJECTION_ERROR = 2.0
SEED = 0

Log = Callable[[str], None]

INSTALL_HINT = "pycolmap is not installed; install it with: pip install 'liquidgs[colmap]' (or: pip install pycolmap)"


def import_pycolmap():
    try:
        import pycolmap
    except ImportError:
        raise LiquidGSError(INSTALL_HINT) from None
    return pycolmap


class SolveError(LiquidGSError):
    """COLMAP found no usable model; the message says what to try."""


@dataclass
class SolveOptions:
    matcher: Matcher = "sequential"
    threads: int = -1
    """CPU threads for COLMAP; -1 uses every core."""


@contextmanager
def _quiet_colmap(pycolmap) -> Iterator[None]:
    """COLMAP logs every step to stderr; the pipeline prints its own progress and errors instead."""
    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 3
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = level


def solve_cameras(
    frames_dir: Path,
    image_names: list[str],
    work_dir: Path,
    options: SolveOptions,
    log: Log,
    mask_dir: Path | None = None,
) -> pycolmap.Reconstruction:
    """Features, matches and incremental mapping for frames_dir/<name>; the largest model.

    mask_dir holds COLMAP masks (<name>.png, features on zero pixels are dropped) or is None.
    """
    pycolmap = import_pycolmap()
    database_path = work_dir / "database.db"
    with _quiet_colmap(pycolmap):
        pycolmap.set_random_seed(SEED)
        started = time.perf_counter()
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = CAMERA_MODEL
        if mask_dir is not None:
            reader.mask_path = str(mask_dir)
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.num_threads = options.threads
        pycolmap.extract_features(
            database_path,
            frames_dir,
            image_names=image_names,
            camera_mode=pycolmap.CameraMode.SINGLE,
            reader_options=reader,
            extraction_options=extraction,
            device=pycolmap.Device.cpu,
        )
        with pycolmap.Database.open(database_path) as database:
            keypoints = database.num_keypoints()
            images = database.num_images()
        log(
            f"features: {keypoints} SIFT keypoints in {images} frames "
            f"({keypoints / max(images, 1):.0f} per frame, {time.perf_counter() - started:.1f} s)"
        )
        if images < len(image_names):
            raise SolveError(f"COLMAP read only {images} of {len(image_names)} frames from {frames_dir}")
        if keypoints == 0:
            raise SolveError(
                f"COLMAP found no features in any of the {images} frames (blank or untextured images); "
                "film a textured, static background"
            )

        started = time.perf_counter()
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = options.threads
        if options.matcher == "sequential":
            pairing = pycolmap.SequentialPairingOptions()
            pairing.overlap = SEQUENTIAL_OVERLAP
            pairing.num_threads = options.threads
            pycolmap.match_sequential(database_path, matching_options=matching, pairing_options=pairing,
                                      device=pycolmap.Device.cpu)  # fmt: skip
        else:
            pairing = pycolmap.ExhaustivePairingOptions()
            pairing.num_threads = options.threads
            pycolmap.match_exhaustive(database_path, matching_options=matching, pairing_options=pairing,
                                      device=pycolmap.Device.cpu)  # fmt: skip
        with pycolmap.Database.open(database_path) as database:
            _, inliers = database.read_two_view_geometry_num_inliers()
        verified = sum(count > 0 for count in inliers)
        log(
            f"matching ({options.matcher}): {len(inliers)} frame pairs compared, {verified} geometrically "
            f"verified ({time.perf_counter() - started:.1f} s)"
        )
        if verified == 0:
            raise SolveError(
                f"no two of the {len(image_names)} frames share enough matching features for COLMAP; "
                "film a textured, static background (not a blank wall), move the camera more slowly, "
                "or sample more frames (--fps/--frames)"
            )

        started = time.perf_counter()
        mapping = pycolmap.IncrementalPipelineOptions()
        mapping.num_threads = options.threads
        mapping.random_seed = SEED
        registered = [0]

        def next_image() -> None:
            registered[0] += 1
            if registered[0] % 10 == 0:
                log(f"mapping: {registered[0] + 2} frames registered ...")

        sparse_dir = work_dir / "sparse"
        sparse_dir.mkdir()
        models = pycolmap.incremental_mapping(
            database_path, frames_dir, sparse_dir, options=mapping, next_image_callback=next_image
        )
    if not models:
        raise SolveError(
            f"COLMAP could not start a model from any two of the {len(image_names)} frames (too little "
            "parallax or texture); move the camera sideways rather than only turning it, film a textured "
            "static background, or try --matcher exhaustive"
        )
    model = max(models.values(), key=lambda m: (m.num_reg_images(), m.num_points3D()))
    log(
        f"mapping: {len(models)} model(s); the largest has {model.num_reg_images()} of {len(image_names)} "
        f"frames and {model.num_points3D()} points ({time.perf_counter() - started:.1f} s)"
    )
    return model


def check_model(model: pycolmap.Reconstruction, total: int) -> None:
    """Refuse a model with too few frames or one that did not settle."""
    count = model.num_reg_images()
    needed = max(MIN_REGISTERED_FRAMES, int(MIN_REGISTERED_SHARE * total + 0.999))
    if model.num_points3D() < MIN_POINTS:
        # Frames registered with (almost) nothing triangulated: every ray pair is parallel, which
        # is what a camera turning in place gives (measured: 5 of 16 frames, 0 points).
        raise SolveError(
            f"COLMAP registered {count} of {total} frames but triangulated only {model.num_points3D()} points: "
            "the camera seems to turn in place, which gives no depth; walk sideways around the subject while "
            "filming (a pan from one spot cannot be reconstructed)"
        )
    if count < needed:
        raise SolveError(
            f"COLMAP registered only {count} of {total} frames (at least {needed} needed); try "
            "--matcher exhaustive, more frames (--fps/--frames), a larger --max-size, a slower camera "
            "or more textured static background, or --mask-dynamic if moving things fill the view"
        )
    error = model.compute_mean_reprojection_error()
    if not error <= MAX_MEAN_REPROJECTION_ERROR:
        raise SolveError(
            f"COLMAP's model did not converge: mean reprojection error {error:.2f} px (at most "
            f"{MAX_MEAN_REPROJECTION_ERROR} px expected); try --matcher exhaustive or --mask-dynamic"
        )
