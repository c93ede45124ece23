"""The files of a run folder by name, and the state a folder is in."""

from __future__ import annotations

from pathlib import Path

from liquidgs.atomic import temporaries_of

CONFIG = "config.yml"
CHECKPOINT = "checkpoint.pt"
PER_VIEW = "per_view.json"
RESULTS = "results.json"
"""Written last: the run's only "done" marker."""
CAMERAS_REFINED = "cameras_refined.json"
"""How far camera refinement moved each training camera (with each checkpoint of a run that refines)."""
EXPOSURE = "exposure.json"
"""The colour correction learned for each training frame (with each checkpoint of a run that compensates)."""
SCENE_PRINT = "scene.json"
"""The files of the scene the run trains on (run_folder.scene_print); absent in older runs."""
FAILURE = "failure.json"
"""Why the run stopped, when it failed (divergence, collapse): its checkpoint is kept, no results."""
RUN_FILES = (CONFIG, SCENE_PRINT, CHECKPOINT, PER_VIEW, RESULTS, CAMERAS_REFINED, EXPOSURE, FAILURE)
"""What the trainer writes into a run folder (besides TENSORBOARD), each atomically."""
TENSORBOARD = "tensorboard"
EVAL = "eval.json"
EVAL_PER_VIEW = "eval_per_view.json"
"""`liquidgs eval` writes these two; the training record is left as it was."""
LOCK_NAME = ".liquidgs.lock"
"""The writer's lock (run_folder.lock); it goes with its writer."""


def stale_temporaries(run_dir: Path) -> list[Path]:
    """Temporaries of the run files that a process killed mid-write left behind."""
    return [tmp for name in RUN_FILES for tmp in temporaries_of(run_dir / name)]


def run_directory_state(run_dir: Path) -> str:
    """'empty' (absent, or holding only a lock / stale temporaries / the scene print), 'configured'
    (config.yml, no checkpoint yet), 'unfinished' (a checkpoint, no results.json), 'finished' or
    'foreign' (anything else, including a file where the folder should be)."""
    if not run_dir.exists():
        return "empty"
    if not run_dir.is_dir():
        return "foreign"
    leftovers = {LOCK_NAME, SCENE_PRINT, *(tmp.name for tmp in stale_temporaries(run_dir))}
    if all(entry.name in leftovers for entry in run_dir.iterdir()):
        return "empty"
    if not (run_dir / CONFIG).is_file():
        return "foreign"
    if (run_dir / RESULTS).is_file():
        return "finished"
    if (run_dir / CHECKPOINT).is_file():
        return "unfinished"
    return "configured"
