"""Camera poses for a folder of frames with COLMAP (the pycolmap wheels: no COLMAP build, CPU),
and COLMAP's own undistortion of images into a pinhole camera.

One shared SIMPLE_RADIAL camera (a video has one lens and one zoom), SIFT features, COLMAP's sequential
or exhaustive matching or matching along the optical flow (data.flow_matches), then COLMAP's global mapper
(GLOMAP's: rotation averaging, then every position at once; seconds where incremental mapping takes
minutes) or its incremental mapper; the
largest model is kept. When an attempt gives no usable model, the next is tried (`solve_attempts`):
the incremental mapper on the same matches, every pair of frames matched, then a relaxed initial
pair. A global model that passes COLMAP's checks but not the phone-camera checks of
data.plausibility is compared with the incremental mapper's on the same matches, and the one with
fewer warnings is used (the incremental one on a tie). Each attempt's mapping has a deadline; each
attempt, its seconds and the one used are logged and returned.

Undistortion (`undistorters`): pycolmap.undistort_camera / undistort_image with COLMAP's default
options. blank_pixels = 0 means the border is cropped: the pinhole image keeps the focal length
and spans only pixels the lens saw, so no pixel is blank (a barrel lens, k1 < 0, gives a
slightly larger image, a pincushion lens a smaller one). The result is then centre-cropped to
sides divisible by a given multiple (the coarsest rgb/<k>x folder).
"""

from __future__ import annotations

import copy
import shutil
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np

from liquidgs.data.flow_matches import VERIFY_MAX_ERROR, colmap_features, flow_guided_matches
from liquidgs.data.keyframes import KEYFRAME_EVERY, MAX_UNPLACED_SHARE, keyframe_names, keyframe_step, place_between
from liquidgs.data.optical_flow import read_gray
from liquidgs.data.plausibility import MIN_POINTS_PER_FRAME, lens_warnings, model_warnings
from liquidgs.data.stage_times import StageTimes
from liquidgs.errors import LiquidGSError

if TYPE_CHECKING:
    import pycolmap

Matcher = Literal["flow", "sequential", "exhaustive"]
MapperKind = Literal["global", "incremental"]
CAMERA_MODEL = "SIMPLE_RADIAL"
# With COLMAP's quadratic overlap (its default) each frame is matched with the 1st, 2nd, 4th, 8th, ...
# frame after it, 2^0 to 2^(overlap - 1) ahead: 25 pairs for 10 frames, 237 for 50 (measured).
SEQUENTIAL_OVERLAP = 10
MIN_REGISTERED_SHARE = 0.5
# The relaxed attempt's weak start: only a model that registers (nearly) every frame is trusted.
# Measured on 15 rendered low-parallax clips: its half-registered models had focal lengths 2.4-2.6x
# the truth and passed every other check; those that registered every frame were within 23%.
MIN_REGISTERED_SHARE_RELAXED = 0.9
MIN_REGISTERED_FRAMES = 4
MIN_POINTS = 20  # fewer triangulated points than this: no usable geometry
# COLMAP drops observations above 4 px; a model whose mean is still above this has not settled.
MAX_MEAN_REPROJECTION_ERROR = 2.0
GLOBAL_TRACKS_PER_VIEW = 300
"""The global mapper positions the cameras from enough tracks to give each frame this many (COLMAP's
track_required_tracks_per_view; its default keeps every track), then triangulates every match: on the
apple clip (50 frames, 10,483 tracks) its global positioning took 2 s instead of 82 s, the whole
mapping 14 s instead of 118 s, and the poses moved by 0.02% of the path (measured, docs/results/registration.md)."""
GLOBAL_BA_WITHOUT_FIXED_ROTATIONS = True
"""The global mapper's bundle adjustment skips its first stage (the camera positions and points
refined with the rotations held, COLMAP's ba_skip_fixed_rotation_stage): on New Tsukuba (150 frames,
known cameras) mapping took 18.2 s instead of 22.7 with the poses as near the truth (0.156 centre RMS,
0.151 deg against 0.155, 0.152), on the cat 4.7 s instead of 5.9 with the poses 0.13 deg from the
stage's (measured, docs/results/registration.md)."""
VERIFICATION_MAX_TRIALS = 2000
"""RANSAC draws at most this many samples per model when COLMAP verifies a frame pair (its default
10,000): on New Tsukuba the verification of 814 pairs took about 11 s of the 24 s of matching, most of
it in pairs that ran to the cap; at 2,000 (and at 1,000) every pair kept the same inlier count and the
poses were the same to the last digit, matching 16.5 s (14.8 s); the cat, teddy and apple were
unchanged, in result and time (measured, docs/results/log.md)."""
DEADLINE_SECONDS = 600
"""Each attempt's mapping stops after this long (COLMAP's max_runtime_seconds for the incremental
mapper; for the global one, which has no such option, its bundle adjustment's time limit)."""
SEED = 0

Log = Callable[[str], None]

INSTALL_HINT = (
    "pycolmap is not installed; install it with: pip install pycolmap (or, in the clone, pip install -e '.[colmap]')"
)


def import_pycolmap():
    try:
        import pycolmap
    except ImportError:
        raise LiquidGSError(INSTALL_HINT) from None
    return pycolmap


class SolveError(LiquidGSError):
    """COLMAP found no usable model; the message says what to try."""

    attempts: Sequence[dict] = ()
    """The attempts made before the refusal (Solved.attempts' records), where known."""


@dataclass
class SolveOptions:
    matcher: Matcher = "sequential"
    mapper: MapperKind = "global"
    """The first attempt's mapper; the incremental one is always the fallback."""
    threads: int = -1
    """CPU threads for COLMAP; -1 uses every core."""
    deadline: int = DEADLINE_SECONDS
    """Seconds each attempt's mapping may take."""
    keyframe_every: int = KEYFRAME_EVERY
    """COLMAP solves every this-th frame and the frames between are placed (data.keyframes); 1: every frame."""
    fast_features: bool = False
    """SIFT from the frames as they are (first_octave 0), not from COLMAP's doubled first octave. Measured on
    New Tsukuba (150 frames, 640x480, global mapper): features, matching and mapping took 35.8 s of CPU
    against 103.4 s (618 keypoints a frame against 1,838), and the centre error after a similarity fit was
    0.354 against 0.157, the relative rotation 0.342 against 0.154 degrees (docs/results/registration.md)."""


class NoDepthError(SolveError):
    """The frames registered but show (almost) no depth: what a camera turning in place gives.
    A later attempt may still solve the clip (a real one did), but when every attempt fails and
    any showed this, it is the reason given: it says what to change in the filming."""


@dataclass(frozen=True)
class Attempt:
    """One try at the camera solve: a matcher, a mapper, and COLMAP mapper options changed from its defaults."""

    name: str
    matcher: Matcher
    changes: str
    """What it changes, in words, for the log and capture.json."""
    mapper: dict[str, float] = field(default_factory=dict)
    """IncrementalMapperOptions values that differ from COLMAP's defaults."""
    min_registered_share: float = MIN_REGISTERED_SHARE
    """The share of the frames its model must register to be used."""
    kind: MapperKind = "incremental"
    hold_distortion: bool = False
    """Keep the lens's radial distortion at 0 in bundle adjustment (the re-run of a suspect lens)."""


# COLMAP itself starts from an initial pair with at least 100 inlier matches seen at 16 degrees or
# more, and, when that registers too few frames, halves first the count and then the angle, twice
# (down to 25 and 4). The relaxed attempt starts from those halves, so COLMAP goes down to 12
# inliers and 2 degrees: a start for clips whose camera moves little between frames.
RELAXED_INITIAL_PAIR = {"init_min_num_inliers": 50, "init_min_tri_angle": 8.0}


def solve_attempts(matcher: Matcher, mapper: MapperKind = "global") -> list[Attempt]:
    """The attempts in the order they are tried, each only when the one before gave no usable model:
    the global mapper (when it is the choice), the incremental mapper on the same pairs, more frame
    pairs (COLMAP's own thresholds on more data), then a lower bar for the start."""
    first = "incremental mapper" if mapper == "global" else "default"
    default = Attempt(first, matcher, f"{matcher} matching, COLMAP's incremental mapper with its defaults")
    exhaustive = Attempt("exhaustive matching", "exhaustive", "every pair of frames matched, COLMAP's mapper defaults")
    relaxed = Attempt(
        "relaxed initial pair",
        "exhaustive",
        "every pair of frames matched; the initial pair needs 50 inlier matches at 8 degrees "
        "(COLMAP: 100 at 16), relaxed by COLMAP down to 12 at 2",
        RELAXED_INITIAL_PAIR,
        MIN_REGISTERED_SHARE_RELAXED,
    )
    attempts = [default, relaxed] if matcher == "exhaustive" else [default, exhaustive, relaxed]
    if mapper == "global":
        glomap = Attempt(
            "global mapper", matcher, f"{matcher} matching, COLMAP's global mapper (rotation averaging, then "
            "every camera position at once)", kind="global",
        )  # fmt: skip
        attempts.insert(0, glomap)
    return attempts


@dataclass
class Solved:
    model: pycolmap.Reconstruction
    attempt: str
    """The name of the attempt whose model is used."""
    matcher: Matcher
    """That attempt's matcher."""
    attempts: list[dict]
    """Every attempt made, in order: name, matcher, mapper, changes, result ("used" or the refusal), seconds."""
    times: StageTimes
    """Seconds of features, matching and mapping (summed over attempts)."""
    warnings: list[str]
    """data.plausibility's warnings about the model used."""
    keyframes: dict | None = None
    """What data.keyframes did (keyframes, frames placed and not), or None: COLMAP solved every frame."""


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
) -> Solved:
    """The cameras of `image_names` (in time order): COLMAP solves the keyframes (data.keyframes) and the
    frames between them are placed; when the keyframes give no usable model (but depth), or too many frames
    between them cannot be placed, COLMAP solves every frame (the keyframes' features and matches reused).

    mask_dir holds COLMAP masks (<name>.png, features on zero pixels are dropped) or is None. Refuses with
    one SolveError when no attempt on every frame gives a usable model (see _solve).
    """
    step = keyframe_step(len(image_names), options.keyframe_every)
    if step == 1:
        return _solve(frames_dir, image_names, work_dir, options, log, mask_dir)
    keys = keyframe_names(image_names, step)
    log(f"keyframes: COLMAP solves one frame in {step} of the {len(image_names)} and the last "
        f"({len(keys)}); the frames between them are placed from the points they see")  # fmt: skip
    try:
        solved = _solve(frames_dir, keys, work_dir, options, log, mask_dir)
    except NoDepthError:
        raise  # a camera turning in place: more frames of it add no depth
    except SolveError as error:
        log(f"keyframes refused: {error}; next: COLMAP solves every frame")
        return _every_frame(frames_dir, image_names, work_dir, options, log, mask_dir, StageTimes(), error.attempts)
    pycolmap = import_pycolmap()
    with solved.times.stage("placing"):
        placed = place_between(pycolmap, solved.model, frames_dir, image_names, log)
    between = len(image_names) - len(keys)
    if len(placed.unplaced) > MAX_UNPLACED_SHARE * between:
        log(f"placing: {len(placed.unplaced)} of the {between} frames between keyframes could not be placed (at most "
            f"{MAX_UNPLACED_SHARE:.0%}); next: COLMAP solves every frame")  # fmt: skip
        return _every_frame(frames_dir, image_names, work_dir, options, log, mask_dir, solved.times, solved.attempts)
    solved.warnings = model_warnings(solved.model)
    solved.keyframes = placed.record(step, len(keys))
    return solved


def _every_frame(frames_dir: Path, image_names: list[str], work_dir: Path, options: SolveOptions, log: Log,
                 mask_dir: Path | None, times: StageTimes, attempts: Sequence[dict]) -> Solved:  # fmt: skip
    """_solve on every frame, in a folder of its own with a copy of the keyframes' database (their features and
    matches are not computed again); the keyframes' stage times and attempts come first in the result's."""
    work = work_dir / "every-frame"
    work.mkdir()
    if (work_dir / "database.db").is_file():
        shutil.copyfile(work_dir / "database.db", work / "database.db")
    solved = _solve(frames_dir, image_names, work, options, log, mask_dir)
    times.merge(solved.times)
    solved.times, solved.attempts = times, [{**record, "frames": "keyframes"} for record in attempts] + solved.attempts
    return solved


def _solve(frames_dir: Path, image_names: list[str], work_dir: Path, options: SolveOptions, log: Log,
           mask_dir: Path | None) -> Solved:  # fmt: skip
    """Features, then the attempts of solve_attempts (matching, mapping, check_model) until one gives
    a usable model; the largest model of that attempt.

    The features, so the masks, are the same for every attempt. Refuses with one SolveError when no
    attempt gives a usable model: a camera turning in place when any attempt saw one, else the
    last attempt's reason.
    """
    pycolmap = import_pycolmap()
    database_path = work_dir / "database.db"
    total = len(image_names)
    times = StageTimes()
    with _quiet_colmap(pycolmap):
        pycolmap.set_random_seed(SEED)
        with times.stage("features"):
            _extract_features(pycolmap, database_path, frames_dir, image_names, options, log, mask_dir)
        attempts = solve_attempts(options.matcher, options.mapper)
        records: list[dict] = []
        failures: list[SolveError] = []
        # Each matcher runs once: a later attempt with the same matcher reuses its pairs, or its refusal.
        matching: dict[Matcher, SolveError | None] = {}
        held: tuple[str, pycolmap.Reconstruction, list[str]] | None = None  # a global model with warnings

        def use(model, attempt: Attempt, warnings: list[str]) -> Solved:
            return _with_lens_held(pycolmap, database_path, frames_dir, work_dir, model, attempt, warnings, total,
                                   options, log, records, times)  # fmt: skip

        for number, attempt in enumerate(attempts, 1):
            label = f"attempt {number} of {len(attempts)} ({attempt.name})"
            log(f"{label}: {attempt.changes}")
            started = time.perf_counter()
            try:
                if attempt.matcher not in matching:
                    try:
                        with times.stage("matching"):
                            _match(pycolmap, database_path, attempt.matcher, frames_dir, image_names, options, log)
                        matching[attempt.matcher] = None
                    except SolveError as error:
                        matching[attempt.matcher] = error
                if matching[attempt.matcher] is not None:
                    raise matching[attempt.matcher]
                with times.stage("mapping"):
                    model, stopped = _map(pycolmap, database_path, frames_dir, work_dir / f"sparse-{number}",
                                          attempt, total, options, log)  # fmt: skip
                try:
                    check_model(model, total, attempt.min_registered_share)
                except SolveError as error:
                    if stopped:  # what failed was time: say so, and how to give more
                        raise type(error)(f"{error} (its mapping was stopped at the deadline of {options.deadline} "
                                          "s; --deadline SECONDS gives it longer)") from None  # fmt: skip
                    raise
                if stopped and model.num_reg_images() < total:  # cut short: frames COLMAP had not reached yet
                    raise SolveError(
                        f"COLMAP's mapping was stopped at the deadline of {options.deadline} s with "
                        f"{model.num_reg_images()} of {total} frames registered; --deadline SECONDS gives it longer"
                    )
                if total - model.num_reg_images() >= MIN_REGISTERED_FRAMES:
                    _refuse_cut(database_path, image_names, "")
            except SolveError as error:
                failures.append(error)
                records.append(_record(attempt, str(error), started))
                log(f"{label} refused: {error}")
                if held is not None:  # the global model was usable: it stays the answer
                    log(f"camera solve: the {held[0]}'s model is kept ({len(held[2])} warning(s); {label} refused)")
                    return use(held[1], attempts[0], held[2])
                if number < len(attempts):
                    log(f"next: attempt {number + 1} of {len(attempts)} will try {attempts[number].changes}")
                continue
            warnings = model_warnings(model)
            records.append(_record(attempt, "usable", started, warnings))
            if held is not None:
                held_label, held_model, held_warnings = held  # the global mapper's: always attempts[0]
                if len(warnings) <= len(held_warnings):  # a tie goes to the incremental mapper, the tried one
                    log(f"camera solve: {label} is used: {len(warnings)} warning(s) against the "
                        f"{held_label}'s {len(held_warnings)}")  # fmt: skip
                    return use(model, attempt, warnings)
                log(f"camera solve: the {held_label}'s model is kept ({len(held_warnings)} warning(s) against "
                    f"{len(warnings)} of {label})")  # fmt: skip
                return use(held_model, attempts[0], held_warnings)
            if attempt.kind == "global" and warnings and number < len(attempts):
                for warning in warnings:
                    log(f"{label}: warning: {warning}")
                log(f"camera solve: the global mapper's model is usable but has {len(warnings)} warning(s); "
                    f"comparing it with attempt {number + 1} of {len(attempts)} ({attempts[number].name}) on the "
                    "same matches")  # fmt: skip
                held = (attempt.name, model, warnings)
                continue
            reason = (
                "the global mapper solved it (seconds where the incremental mapper takes minutes)"
                if attempt.kind == "global"
                else "the incremental mapper solved it"
            )
            log(f"camera solve: {label} succeeded; {reason}")
            return use(model, attempt, warnings)
    cause = next((failure for failure in failures if isinstance(failure, NoDepthError)), failures[-1])
    tried = ", ".join(record["name"] for record in records)
    _refuse_cut(database_path, image_names, f" [COLMAP tried: {tried}]")
    refusal = type(cause)(f"{cause} [COLMAP tried: {tried}]")
    refusal.attempts = records
    raise refusal


def _refuse_cut(database_path: Path, image_names: list[str], suffix: str) -> None:
    cut = cut_in(database_path, image_names)
    if cut is not None:
        before, after = cut
        raise SolveError(
            f"no frame up to {before} shares verified matches with any frame from {after} on: the clip seems "
            f"to have a cut (two shots) there; register each shot on its own{suffix}"
        )


def cut_in(database_path: Path, image_names: list[str]) -> tuple[str, str] | None:
    """(last frame before, first frame after) the first place in time order that no geometrically verified
    pair of the database crosses, with at least MIN_REGISTERED_FRAMES frames on each side; None when every
    place is crossed. (The database keeps only verified pairs, so a pair never compared and a pair compared
    in vain look alike: a cut is only refused once a model leaves the frames past it out.)"""
    pycolmap = import_pycolmap()
    with pycolmap.Database.open(database_path) as database:
        order = {image.image_id: image_names.index(image.name) for image in database.read_all_images()}
        pair_ids, inliers = database.read_two_view_geometry_num_inliers()
    crossing = np.zeros(len(image_names) + 1, int)  # verified pairs spanning the gap before each frame
    for pair_id, count in zip(pair_ids, inliers):
        if count > 0:
            first, second = sorted(order[i] for i in pycolmap.pair_id_to_image_pair(pair_id))
            crossing[first + 1 : second + 1] += 1
    for gap in range(MIN_REGISTERED_FRAMES, len(image_names) - MIN_REGISTERED_FRAMES + 1):
        if crossing[gap] == 0:
            return image_names[gap - 1].rsplit(".", 1)[0], image_names[gap].rsplit(".", 1)[0]
    return None


def _with_lens_held(pycolmap, database_path: Path, frames_dir: Path, work_dir: Path, model, attempt: Attempt,
                    warnings: list[str], total: int, options: SolveOptions, log: Log, records: list[dict],
                    times: StageTimes) -> Solved:  # fmt: skip
    """The chosen model (of `attempt`, with its `warnings`), re-run once with the lens's distortion held
    at 0 when the lens it fitted is not a phone's (data.plausibility.lens_warnings): focal length and distortion
    trade off on a clip with little parallax, and a distortion far from any phone's can make up depth a
    camera turning in place never saw (measured: a rendered 10-frame pan solved with k1 +1.08, 6 of 10
    frames and 501 points). The re-run's model is used when it is usable with no more warnings; when it
    finds no depth, the clip is refused as a camera turning in place; otherwise the chosen model stays,
    with its warnings."""
    camera = next(iter(model.cameras.values()))
    if camera.model_name != "SIMPLE_RADIAL" or not lens_warnings(
        camera.model_name, list(camera.params), camera.width, camera.height
    ):
        return _solved(model, attempt, records, times, warnings)
    fitted = f"f {camera.params[0]:.0f} px, k1 {camera.params[3]:+.3f}"
    held = Attempt(
        "lens held", attempt.matcher, f"the same matches, COLMAP's incremental mapper with the lens's distortion held "
        f"at 0 (the lens fitted, {fitted}, is not a phone's)", min_registered_share=attempt.min_registered_share,
        hold_distortion=True,
    )  # fmt: skip
    label = f"re-run ({held.name})"
    log(f"{label}: {held.changes}")
    started = time.perf_counter()
    try:
        with times.stage("mapping"):
            held_model, _ = _map(pycolmap, database_path, frames_dir, work_dir / "sparse-lens-held", held, total,
                                 options, log)  # fmt: skip
        check_model(held_model, total, held.min_registered_share)
    except NoDepthError as error:
        records.append(_record(held, str(error), started))
        log(f"{label} refused: {error}")
        raise NoDepthError(
            f"{error}; with the lens it fitted ({fitted}, not a phone's) COLMAP made up depth the frames do not show"
        ) from None
    except SolveError as error:
        records.append(_record(held, str(error), started))
        log(f"{label} refused: {error}; the model of {attempt.name} is kept, with its warnings")
        return _solved(model, attempt, records, times, warnings)
    held_warnings = model_warnings(held_model)
    records.append(_record(held, "usable", started, held_warnings))
    if len(held_warnings) <= len(warnings):
        log(f"camera solve: {label} is used: {len(held_warnings)} warning(s) against {len(warnings)} of {attempt.name}")
        return _solved(held_model, held, records, times, held_warnings)
    log(f"camera solve: the model of {attempt.name} is kept ({len(warnings)} warning(s) against {len(held_warnings)} "
        f"with the lens held)")  # fmt: skip
    return _solved(model, attempt, records, times, warnings)


def _solved(model, attempt: Attempt, records: list[dict], times: StageTimes, warnings: list[str]) -> Solved:
    for record in records:
        if record["name"] == attempt.name:
            record["result"] = "used"
    return Solved(model, attempt.name, attempt.matcher, records, times, warnings)


def _record(attempt: Attempt, result: str, started: float, warnings: list[str] | None = None) -> dict:
    return {
        "name": attempt.name,
        "matcher": attempt.matcher,
        "mapper": attempt.kind,
        "changes": attempt.changes,
        "result": result,
        "warnings": warnings or [],
        "seconds": round(time.perf_counter() - started, 2),
    }


def _extract_features(pycolmap, database_path: Path, frames_dir: Path, image_names: list[str],
                      options: SolveOptions, log: Log, mask_dir: Path | None) -> None:  # fmt: skip
    started = time.perf_counter()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = CAMERA_MODEL
    if mask_dir is not None:
        reader.mask_path = str(mask_dir)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = options.threads
    if options.fast_features:  # COLMAP's default -1 first doubles the image: 4x the pixels of the finest octave
        extraction.sift.first_octave = 0
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
    scale = "the frames as they are (--fast-features)" if options.fast_features else "the frames doubled in size"
    log(
        f"features: {keypoints} SIFT keypoints in {images} frames from {scale} "
        f"({keypoints / max(images, 1):.0f} per frame, {time.perf_counter() - started:.1f} s)"
    )
    if images < len(image_names):
        raise SolveError(f"COLMAP read only {images} of {len(image_names)} frames from {frames_dir}")
    if keypoints == 0:
        raise SolveError(
            f"COLMAP found no features in any of the {images} frames (blank or untextured images); "
            "film a textured, static background"
        )


def _match(pycolmap, database_path: Path, matcher: Matcher, frames_dir: Path, image_names: list[str],
           options: SolveOptions, log: Log) -> None:  # fmt: skip
    """Match the frame pairs `matcher` chooses (image_names in time order); pairs already in the database are
    not matched again."""
    started = time.perf_counter()
    total = len(image_names)
    with pycolmap.Database.open(database_path) as database:
        before = len(database.read_two_view_geometry_num_inliers()[0])
    geometry = pycolmap.TwoViewGeometryOptions()
    geometry.ransac.random_seed = SEED  # unseeded, the same frames gave another model from run to run
    geometry.ransac.max_num_trials = VERIFICATION_MAX_TRIALS
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = options.threads
    if matcher == "flow":
        _match_along_flow(pycolmap, database_path, frames_dir, image_names, geometry, options, log)
    elif matcher == "sequential":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = SEQUENTIAL_OVERLAP
        pairing.num_threads = options.threads
        pycolmap.match_sequential(database_path, matching_options=matching, pairing_options=pairing,
                                  verification_options=geometry, device=pycolmap.Device.cpu)  # fmt: skip
    else:
        pairing = pycolmap.ExhaustivePairingOptions()  # no thread count of its own (matching_options has it)
        pycolmap.match_exhaustive(database_path, matching_options=matching, pairing_options=pairing,
                                  verification_options=geometry, device=pycolmap.Device.cpu)  # fmt: skip
    with pycolmap.Database.open(database_path) as database:
        _, inliers = database.read_two_view_geometry_num_inliers()
    verified = sum(count > 0 for count in inliers)
    earlier = f" ({before} of them before)" if before else ""
    log(
        f"matching ({matcher}): {len(inliers)} frame pairs compared{earlier}, {verified} geometrically "
        f"verified ({time.perf_counter() - started:.1f} s)"
    )
    if verified == 0:
        raise SolveError(
            f"no two of the {total} frames share enough matching features for COLMAP; "
            "film a textured, static background (not a blank wall), move the camera more slowly, "
            "or sample more frames (--fps/--frames)"
        )


def _match_along_flow(pycolmap, database_path: Path, frames_dir: Path, image_names: list[str], geometry,
                      options: SolveOptions, log: Log) -> None:  # fmt: skip
    """data.flow_matches' flow-guided matches of COLMAP's sequential pairs between the database's features (the
    frames in time order), then COLMAP's geometric verification of them: `geometry` (TwoViewGeometryOptions,
    seeded) with RANSAC's threshold VERIFY_MAX_ERROR."""
    with pycolmap.Database.open(database_path) as database:
        images = [database.read_image_with_name(name) for name in image_names]
        features = [colmap_features(database.read_keypoints(image.image_id),
                                    database.read_descriptors(image.image_id).data) for image in images]  # fmt: skip
    gray = [_read_gray(frames_dir / image.name) for image in images]
    found = flow_guided_matches(gray, features, SEQUENTIAL_OVERLAP, options.threads, log)
    with pycolmap.Database.open(database_path) as database:
        for (i, j), matches in found.items():
            database.write_matches(images[i].image_id, images[j].image_id, matches)
    geometry.ransac.max_error = VERIFY_MAX_ERROR
    verifier = pycolmap.GeometricVerifierOptions()
    verifier.num_threads = options.threads
    pycolmap.geometric_verification(database_path, verifier_options=verifier, two_view_geometry_options=geometry)


def _read_gray(path: Path) -> np.ndarray:
    """optical_flow.read_gray, its refusal a SolveError: the attempt fails, the next is tried."""
    try:
        return read_gray(path)
    except LiquidGSError as error:
        raise SolveError(str(error)) from None


def _map(pycolmap, database_path: Path, frames_dir: Path, sparse_dir: Path, attempt: Attempt, total: int,
         options: SolveOptions, log: Log) -> tuple[pycolmap.Reconstruction, bool]:  # fmt: skip
    """COLMAP's global or incremental mapping with the attempt's options, under the deadline: the largest
    model, and whether the deadline stopped it."""
    started = time.perf_counter()
    sparse_dir.mkdir()
    if attempt.kind == "global":
        mapping = pycolmap.GlobalPipelineOptions()
        mapping.num_threads = options.threads
        mapping.random_seed = SEED
        mapping.mapper.bundle_adjustment.ceres.solver_options.max_solver_time_in_seconds = float(options.deadline)
        mapping.mapper.track_required_tracks_per_view = GLOBAL_TRACKS_PER_VIEW
        mapping.mapper.ba_skip_fixed_rotation_stage = GLOBAL_BA_WITHOUT_FIXED_ROTATIONS
        models = pycolmap.global_mapping(database_path, frames_dir, sparse_dir, options=mapping)
    else:
        mapping = pycolmap.IncrementalPipelineOptions()
        mapping.num_threads = options.threads
        mapping.random_seed = SEED
        mapping.max_runtime_seconds = options.deadline
        mapping.ba_refine_extra_params = not attempt.hold_distortion
        for name, value in attempt.mapper.items():
            setattr(mapping.mapper, name, value)
        registered = [0]

        def next_image() -> None:
            # Called for every frame registered in any model: a frame registered again in a new
            # model counts again, so this counts steps, not frames (a pan of 16 frames took 110).
            registered[0] += 1
            if registered[0] % 10 == 0:
                log(f"mapping: {registered[0]} registration steps ...")

        models = pycolmap.incremental_mapping(
            database_path, frames_dir, sparse_dir, options=mapping, next_image_callback=next_image
        )
    seconds = time.perf_counter() - started
    late = f"; stopped at its deadline of {options.deadline} s" if seconds >= options.deadline else ""
    if not models:
        log(f"mapping ({attempt.kind}): no model ({seconds:.1f} s{late})")
        raise SolveError(
            f"COLMAP could not start a model from any two of the {total} frames (too little "
            "parallax or texture); move the camera sideways rather than only turning it, or film a "
            "textured static background"
        )
    model = max(models.values(), key=lambda m: (m.num_reg_images(), m.num_points3D()))
    log(
        f"mapping ({attempt.kind}): {len(models)} model(s); the largest has {model.num_reg_images()} of {total} "
        f"frames and {model.num_points3D()} points ({seconds:.1f} s{late})"
    )
    return model, bool(late)


def check_model(model: pycolmap.Reconstruction, total: int, min_share: float = MIN_REGISTERED_SHARE) -> None:
    """Refuse a model with too few frames (under min_share of total), too little depth, or one that did
    not settle."""
    count = model.num_reg_images()
    needed = max(MIN_REGISTERED_FRAMES, int(min_share * total + 0.999))
    seen = [image.num_points3D for image in model.images.values() if image.has_pose]
    seen_per_frame = float(np.median(seen)) if seen else 0.0
    if model.num_points3D() < MIN_POINTS or seen_per_frame < MIN_POINTS_PER_FRAME:
        # Frames registered with (almost) nothing triangulated: every ray pair is parallel, which
        # is what a camera turning in place gives (measured on a rendered pan: 5 of 16 frames, 0 points;
        # with the relaxed start on every pair matched in one pass, 9 of 16 frames, 22 points, 12 seen
        # per frame).
        raise NoDepthError(
            f"COLMAP registered {count} of {total} frames but triangulated only {model.num_points3D()} points "
            f"({seen_per_frame:.0f} seen per frame): the camera seems to turn in place, which gives no depth; "
            "walk sideways around the subject while filming (a pan from one spot cannot be reconstructed)"
        )
    if count < needed:
        raise SolveError(
            f"COLMAP registered only {count} of {total} frames (at least {needed} needed); try "
            "more frames (--fps/--frames), a larger --max-size, a slower camera "
            "or more textured static background, or --mask-dynamic if moving things fill the view"
        )
    error = model.compute_mean_reprojection_error()
    if not error <= MAX_MEAN_REPROJECTION_ERROR:
        raise SolveError(
            f"COLMAP's model did not converge: mean reprojection error {error:.2f} px (at most "
            f"{MAX_MEAN_REPROJECTION_ERROR} px expected); try --mask-dynamic if moving things fill the view"
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
