"""Camera poses for a folder of frames with COLMAP (the pycolmap wheels: no COLMAP build, CPU),
and COLMAP's own undistortion of images into a pinhole camera.

One shared SIMPLE_RADIAL camera (a video has one lens and one zoom), SIFT features, sequential
or exhaustive matching, incremental mapping; the largest model is kept.

Undistortion (`undistorters`): pycolmap.undistort_camera / undistort_image with COLMAP's default
options. blank_pixels = 0 means the border is cropped: the pinhole image keeps the focal length
and spans only pixels the lens saw, so no pixel is blank (a barrel lens, k1 < 0, gives a
slightly larger image, a pincushion lens a smaller one). The result is then centre-cropped to
sides divisible by a given multiple (the coarsest rgb/<k>x folder).
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

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


@dataclass(frozen=True)
class Undistorter:
    """Images of one distorted camera -> images of a pinhole camera (COLMAP's warp, then a crop)."""

    distorted: pycolmap.Camera
    """The lens, at the resolution of the images it is given."""
    pinhole: pycolmap.Camera
    """PINHOLE: fx, fy, cx, cy of the undistorted, cropped images (pixel centres at +0.5)."""
    offset: tuple[int, int]
    """Columns and rows cropped at the left and top of COLMAP's undistorted image."""

    def image(self, pixels: np.ndarray) -> np.ndarray:
        """uint8 [H, W, 3] (or [H, W, 4], straight alpha) seen by `distorted` -> the pinhole image."""
        pycolmap = import_pycolmap()
        if pixels.shape[:2] != (self.distorted.height, self.distorted.width):
            raise LiquidGSError(
                f"an image of {pixels.shape[1]}x{pixels.shape[0]} given to the undistortion of a "
                f"{self.distorted.width}x{self.distorted.height} camera"
            )
        if pixels.ndim == 3 and pixels.shape[2] == 4 and (pixels[..., 3] < 255).any():
            # Interpolate premultiplied colour and alpha (COLMAP's bitmaps hold 1 or 3 channels),
            # so that edges do not pick up the colour of transparent pixels.
            alpha = pixels[..., 3:].astype(np.float64)
            premultiplied = np.rint(pixels[..., :3] * alpha / 255.0).astype(np.uint8)
            color = self._warp(pycolmap, premultiplied).astype(np.float64)
            alpha = self._warp(pycolmap, pixels[..., 3])[..., None].astype(np.float64)
            rgb = np.divide(color * 255.0, alpha, out=np.zeros_like(color), where=alpha > 0)
            return np.concatenate([np.rint(rgb).clip(0, 255), alpha], axis=-1).astype(np.uint8)
        if pixels.ndim == 3 and pixels.shape[2] == 4:  # opaque: the colour alone
            opaque = np.full((self.pinhole.height, self.pinhole.width, 1), 255, np.uint8)
            return np.concatenate([self._warp(pycolmap, pixels[..., :3]), opaque], axis=-1)
        return self._warp(pycolmap, pixels)

    def _warp(self, pycolmap, pixels: np.ndarray) -> np.ndarray:
        bitmap = pycolmap.Bitmap.from_array(np.ascontiguousarray(pixels))
        warped, _ = pycolmap.undistort_image(pycolmap.UndistortCameraOptions(), bitmap, self.distorted)
        x, y = self.offset
        array = warped.to_array()[y : y + self.pinhole.height, x : x + self.pinhole.width]
        return array.reshape(*array.shape[:2], *pixels.shape[2:])

    def points(self, xy: np.ndarray) -> np.ndarray:
        """[N, 2] pixel positions in the distorted images -> the same points in the pinhole images."""
        rays = self.distorted.cam_from_img(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
        return self.pinhole.img_from_cam(np.concatenate([rays, np.ones((len(rays), 1))], axis=1))


def undistorters(cameras: Sequence[pycolmap.Camera], multiple: int) -> list[Undistorter]:
    """One Undistorter per camera, each cropped to sides divisible by `multiple`.

    Cameras of one image size get one output size (the smallest of COLMAP's, each cropped about
    its centre), so that a scene whose images had one size keeps one size.
    """
    pycolmap = import_pycolmap()
    options = pycolmap.UndistortCameraOptions()  # blank_pixels = 0: crop to valid pixels
    full = [pycolmap.undistort_camera(options, camera) for camera in cameras]
    sizes: dict[tuple[int, int], tuple[int, int]] = {}
    for camera, pinhole in zip(cameras, full):
        width, height = sizes.get((camera.width, camera.height), (pinhole.width, pinhole.height))
        sizes[(camera.width, camera.height)] = (min(width, pinhole.width), min(height, pinhole.height))
    result = []
    for camera, pinhole in zip(cameras, full):
        width, height = sizes[(camera.width, camera.height)]
        width, height = width - width % multiple, height - height % multiple
        if width < multiple or height < multiple:
            raise LiquidGSError(
                f"undistorting the {camera.width}x{camera.height} {camera.model_name} camera "
                f"({camera.params_to_string()}) leaves {pinhole.width}x{pinhole.height} valid pixels, "
                f"too few for sides divisible by {multiple}; are the distortion coefficients right?"
            )
        left, top = (pinhole.width - width) // 2, (pinhole.height - height) // 2
        fx, fy, cx, cy = (float(value) for value in pinhole.params)
        cropped = pycolmap.Camera(
            model="PINHOLE", width=width, height=height, params=[fx, fy, cx - left, cy - top],
            camera_id=camera.camera_id,
        )  # fmt: skip
        result.append(Undistorter(copy.copy(camera), cropped, (left, top)))  # not a reference into a model
    return result


def describe_camera(camera: pycolmap.Camera) -> str:
    """'SIMPLE_RADIAL 200x152 (f, cx, cy, k: 190.2, 100, 76, -0.1498)', for the log."""
    values = ", ".join(f"{float(value):.4g}" for value in camera.params)
    return f"{camera.model_name} {camera.width}x{camera.height} ({camera.params_info}: {values})"
