"""What `liquidgs train` refuses to do to a run folder, checked before anything is written."""

from __future__ import annotations

from pathlib import Path

from liquidgs.errors import ConfigError
from liquidgs.train.config import TrainConfig, differing_settings, load_yaml
from liquidgs.train.run_folder.layout import CONFIG, run_directory_state
from liquidgs.train.run_folder.scene_print import check_scene_print


def check_run_dir(cfg: TrainConfig, run_dir: Path) -> str:
    """Refuse to touch a folder holding anything but this same run. Returns its state."""
    state = run_directory_state(run_dir)
    if state == "foreign":
        what = "is not empty and holds no liquidgs run" if run_dir.is_dir() else "is a file, not a folder"
        raise ConfigError(f"{run_dir}: output folder {what}; nothing was written")
    if state != "empty":
        check_scene_print(run_dir, cfg.data.path)
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


def check_resume_progress(cfg: TrainConfig, run_dir: Path, checkpoint_iteration: int) -> None:
    """A resume may end a run where it is or extend it, never take it back."""
    if cfg.iterations < checkpoint_iteration:
        raise ConfigError(
            f"{run_dir}: --iterations {cfg.iterations} would go back: the checkpoint is at iteration "
            f"{checkpoint_iteration}; nothing was changed"
        )
