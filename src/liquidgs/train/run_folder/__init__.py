"""A run folder: what `liquidgs train` writes, and what eval, render, export, the viewer and the
experiments read. Readers import this package, never the training loop.

    config.yml        the resolved configuration (written first), its scene path absolute
    scene.json        the scene's files, so a changed scene is refused (scene_print.py)
    checkpoint.pt     the latest checkpoint (CHECKPOINT_FORMAT)
    per_view.json     each test view's scores at the last iteration
    failure.json      why a run that failed (diverged, collapsed) stopped; removed when it finishes
    results.json      RunResults (RESULTS_FORMAT), written last: the run's only "done" marker
    cameras_refined.json  how far camera refinement moved each training camera (runs that refine)
    exposure.json     the colour correction learned for each training frame (runs that compensate)
    tensorboard/      training curves
    eval.json, eval_per_view.json   written by `liquidgs eval`, each with the source record of the
                      checkpoint it scored (provenance.py); a report refuses one the run has outgrown
    .liquidgs.lock    held by the one process writing the folder (lock.py)

Each file is written atomically. A folder is empty, configured, unfinished, finished or foreign
(run_directory_state); `liquidgs train` refuses what rules.py says, before writing anything.
"""

from liquidgs.train.run_folder.layout import (
    CAMERAS_REFINED,
    CHECKPOINT,
    CONFIG,
    EVAL,
    EVAL_PER_VIEW,
    EXPOSURE,
    FAILURE,
    LOCK_NAME,
    PER_VIEW,
    RESULTS,
    SCENE_PRINT,
    TENSORBOARD,
    run_directory_state,
    stale_temporaries,
)
from liquidgs.train.run_folder.lock import run_folder_lock, writer_pid
from liquidgs.train.run_folder.provenance import (
    check_source,
    file_sha256,
    same_source,
    source_comment,
    source_in_comments,
    source_record,
)
from liquidgs.train.run_folder.records import (
    CHECKPOINT_FORMAT,
    RESULTS_FORMAT,
    RunResults,
    check_results_format,
    read_checkpoint,
    read_results,
    write_checkpoint,
    write_failure,
    write_per_view,
    write_results,
)
from liquidgs.train.run_folder.rules import check_resume_progress, check_run_dir
from liquidgs.train.run_folder.scene_print import check_scene_print, scene_print, write_scene_print

__all__ = [
    "CAMERAS_REFINED",
    "CHECKPOINT",
    "CHECKPOINT_FORMAT",
    "CONFIG",
    "EVAL",
    "EVAL_PER_VIEW",
    "EXPOSURE",
    "FAILURE",
    "LOCK_NAME",
    "PER_VIEW",
    "RESULTS",
    "RESULTS_FORMAT",
    "SCENE_PRINT",
    "TENSORBOARD",
    "RunResults",
    "check_results_format",
    "check_resume_progress",
    "check_run_dir",
    "check_scene_print",
    "check_source",
    "file_sha256",
    "read_checkpoint",
    "read_results",
    "run_directory_state",
    "run_folder_lock",
    "same_source",
    "scene_print",
    "source_comment",
    "source_in_comments",
    "source_record",
    "stale_temporaries",
    "write_checkpoint",
    "write_failure",
    "write_per_view",
    "write_results",
    "write_scene_print",
    "writer_pid",
]
