"""`liquidgs bake --run DIR [--out BAKED]`: distil a finished run's deformation field into explicit
per-Gaussian motion that renders without the network.

The field is sampled at uniform keyframe times over the capture's time range; between them each
Gaussian's position, rotation and scale follow a Catmull-Rom spline (rotation renormalised).
Keyframes double (9, 17, 33, ...) until every visible Gaussian (opacity >= 1/255) stays within
--tolerance half-way between keyframes, measured against the field: position and scale error as a
fraction of the Gaussian's largest axis, rotation error in radians. Past --max-keyframes the scene
is baked anyway, with a warning naming the Gaussians and times over budget (all in baked.json).

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
from liquidgs.bake.distil import BakeSettings, check_finished, describe_over_budget, distil, most_samples
from liquidgs.bake.motion import CHANNELS
from liquidgs.bake.scene import BAKED_FORMAT, MANIFEST, SCENE, is_baked
from liquidgs.commands.progress import progress_for
from liquidgs.data.cameras_file import CAMERAS_FILE, cameras_record
from liquidgs.data.capture import refuse_taken
from liquidgs.errors import ConfigError, LiquidGSError, check_finite
from liquidgs.gaussians import PARAM_KEYS
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
    """Error budget half-way between keyframes (fraction of the Gaussian's size; radians)."""
    min_keyframes: int = BakeSettings.min_keyframes
    """Keyframes to start from (at least 2)."""
    max_keyframes: int = BakeSettings.max_keyframes
    """Keyframes the doubling stops at, at most 1,025 (MAX_KEYFRAMES)."""
    device: str = "auto"
    """auto (CUDA where torch sees a GPU, else the CPU), cpu, cuda or cuda:N."""


def check_args(args: BakeArgs) -> Path:
    if not 0.0 < args.tolerance < 1.0:
        raise ConfigError(f"--tolerance must be in (0, 1), got {args.tolerance}")
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
    cameras = cameras_record(run.scene())  # the scene checked against the run's print first
    settings = BakeSettings(args.tolerance, args.min_keyframes, args.max_keyframes)
    n = run.params["means"].shape[0]
    samples = [0]

    def sampled(keyframes: int) -> None:
        samples[0] += 1
        progress.update(task, completed=samples[0], keyframes=keyframes)

    most = most_samples(settings)
    run.at_time(0.0)  # a diverged run: its one line before any progress line
    with make_progress(console or Console(quiet=True)) as progress:
        task = progress.add_task("bake", total=most, keyframes=settings.min_keyframes, gaussians=n)
        distilled = distil(run, settings, sampled)
        if samples[0] < most:  # the budget met before the most keyframes: done at the samples taken
            progress.update(task, total=samples[0], completed=samples[0])
    payload = {
        "params": {k: run.params[k].detach().cpu().contiguous() for k in PARAM_KEYS},
        "keyframes": distilled.keyframes.contiguous(),
    }
    check_finite(args.run, "the Gaussians and their keyframes", [*payload["params"].values(), payload["keyframes"]])
    manifest = {
        "format": BAKED_FORMAT,
        "source": run.source(),
        "field": run.config.field,
        "iteration": run.iteration,
        "sh_degree": run.sh_degree,
        "gaussians": n,
        "keyframes": distilled.keyframes.shape[0],
        "keyframe_times": "uniform over [0, 1], the capture's normalised time range",
        "interpolation": "Catmull-Rom per channel (position, wxyz quaternion renormalised, scale)",
        "channels": CHANNELS,
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
        f"baked {record['gaussians']:,} Gaussians x {record['keyframes']} keyframes "
        f"({record['bytes_per_gaussian']:.0f} bytes per Gaussian); midpoint error: max "
        f"{error['max_relative_error']:.3g} of a Gaussian's size, max position {error['max_position_error']:.3g} "
        f"scene units -> {record['out']}",
        highlight=False,
        soft_wrap=True,
    )
    return 0
