"""Where a derived file came from: the source record that eval.json, baked folders and exports carry,
and the one check their readers make against the run folder as it is now.

A source record names the run (its folder and config hash), the iteration of the checkpoint it was
derived from, the checkpoint's content hash and the scene's print (scene_print.py). A reader that
finds the run folder still at the recorded place compares the checkpoint's hash and the scene's
print with the record: a derived file whose run has trained on since (a resume, an experiment
finishing it) or whose scene changed is refused in one line naming the file and what differs.
A derived file whose run folder is gone (a copy on another machine, a shared export) stands alone.
"""

from __future__ import annotations

import json
from pathlib import Path

from liquidgs.errors import LiquidGSError
from liquidgs.file_hash import file_sha256
from liquidgs.train.run_folder.layout import SCENE_PRINT

SOURCE_FORMAT = "liquidgs-source-1"
SOURCE_KEYS = ("run", "config", "iteration", "checkpoint", "checkpoint_sha256", "scene_sha256")

def scene_sha256(folder: Path) -> str | None:
    """The hash of the scene print a run (or baked) folder holds; None where it has none."""
    path = Path(folder) / SCENE_PRINT
    return file_sha256(path) if path.is_file() else None


def source_record(folder: Path, config_hash: str, iteration: int, checkpoint: Path) -> dict:
    """The record a file derived from `checkpoint` (a run's checkpoint.pt, a baked scene's scene.pt)
    in `folder`, at `iteration`, carries."""
    folder = Path(folder)
    return {
        "format": SOURCE_FORMAT,
        "run": str(folder.resolve()),
        "config": config_hash,
        "iteration": int(iteration),
        "checkpoint": Path(checkpoint).name,
        "checkpoint_sha256": file_sha256(checkpoint),
        "scene_sha256": scene_sha256(folder),
    }


def check_source(derived: Path, source, *, folder: Path | None = None, again: str = "derive it again") -> None:
    """Refuse `derived` (one line, ending with `again`: what to do) where its source record is
    malformed, or where the folder it came from (`folder`, else the recorded one) still exists and its
    checkpoint or scene print differs."""
    if not isinstance(source, dict) or source.get("format") != SOURCE_FORMAT:
        raise LiquidGSError(f"{derived}: its source record is missing or not {SOURCE_FORMAT}")
    bad = [key for key in SOURCE_KEYS if key not in source]
    if bad or not isinstance(source["run"], str) or not isinstance(source["checkpoint"], str):
        raise LiquidGSError(f"{derived}: source record field '{(bad or ['run'])[0]}' is missing or malformed")
    given = folder is not None
    folder = Path(folder if given else source["run"])
    checkpoint = folder / Path(source["checkpoint"]).name
    if not checkpoint.is_file():
        if given:
            raise LiquidGSError(f"{derived}: derived from {checkpoint}, which no longer exists")
        return  # the source run is gone: the derived file stands alone
    if file_sha256(checkpoint) != source["checkpoint_sha256"]:
        raise LiquidGSError(
            f"{derived}: derived from the checkpoint at iteration {source['iteration']}, but {checkpoint} "
            f"has changed since (trained on or replaced); {again}"
        )
    if scene_sha256(folder) != source["scene_sha256"]:
        raise LiquidGSError(
            f"{derived}: derived from {folder} with another scene print ({SCENE_PRINT}) than it has now; {again}"
        )


def same_source(a: dict | None, b: dict | None) -> bool:
    """Whether two source records name one checkpoint (the folder may have moved)."""
    if not (isinstance(a, dict) and isinstance(b, dict)):
        return a == b
    return a.get("checkpoint_sha256") == b.get("checkpoint_sha256")


COMMENT_PREFIX = "liquidgs-source "
"""A PLY header comment that holds a source record."""


def source_comment(source: dict) -> str:
    """The record as a one-line PLY header comment."""
    return COMMENT_PREFIX + json.dumps(source, sort_keys=True, separators=(",", ":"))


def source_in_comments(comments: list[str]) -> dict | None:
    """The source record among a PLY's header comments; None for a PLY without one (another tool's)."""
    for comment in comments:
        if comment.startswith(COMMENT_PREFIX):
            try:
                return json.loads(comment[len(COMMENT_PREFIX) :])
            except ValueError:
                return {}  # malformed: check_source says so
    return None
