"""`liquidgs bake --run DIR [--out BAKED]`: distil a finished run's deformation field into explicit
per-Gaussian motion that renders without the network.

Each Gaussian gets as many keyframes as its motion needs (one if it does not move; else 2, 3, 5,
9, ... up to --max-keyframes, from --min-keyframes doubled), at uniform times over the capture's
time range; between them its position, rotation and scale follow a Catmull-Rom spline (rotation
renormalised). Every visible Gaussian (opacity >= 1/255) must stay within --tolerance at every
sample time (the keyframe times of the most keyframes and the midpoints between them), measured
against the field with the keyframes as stored (quantised to 8 or 16 bits of their range):
position and scale error as a fraction of the Gaussian's largest axis, rotation error in radians.
Past --max-keyframes the scene is baked anyway, with a warning naming the Gaussians and times over
budget (all in baked.json).

BAKED (default DIR/baked) is read by `render`, `eval`, `view` and `export` in place of a run
folder. It is built in a hidden folder beside BAKED and renamed into place when complete. It
records the run it came from (iteration, the checkpoint's hash, the scene print) and carries the
scene's cameras: it renders, plays and exports without the scene folder or the field's package,
and is refused where its run has trained on since.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from rich.console import Console

from liquidgs.atomic import build_atomically, save_torch_atomic, write_json_atomic, write_text_atomic
from liquidgs.bake.distil import BakeSettings, check_finished, describe_over_budget, distil, field_samples
from liquidgs.bake.motion import CHANNELS
from liquidgs.bake.scene import BAKED_FORMAT, MANIFEST, SCENE, STORED_PARAMS, is_baked, stored_scene
from liquidgs.commands.progress import progress_for
from liquidgs.data.cameras_file import CAMERAS_FILE, cameras_record
from liquidgs.data.capture import refuse_taken
from liquidgs.errors import ConfigError, LiquidGSError, check_finite
from liquidgs.settings import parse_flags
from liquidgs.train.run import load_run
from liquidgs.train.run_folder import CONFIG, SCENE_PRINT, file_sha256

MAX_KEYFRAMES = 1025
"""The most keyframes (--max-keyframes): 16x the default 65, four doublings past it; bake's time and
the baked scene's bytes grow with them."""


@dataclass
class BakeArgs:
    run: Path
    """A finished run folder."""
    out: Path | None = None
    """Default: DIR/baked."""
    tolerance: float = BakeSettings.tolerance
    """Error budget at every sample time (fraction of the Gaussian's size; radians)."""
    min_keyframes: int = BakeSettings.min_keyframes
    """The fewest keyframes of a Gaussian that moves (at least 2)."""
    max_keyframes: int = BakeSettings.max_keyframes
    """Keyframes the doubling stops at, at most 1,025 (MAX_KEYFRAMES)."""
    pixel_floor: float = BakeSettings.pixel_floor
    """In the budget a Gaussian's size counts as at least this many pixel widths (in the scene's camera
    that sees it finest): an error within a fraction of a pixel cannot show at the scene's resolution
    (0: the Gaussian's own size only)."""
    device: str = "auto"
    """auto (CUDA where torch sees a GPU, else the CPU), cpu, cuda or cuda:N."""


def check_args(args: BakeArgs) -> Path:
    if not 0.0 < args.tolerance < 1.0:
        raise ConfigError(f"--tolerance must be in (0, 1), got {args.tolerance}")
    if not 0.0 <= args.pixel_floor <= 100.0:
        raise ConfigError(f"--pixel-floor must be in [0, 100], got {args.pixel_floor}")
    if not 2 <= args.min_keyframes <= args.max_keyframes <= MAX_KEYFRAMES:
        raise ConfigError(
            f"--min-keyframes and --max-keyframes must satisfy 2 <= min <= max <= {MAX_KEYFRAMES}, "
            f"got {args.min_keyframes} and {args.max_keyframes}"
        )
    if is_baked(args.run):
        raise LiquidGSError(f"{args.run}: a baked scene, not a run; bake the run it came from")
    out = args.out or args.run / "baked"
    refuse_taken(out)
    return out


def make_progress(console: Console):
    """The sampling bar on a terminal; plain lines to a file or a pipe (commands.progress). Its total is
    the samples of the most keyframes allowed, so its ETA is the longest the bake can take."""

    def line(task: dict) -> str:
        return (
            f"{task['description']} {task['completed']}/{task['total']} field samples  keyframes {task['keyframes']}"
            f"  Gaussians {task['gaussians']:,}"
        )

    counts, fields = (
        "{task.completed}/{task.total} field samples",
        "keyframes {task.fields[keyframes]}  #G {task.fields[gaussians]}",
    )
    return progress_for(console, counts, fields, line, eta="ETA at most")


def bake(args: BakeArgs, console: Console | None = None) -> dict:
    out = check_args(args)
    run = load_run(args.run, args.device)
    check_finished(run, "bake")
    scene = run.scene()  # checked against the run's print first
    cameras = cameras_record(scene)
    settings = BakeSettings(args.tolerance, args.min_keyframes, args.max_keyframes, args.pixel_floor)
    n = run.params["means"].shape[0]
    samples = field_samples(settings)
    run.at_time(0.0)  # a diverged run: its one line before any progress line
    with make_progress(console or Console(quiet=True)) as progress:
        task = progress.add_task("bake", total=samples, keyframes=settings.ladder()[-1], gaussians=n)
        distilled = distil(run, settings, [frame.camera for frame in (*scene.train, *scene.test)],
                           lambda: progress.update(task, advance=1))  # fmt: skip
    params = {k: run.params[k].detach().cpu() for k in STORED_PARAMS}
    check_finite(
        args.run, "the Gaussians and their keyframes", [*params.values(), run.params["shN"], distilled.stored["low"]]
    )
    payload = stored_scene(run.params, distilled.stored)
    sh_rest = payload["sh_rest"]
    # float16 overflows to infinity
    as_stored = [*payload["params"].values(), distilled.stored["span"], sh_rest["low"], sh_rest["span"]]
    check_finite(args.run, "the Gaussians and their keyframes as stored", as_stored)
    manifest = {
        "format": BAKED_FORMAT,
        "source": run.source(),
        "field": run.config.field,
        "iteration": run.iteration,
        "sh_degree": run.sh_degree,
        "gaussians": n,
        "keyframes": distilled.report["max_keyframes"],
        "mean_keyframes": distilled.report["mean_keyframes"],
        "keyframe_times": "per Gaussian, uniform over [0, 1] (the capture's normalised time range)",
        "interpolation": "Catmull-Rom per channel (position, wxyz quaternion renormalised, scale)",
        "channels": CHANNELS,
        "storage": "bake/tracks.py: per Gaussian and channel, 8- or 16-bit codes of its range; opacity and "
        "SH degree 0 float16, higher SH 8-bit codes of each Gaussian's range",
        "error": distilled.report,
    }

    config_text = (args.run / CONFIG).read_text()
    scene_print_text = (args.run / SCENE_PRINT).read_text() if (args.run / SCENE_PRINT).is_file() else None

    def build(folder: Path) -> None:
        write_text_atomic(folder / CONFIG, config_text)
        if scene_print_text is not None:
            write_text_atomic(folder / SCENE_PRINT, scene_print_text)
        write_json_atomic(folder / CAMERAS_FILE, cameras)
        save_torch_atomic(folder / SCENE, payload)
        manifest["scene_sha256"] = file_sha256(folder / SCENE)
        manifest["bytes_per_gaussian"] = (folder / SCENE).stat().st_size / n
        write_json_atomic(folder / MANIFEST, manifest)  # last: it marks the folder a baked scene

    build_atomically(out, build)
    if distilled.over_budget and console is not None:
        console.print(f"[yellow]warning:[/] {describe_over_budget(distilled.report, n)}; listed in {out / MANIFEST}")
    return {**manifest, "out": str(out)}


def main(argv: list[str]) -> int:
    args = parse_flags(BakeArgs, argv, prog="liquidgs bake", description=__doc__)
    console = Console(stderr=True)
    record = bake(args, console)
    error = record["error"]
    console.print(
        f"baked {record['gaussians']:,} Gaussians, {record['mean_keyframes']:.1f} keyframes each on average "
        f"(at most {record['keyframes']}; {record['bytes_per_gaussian']:.0f} bytes per Gaussian); error: max "
        f"{error['max_relative_error']:.3g} of a Gaussian's size, max position {error['max_position_error']:.3g} "
        f"scene units -> {record['out']}",
        highlight=False,
        soft_wrap=True,
    )
    return 0
