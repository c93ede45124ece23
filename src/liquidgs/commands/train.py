"""`liquidgs train`: train a dynamic scene with a deformation field.

    liquidgs train --data PATH --field NAME [--preset NAME] [--lambda L]
                   [--iterations N] [--downscale K] [--seed S] [--out DIR] [--resume]
    liquidgs train --config FILE [--out DIR]
    liquidgs train --out DIR --resume [--iterations N]

Every other setting of TrainConfig is a flag too (`liquidgs train --help`), with the
preset's values as defaults. The resolved configuration is written to DIR/config.yml;
--config FILE trains such a configuration (flags on top still apply) in --out DIR, else in the
default folder: the `out` and `resume` FILE holds are where and how its run was written, not
settings. --resume continues the run in --out as its config.yml says (only --iterations may grow).
"""

from __future__ import annotations

import dataclasses
import json
import math
import shlex
from pathlib import Path

import torch
from rich.console import Console

from liquidgs.commands.progress import progress_for
from liquidgs.errors import ConfigError
from liquidgs.eval import describe_lpips
from liquidgs.eval.collapse import below_background_note
from liquidgs.fields.config import PRESET_NAMES
from liquidgs.settings import parse_flag_settings, print_help, wants_help, with_settings
from liquidgs.train.config import (
    TrainConfig,
    check_given_settings,
    differing_settings,
    load_yaml,
    preset_config,
    run_folder,
)
from liquidgs.train.run import training_threads
from liquidgs.train.run_folder import (
    CAMERAS_REFINED,
    CONFIG,
    PER_VIEW,
    RESULTS,
    RunResults,
    check_resume_progress,
    check_run_dir,
    read_results,
    run_folder_lock,
    stale_temporaries,
    write_scene_print,
)
from liquidgs.train.trainer import Trainer


def default_run_dir(cfg: TrainConfig) -> Path:
    return run_folder(cfg, Path("outputs") / cfg.data.path.resolve().name / cfg.field)


def config_file_argument(argv: list[str]) -> tuple[Path | None, list[str]]:
    """--config FILE (a resolved run configuration, e.g. written by an experiment), and the rest."""
    if "--config" not in argv:
        return None, argv
    at = argv.index("--config")
    if at + 1 == len(argv):
        raise ConfigError("--config needs a FILE (a run configuration, as a run folder's config.yml)")
    return Path(argv[at + 1]), argv[:at] + argv[at + 2 :]


def _help_preset(argv: list[str]) -> str:
    at = argv.index("--preset") if "--preset" in argv else -1
    return argv[at + 1] if 0 <= at < len(argv) - 1 and argv[at + 1] in PRESET_NAMES else "dnerf"


def resolve_config(argv: list[str]) -> tuple[TrainConfig, Path]:
    """The defaults - a preset's, the stored run's on --resume, or a --config FILE - with the
    command line on top; every setting parsed once and checked when the config is built."""
    if wants_help(argv):
        print_help(TrainConfig, "liquidgs train", __doc__, preset_config(_help_preset(argv), Path(".")))
    config_file, argv = config_file_argument(argv)
    flags = parse_flag_settings(TrainConfig, argv, "liquidgs train")
    out, stored = flags.get("out"), None
    if flags.get("resume") and config_file is not None:
        raise ConfigError(
            f"{config_file}: --resume continues the run in --out as its own config.yml says; --config cannot "
            "change it (to train this config, leave out --resume)"
        )
    if flags.get("resume"):
        if out is None:
            raise ConfigError("--resume needs --out DIR, the run folder to continue")
        if not (out / CONFIG).is_file():
            raise ConfigError(f"{out}: no run to resume (no {CONFIG})")
        stored = base = load_yaml(out / CONFIG)
    elif config_file is not None:
        if not config_file.is_file():
            raise ConfigError(f"{config_file}: no such run configuration (--config)")
        # A run's `out` and `resume` say where and how that run was written, not what it computes:
        # they do not carry over, so a changed config never continues (or overwrites) that run.
        base = dataclasses.replace(load_yaml(config_file), out=None, resume=False)
    else:
        if "data.path" not in flags:
            raise ConfigError("--data PATH is required")
        base = preset_config(flags.get("preset", "dnerf"), flags["data.path"])
    cfg = with_settings(base, flags, "liquidgs train")
    check_given_settings(cfg, flags)
    if stored is not None:
        changed = [k for k in differing_settings(cfg, stored) if k != "iterations"]
        if changed:
            raise ConfigError(
                f"{out / CONFIG}: --resume continues the run as configured; these settings differ: "
                + ", ".join(changed)
            )
    # The scene as an absolute path: config.yml names the same folder from any working directory.
    cfg = dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, path=cfg.data.path.resolve()))
    run_dir = cfg.out or default_run_dir(cfg)
    return dataclasses.replace(cfg, out=run_dir), run_dir


def make_progress(console: Console):
    """The training bar on a terminal; plain lines to a file or a pipe (commands.progress)."""

    def shown(value: float, spec: str) -> str:  # "-" before the first step, not a "nan" that reads as a failure
        return "-" if math.isnan(value) else format(value, spec)

    def line(task: dict) -> str:
        return (
            f"{task['description']} {task['completed']}/{task['total']}  loss {shown(task['loss'], '.4f')}  "
            f"PSNR {shown(task['psnr'], '.2f')}  Gaussians {task['gaussians']:,}"
        )

    counts = "{task.completed}/{task.total}"
    fields = "loss {task.fields[loss]:.4f}  PSNR {task.fields[psnr]:.2f}  #G {task.fields[gaussians]}"
    return progress_for(console, counts, fields, line)


def interrupted_message(trainer: Trainer, run_dir: Path) -> str:
    resume = f"liquidgs train --out {shlex.quote(str(run_dir))} --resume"
    if trainer.checkpoint_iteration is None:
        return f"no checkpoint was written yet in {run_dir}; start it again with the same command"
    return f"the checkpoint at iteration {trainer.checkpoint_iteration} is kept in {run_dir}; continue with: {resume}"


def train(cfg: TrainConfig, run_dir: Path, console: Console | None = None, dataset=None) -> RunResults:
    """Validate the data, then train (or resume, or report a finished run).

    The run folder is written by one process at a time (run_folder_lock); nothing is written
    before the data, the settings and, on --resume, the checkpoint have been checked.
    """
    from liquidgs.data import load_dataset

    console = console or Console(stderr=True)
    torch.set_num_threads(training_threads())
    state = check_run_dir(cfg, run_dir)
    if state == "finished" and not cfg.resume:
        console.print(f"{run_dir}: already finished; results in {run_dir / RESULTS}")
        return read_results(run_dir)
    # Load (and so validate) the data before anything is written.
    dataset = dataset if dataset is not None else load_dataset(cfg.data)
    trainer = Trainer(cfg, run_dir, dataset)
    for note in trainer.notes:
        console.print(f"[yellow]note:[/] {note}")
    with run_folder_lock(run_dir):
        state = check_run_dir(cfg, run_dir)  # again, now that no other writer can change it
        for tmp in stale_temporaries(run_dir):
            tmp.unlink(missing_ok=True)
            console.print(f"removed {tmp.name}, left by a write that was interrupted")
        if state == "finished" and not cfg.resume:
            console.print(f"{run_dir}: already finished; results in {run_dir / RESULTS}")
            return read_results(run_dir)
        if cfg.resume and state != "empty":
            trainer.load_checkpoint()
            check_resume_progress(cfg, run_dir, trainer.state.iteration)
            if state == "finished":
                if cfg.iterations == trainer.state.iteration:
                    console.print(f"{run_dir}: already finished at iteration {cfg.iterations}")
                    return read_results(run_dir)
                # Extending a finished run: its results no longer describe the checkpoint.
                (run_dir / RESULTS).unlink()
                (run_dir / PER_VIEW).unlink(missing_ok=True)
                console.print(f"extending the finished run to {cfg.iterations} iterations; removed its {RESULTS}")
            console.print(f"resuming {run_dir} at iteration {trainer.state.iteration}")
        write_scene_print(run_dir, cfg.data.path, trainer.flow_scales())
        try:
            with make_progress(console) as progress:
                results = trainer.run(progress)
        except KeyboardInterrupt:
            raise KeyboardInterrupt(interrupted_message(trainer, run_dir)) from None
    final = results.final
    console.print(
        f"[bold]{cfg.field}[/] {results.scene}: final PSNR {final['psnr']:.2f}  SSIM {final['ssim']:.4f}  "
        f"{describe_lpips(final)}  ({results.num_gaussians} Gaussians, "
        f"{results.train_seconds:.0f} s) -> {run_dir}"
    )
    for line in refinement_lines(results, run_dir):
        console.print(line, highlight=False, soft_wrap=True)
    note = below_background_note(final)  # a collapse would have failed the run: this one never learned
    if note:
        console.print(f"[yellow]note:[/] {note}")
    return results


def refinement_lines(results: RunResults, run_dir: Path) -> list[str]:
    """A run that refined its cameras: its score from aligned test cameras and, where its poses were
    made noisy on purpose, how far refinement brought them back (as the run folder records them)."""
    lines = []
    aligned = results.final_aligned
    if aligned:
        lines.append(f"  test cameras aligned to the scene: PSNR {aligned['psnr']:.2f}  SSIM {aligned['ssim']:.4f}")
    refined = run_dir / CAMERAS_REFINED
    recovery = json.loads(refined.read_text()).get("pose_recovery") if aligned and refined.is_file() else None
    if recovery:
        before, after = recovery["before"], recovery["after"]
        pixels = (f"reprojection {before['reprojection_px']:.2f} -> {after['reprojection_px']:.2f} px, "
                  if "reprojection_px" in before else "")  # fmt: skip
        lines.append(f"  pose recovery: {pixels}rotation {before['aligned_rotation_deg']:.3f} -> "
                     f"{after['aligned_rotation_deg']:.3f} deg, centre {before['aligned_translation']:.4f} -> "
                     f"{after['aligned_translation']:.4f} (after the gauge similarity; {CAMERAS_REFINED})")  # fmt: skip
    return lines


def main(argv: list[str]) -> int:
    cfg, run_dir = resolve_config(argv)
    train(cfg, run_dir)
    return 0
