"""`liquidgs train`: train a dynamic scene with a deformation field.

    liquidgs train --data PATH --field {static,mlp,cfc,sde} [--preset NAME] [--lambda L]
                   [--iterations N] [--downscale K] [--seed S] [--out DIR] [--resume]

Every other setting of TrainConfig is a flag too (`liquidgs train --help`), with the
preset's values as defaults. The resolved configuration is written to DIR/config.yml.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import tyro
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from liquidgs.errors import ConfigError
from liquidgs.train.config import TrainConfig, config_hash, identity, load_yaml, preset_config, validate
from liquidgs.train.trainer import CONFIG, Trainer, data_config, run_directory_state


def default_run_dir(cfg: TrainConfig) -> Path:
    return Path("outputs") / Path(cfg.data).resolve().name / cfg.field / config_hash(cfg)


def differing_settings(a: TrainConfig, b: TrainConfig) -> list[str]:
    def flatten(d: dict, prefix: str = "") -> dict:
        flat = {}
        for key, value in d.items():
            if isinstance(value, dict):
                flat.update(flatten(value, f"{prefix}{key}."))
            else:
                flat[f"{prefix}{key}"] = value
        return flat

    fa, fb = flatten(identity(a)), flatten(identity(b))
    return sorted(k for k in fa.keys() | fb.keys() if fa.get(k) != fb.get(k))


def resolve_config(argv: list[str]) -> tuple[TrainConfig, Path]:
    """Preset defaults (or the stored config on --resume), then the command line on top."""
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--data", type=Path)
    pre.add_argument("--preset", default=None)
    pre.add_argument("--out", type=Path)
    pre.add_argument("--resume", action="store_true")
    known, _ = pre.parse_known_args(argv)
    help_asked = any(a in ("-h", "--help") for a in argv)

    stored = None
    if known.resume:
        if known.out is None:
            raise ConfigError("--resume needs --out DIR, the run folder to continue")
        if not (known.out / CONFIG).is_file():
            raise ConfigError(f"{known.out}: no run to resume (no {CONFIG})")
        stored = load_yaml(known.out / CONFIG)
        default = stored
    else:
        if known.data is None and not help_asked:
            raise ConfigError("--data PATH is required")
        default = preset_config(known.preset or "dnerf", known.data or Path("."))
    cfg = tyro.cli(TrainConfig, default=default, args=argv, prog="liquidgs train", description=__doc__)
    validate(cfg)
    if stored is not None:
        changed = [k for k in differing_settings(cfg, stored) if k != "iterations"]
        if changed:
            raise ConfigError(
                f"{known.out / CONFIG}: --resume continues the run as configured; these settings differ: "
                + ", ".join(changed)
            )
    run_dir = cfg.out or default_run_dir(cfg)
    cfg.out = run_dir
    return cfg, run_dir


def check_run_dir(cfg: TrainConfig, run_dir: Path) -> str:
    """Refuse to touch a folder holding anything but this same run. Returns its state."""
    state = run_directory_state(run_dir)
    if state == "foreign":
        raise ConfigError(f"{run_dir}: output folder is not empty and holds no liquidgs run; nothing was written")
    if state in ("finished", "unfinished", "configured") and not cfg.resume:
        changed = differing_settings(cfg, load_yaml(run_dir / CONFIG))
        if changed:
            raise ConfigError(
                f"{run_dir / CONFIG}: output folder holds a different run (settings differ: {', '.join(changed)}); "
                "choose another --out"
            )
        if state == "unfinished":
            raise ConfigError(f"{run_dir}: holds an unfinished run of this config; pass --resume to continue it")
    if cfg.resume and state == "configured":
        raise ConfigError(f"{run_dir}: nothing to resume (no checkpoint yet); start it again without --resume")
    return state


def make_progress(console: Console) -> Progress:
    return Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        TextColumn("{task.completed}/{task.total}"),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
        TextColumn("loss {task.fields[loss]:.4f}  PSNR {task.fields[psnr]:.2f}  #G {task.fields[gaussians]}"),
        console=console,
        transient=False,
    )


def train(cfg: TrainConfig, run_dir: Path, console: Console | None = None, dataset=None) -> dict:
    """Validate the data, then train (or resume, or report a finished run)."""
    from liquidgs.data import load_dataset

    console = console or Console(stderr=True)
    state = check_run_dir(cfg, run_dir)
    if state == "finished" and not cfg.resume:
        console.print(f"{run_dir}: already finished; results in {run_dir / 'results.json'}")
        return json.loads((run_dir / "results.json").read_text())
    # Load (and so validate) the data before anything is written.
    dataset = dataset if dataset is not None else load_dataset(data_config(cfg))
    trainer = Trainer(cfg, run_dir, dataset)
    if cfg.resume and state != "empty":
        trainer.load_checkpoint()
        console.print(f"resuming {run_dir} at iteration {trainer.state.iteration}")
    with make_progress(console) as progress:
        results = trainer.run(progress)
    final = results["final"]
    lpips = final.get("lpips")
    console.print(
        f"[bold]{cfg.field}[/] {results['scene']}: final PSNR {final['psnr']:.2f}  SSIM {final['ssim']:.4f}  "
        f"LPIPS {lpips if lpips is None else round(lpips, 4)}  ({results['num_gaussians']} Gaussians, "
        f"{results['train_seconds']:.0f} s) -> {run_dir}"
    )
    return results


def main(argv: list[str]) -> int:
    cfg, run_dir = resolve_config(argv)
    train(cfg, run_dir)
    return 0
