"""`liquidgs data {synth,check,download,video,images,undistort,flow}`: generate built-in synthetic
scenes, validate dataset folders, download the D-NeRF or NeRF-DS scenes, turn your own video or image
folder into a scene (cameras solved by COLMAP, frames undistorted into pinhole cameras, optical flow
and motion masks), undistort an existing Nerfies-layout scene, and add optical flow to one."""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

import tyro
from rich.console import Console

from liquidgs.commands.progress import StageLog
from liquidgs.data import DataConfig, check_dataset, generate_synthetic
from liquidgs.data.capture import training_downscale
from liquidgs.data.colmap import DEADLINE_SECONDS, MapperKind, Matcher, SolveOptions, import_pycolmap
from liquidgs.data.flow import TRACK_STEP, check_scene_flow, compute_scene_flow, scene_image_size
from liquidgs.data.keyframes import KEYFRAME_EVERY
from liquidgs.data.optical_flow import import_cv2
from liquidgs.data.scene import Background, DataFormat, Split
from liquidgs.errors import ConfigError
from liquidgs.settings import parse_flags


@dataclass
class SynthArgs:
    """Render a built-in synthetic dynamic scene in both the D-NeRF and the Nerfies layout."""

    scene: str
    """Scene name, one of liquidgs.data.SYNTHETIC_SCENES: puppet (fast articulated motion, the
    default scene of the demo), spinner (slow rigid motion) or still (the puppet at rest: nothing
    moves, a control for what a field gains without motion)."""
    out: Path
    """Output folder; gets dnerf/ and nerfies/ subfolders."""
    size: int = 128
    """Image width and height in pixels."""
    frames: int = 80
    """Total frames (train, val and test interleaved in time)."""
    seed: int = 0
    """Seed of the random camera positions."""


DATA_DEFAULTS = {f.name: f.default for f in fields(DataConfig)}


@dataclass
class CheckArgs:
    """Validate a dataset folder (every JSON field, every image fully decoded) and summarise it."""

    path: tyro.conf.Positional[Path]
    """Scene folder."""
    # DataConfig's settings under check's own flag names (--format, not train's --data-format).
    format: DataFormat = DATA_DEFAULTS["format"]
    """Dataset format; auto detects it from the files in the folder."""
    split: Split = DATA_DEFAULTS["split"]
    """Nerfies split preset (auto = nerfds)."""
    downscale: int | None = DATA_DEFAULTS["downscale"]
    """Image downscale factor (default: 1 for D-NeRF, the split preset's for Nerfies)."""
    background: Background = DATA_DEFAULTS["background"]
    """Background colour RGBA images are composited on."""
    val_as_test: bool = DATA_DEFAULTS["val_as_test"]
    """D-NeRF: use the val split as test."""


@dataclass
class DownloadArgs:
    """Download a dataset's public archive (D-NeRF or NeRF-DS), check it, unpack it and check every scene;
    or the real-clip benchmark's videos, each checked against its recorded size and SHA-256."""

    dataset: tyro.conf.Positional[str]
    """dnerf (the 8 D-NeRF scenes), nerfds (the 7 NeRF-DS scenes) or real-clips (8 public demo videos
    of a handheld camera; not scenes yet: scripts/real_clips.sh registers them)."""
    dir: tyro.conf.Positional[Path]
    """Folder to create (must not exist): one sub-folder per scene, e.g. DIR/hook; an experiment's
    --data-root is the folder holding DIR when DIR is named dnerf or nerfds. real-clips: DIR/<clip>.mp4
    and DIR/clips.json (each clip's source and licence)."""


@dataclass(kw_only=True)
class CaptureArgs:
    out: Path
    """Scene folder to create (must not exist, or be empty); written in the Nerfies layout."""
    max_size: int = 800
    """Longest side of the full-size (rgb/1x) frames in pixels; rgb/2x and rgb/4x are made from them."""
    matcher: Matcher = "sequential"
    """How the SIFT features are matched first: sequential (COLMAP's matcher: each frame with the 1st, 2nd,
    4th, 8th, ... 512th after it; for frames in time order), flow (the same pairs, each feature compared only
    with those near where the optical flow between neighbouring frames carries it, verified at 1 px: 40% less
    time in matching and nearer the truth on New Tsukuba, but 44 of 80 frames on a close-up of a moving cat;
    docs/results/registration.md) or exhaustive (COLMAP's, every pair; slower). When the solve gives no
    usable model, it is tried again with every pair matched, then with a relaxed initial pair."""
    mapper: MapperKind = "global"
    """The first attempt's mapper: global (COLMAP's global mapper, GLOMAP: seconds on a 100-frame clip) or
    incremental (COLMAP's classic mapper: minutes). A global model with plausibility warnings (lens,
    path jumps, thin frames) is compared with the incremental mapper's on the same matches, and the one
    with fewer warnings is used (the incremental one on a tie); the incremental mapper is the fallback when
    the global one fails."""
    deadline: int = DEADLINE_SECONDS
    """Seconds each attempt's mapping may take before it is stopped (and its model checked as it is)."""
    mask_dynamic: Path | None = None
    """Folder of masks of the moving things, one per frame (video: <frame number, 6 digits>.png, counted
    from 0 in the decoded stream; images: <image stem>.png). Nonzero pixels are moving: COLMAP
    takes no features there, so cameras are solved from the static scene only."""
    holdout_every: int = 8
    """Test split: of the registered frames in time order, every K-th (the K/2-th, then every K) is held out."""
    threads: int = -1
    """CPU threads for COLMAP (-1: all cores)."""
    keep_distortion: bool = False
    """Keep the frames as decoded and COLMAP's radial distortion k1 in the camera files (trained as if
    pinhole). By default the frames are undistorted into a pinhole camera by COLMAP's undistorter, the
    border cropped to valid pixels (and to sides divisible by 4), and the camera files carry no distortion."""
    keyframe_every: int = KEYFRAME_EVERY
    """COLMAP solves every K-th frame (and the last) and each frame between two keyframes is placed from the
    points they see, tracked into it by optical flow: on New Tsukuba (150 frames, known cameras) the solve took
    a third of the time with the poses as near the truth (docs/results/registration.md). 1: COLMAP solves every
    frame. The step is made smaller where it would leave under 16 keyframes (clips under 32 frames are solved
    whole); when the keyframes give no usable model, or more than a tenth of the frames between them cannot be
    placed, COLMAP solves every frame."""
    fast_features: bool = False
    """Take COLMAP's SIFT features from the frames as they are, not from the frames doubled in size (its
    default, which finds finer features): about a third of the CPU in features, matching and mapping, at
    about twice the pose error against ground truth (measured on New Tsukuba, docs/results/registration.md).
    For a quick first look; the default is the more accurate."""
    mask_moving: bool = False
    """Without --mask-dynamic: find what moves from optical flow between neighbouring frames (pixels the
    pair's dominant two-view geometry does not explain) and take no COLMAP features there. Off by default:
    on the rendered test clip with known cameras it made the poses worse (centre error 0.0051 against
    0.0034), as it masks few of the moving pixels and some still ones (docs/results/registration.md)."""
    flow: bool = True
    """Compute optical flow and motion masks at the quick look's scale into flow/<k>x (see `data flow`);
    --no-flow skips it (`data flow SCENE` adds it later)."""


@dataclass(kw_only=True)
class VideoArgs(CaptureArgs):
    """Your own video -> a dynamic scene: frames (ffmpeg), cameras (COLMAP), Nerfies layout."""

    video: tyro.conf.Positional[Path]
    """The video file (anything ffmpeg decodes: mp4, mov, mkv, ...)."""
    fps: float | None = None
    """Keep frames at this rate (the first of each 1/fps seconds)."""
    frames: int | None = None
    """Keep this many frames, evenly spread over the video (default 100 when neither is given)."""


@dataclass(kw_only=True)
class ImagesArgs(CaptureArgs):
    """A folder of images in time order (name order, frame2 before frame10) -> a dynamic scene."""

    images: tyro.conf.Positional[Path]
    """Folder of .png/.jpg images, all the same size."""


@dataclass(kw_only=True)
class FlowArgs:
    """Optical flow between neighbouring train frames, tracks (that flow chained over three pairs) and
    a motion mask per frame (pixels whose flow the cameras' motion cannot explain) of a Nerfies-layout
    scene, into SCENE/flow/<k>x; a flow folder already there for that scale is replaced once the new
    one is complete."""

    scene: tyro.conf.Positional[Path]
    """Scene folder in the Nerfies layout (what `data video` / `data images` write)."""
    downscale: int | None = None
    """The rgb/<k>x to compute at (default: the quick look's, the longer side at least 128 pixels)."""


@dataclass(kw_only=True)
class UndistortArgs:
    """A Nerfies/HyperNeRF scene whose cameras carry lens distortion -> a new scene with pinhole cameras."""

    scene: tyro.conf.Positional[Path]
    """Scene folder in the Nerfies layout (dataset.json, camera/<id>.json, rgb/<k>x/). Its images are
    undistorted by COLMAP's undistorter: the focal length is kept and the border cropped to valid pixels."""
    out: Path
    """New scene folder to create (must not exist, or be empty)."""


MAX_SIZE = 4096
DEFAULT_VIDEO_FRAMES = 100
MAX_FRAMES = 10_000


def synth(args: SynthArgs) -> int:
    if not 8 <= args.size <= MAX_SIZE or not 8 <= args.frames <= MAX_FRAMES:
        raise ConfigError(
            f"--size must be between 8 and {MAX_SIZE} and --frames between 8 and {MAX_FRAMES}, "
            f"got {args.size} and {args.frames}"
        )
    if args.seed < 0:
        raise ConfigError(f"--seed must be >= 0, got {args.seed}")
    out_dir = generate_synthetic(args.scene, args.out, size=args.size, frames=args.frames, seed=args.seed)
    print(f"scene '{args.scene}' ({args.frames} frames, {args.size}x{args.size}) written to:")
    print(f"  {out_dir / 'dnerf'}    (D-NeRF layout)")
    print(f"  {out_dir / 'nerfies'}  (Nerfies layout)")
    return 0


def check(args: CheckArgs) -> int:
    options = {f.name: getattr(args, f.name) for f in fields(CheckArgs) if f.name != "path"}
    config = DataConfig(path=args.path, cache_images=0, **options)
    print("\n".join(check_dataset(config).lines()))
    for line in check_scene_flow(args.path):
        print(line)
    return 0


QUICK_LOOK_GRAD_THRESHOLD = 0.0028
"""Densification threshold of the quick look: 4 x the reference's 0.0007, which is for 800 px
images; the quick look trains at 128-255 px along the longer side (see quick_look_commands)."""
QUICK_LOOK_GAUSSIANS = 10_000
"""Gaussians the quick look may grow to: at most 1 per pixel, and at most this many in all."""
QUICK_LOOK_OPACITY_RESET = 3000
"""The reference's opacity-reset interval rather than the tiny preset's 600: past the quick look's
1,500 iterations, so it never resets. On real clips the fields (tiny's learning rate 5e-3) blew the
Gaussians up after a reset at 600, and the size prune that follows it removed most of them."""


def quick_look_commands(out: Path, size: tuple[int, int]) -> list[str]:
    """What `data video` / `data images` print as the CPU quick look for the scene at `out` whose
    frames are `size` (width, height): the tiny preset at the largest downscale that keeps the longer
    side at least 128 pixels, a densification threshold for that size, a cap on Gaussians per pixel
    (DensifyConfig.max_per_pixel) of 1, or less where 1 would allow more than QUICK_LOOK_GAUSSIANS,
    and no opacity reset; then a render of the run."""
    width, height = size
    downscale = training_downscale(size)
    pixels = (width // downscale) * (height // downscale)
    per_pixel = min(1.0, int(100 * QUICK_LOOK_GAUSSIANS / pixels) / 100)
    runs = Path("outputs") / out.name / "quick"
    train = (
        f"liquidgs train --data {out} --preset tiny --downscale {downscale} "
        f"--densify.grad-threshold {QUICK_LOOK_GRAD_THRESHOLD:g} --densify.max-per-pixel {per_pixel:g} "
        f"--densify.opacity-reset-interval {QUICK_LOOK_OPACITY_RESET}"
    )
    return [
        "quick look on a CPU (train + render, under 5 minutes per field on 2 cores):",
        f"  {train} --field mlp --out {runs / 'mlp'}",
        f"  liquidgs render --run {runs / 'mlp'}",
        "  (the same with --field static, the floor a field must beat, and --field cfc, the liquid field)",
    ]


def _capture(args: CaptureArgs, source: Path, video: bool, fps: float | None = None, frames: int | None = None) -> int:
    from liquidgs.data.capture import CaptureSettings, capture_scene

    if args.flow or (args.mask_moving and args.mask_dynamic is None):
        import_cv2()  # fail before any work when it is missing
    from liquidgs.data.video import check_sampling

    check_sampling(fps, frames, args.max_size)
    if args.keyframe_every < 1:
        raise ConfigError(f"--keyframe-every must be at least 1 (1: every frame), got {args.keyframe_every}")
    if args.deadline < 1:
        raise ConfigError(f"--deadline must be at least 1 second, got {args.deadline}")
    if args.threads == 0 or args.threads < -1:
        raise ConfigError(f"--threads must be -1 (all cores) or a positive count, got {args.threads}")
    import_pycolmap()  # fail before any work when it is missing
    settings = CaptureSettings(
        fps=fps,
        frames=frames,
        max_size=args.max_size,
        holdout_every=args.holdout_every,
        mask_dir=args.mask_dynamic,
        solve=SolveOptions(
            matcher=args.matcher,
            mapper=args.mapper,
            threads=args.threads,
            deadline=args.deadline,
            fast_features=args.fast_features,
            keyframe_every=args.keyframe_every,
        ),
        keep_distortion=args.keep_distortion,
        flow=args.flow,
        mask_moving=args.mask_moving,
    )
    with StageLog(Console(), f"data {'video' if video else 'images'}") as log:
        summary = capture_scene(source, args.out, settings, log, video=video)
    print(
        f"done: {summary.frames_registered}/{summary.frames_total} frames registered"
        + (f" ({len(summary.dropped)} dropped, listed in capture.json)" if summary.dropped else "")
        + f", mean reprojection error {summary.mean_reprojection_error_px:.2f} px, {summary.points} points"
    )
    print(f"scene: {args.out} (check it with: liquidgs data check {args.out})")
    print(f"train: liquidgs train --data {args.out} --field mlp --preset nerfds")
    print("\n".join(quick_look_commands(args.out, summary.image_size)))
    return 0


def download(args: DownloadArgs) -> int:
    from liquidgs.data.download import main as download_main

    return download_main(args.dataset, args.dir)


def video(args: VideoArgs) -> int:
    frames = args.frames if args.frames is not None or args.fps is not None else DEFAULT_VIDEO_FRAMES
    return _capture(args, args.video, True, fps=args.fps, frames=frames)


def images(args: ImagesArgs) -> int:
    return _capture(args, args.images, False)


def flow(args: FlowArgs) -> int:
    import_cv2()
    if args.downscale is not None and args.downscale < 1:
        raise ConfigError(f"--downscale must be a positive integer, got {args.downscale}")
    downscale = args.downscale or training_downscale(scene_image_size(args.scene))
    with StageLog(Console(), "data flow") as log:
        summary = compute_scene_flow(args.scene, downscale, log)
    width, height = summary.size
    print(
        f"done: {summary.pairs} flow pairs, {summary.tracks} tracks over {TRACK_STEP + 1} frames and "
        f"{summary.masks} motion masks at {width}x{height} "
        f"({100 * summary.mean_moving_share:.1f}% of pixels moving on average), {summary.seconds:.1f} s "
        f"-> {summary.folder}"
    )
    return 0


def undistort(args: UndistortArgs) -> int:
    from liquidgs.data.undistort import undistort_scene

    import_pycolmap()  # fail before any work when it is missing
    with StageLog(Console(), "data undistort") as log:
        summary = undistort_scene(args.scene, args.out, log)
    folders = " ".join(f"{factor}x" for factor in summary.folders)
    width, height = summary.image_size
    print(
        f"done: {summary.frames} frames undistorted into pinhole cameras, {width}x{height} at 1x, "
        f"rgb {folders}, {summary.seconds:.1f} s"
    )
    if summary.left_out:
        left_out = ", ".join(summary.left_out)
        print(f"not carried over (they describe the distorted images or are not the Nerfies layout): {left_out}")
    print(f"scene: {args.out} (check it with: liquidgs data check {args.out})")
    return 0


SUBCOMMANDS = {
    "synth": (SynthArgs, synth),
    "check": (CheckArgs, check),
    "download": (DownloadArgs, download),
    "video": (VideoArgs, video),
    "images": (ImagesArgs, images),
    "undistort": (UndistortArgs, undistort),
    "flow": (FlowArgs, flow),
}


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in SUBCOMMANDS:
        usage = "usage: liquidgs data {synth,check,download,video,images,undistort,flow} [--help]"
        if argv and argv[0] in ("-h", "--help"):
            print(usage)
            return 0
        raise ConfigError(f"choose a subcommand: synth, check, download, video, images, undistort or flow ({usage})")
    spec, run = SUBCOMMANDS[argv[0]]
    return run(parse_flags(spec, argv[1:], prog=f"liquidgs data {argv[0]}", description=spec.__doc__))
