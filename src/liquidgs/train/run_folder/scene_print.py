"""The scene a run was trained on, recorded in its folder (SCENE_PRINT) so that a run is never
resumed, re-evaluated or rendered on a scene that differs from it.

The print is cheap: every file's path and size, and the bytes of the small files that hold the
cameras, times and splits (D-NeRF's transforms_*.json, Nerfies' dataset.json and camera/*.json),
not the images' bytes. Hidden files and folders are left out (the OS's and editors' own), and so is
flow/ (optical flow and motion masks, derived from the frames and cameras and checked against them
by its own flow.json: adding it to a scene leaves the runs trained on that scene valid) - except the
flow/<k>x a run trains from (the flow loss, the static/dynamic split): computed again otherwise, it
is no longer the run's scene.
A run folder made before the print existed has none: it is read as before, unchecked.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from liquidgs.atomic import write_json_atomic
from liquidgs.data.flow import FLOW_FOLDER
from liquidgs.errors import ConfigError
from liquidgs.train.run_folder.layout import SCENE_PRINT

PRINT_FORMAT = "liquidgs-scene-print-1"
HASHED_SUFFIXES = (".json", ".txt", ".yml", ".yaml")


def scene_print(scene: Path, flow_scales: tuple[str, ...] = ()) -> dict:
    """{format, files: {relative path: size}, hashes: {relative path: sha256}} of a scene folder, with
    the flow/<k>x folders named in `flow_scales` ("2x", ...)."""
    scene = Path(scene)
    files, hashes = {}, {}
    if scene.is_dir():
        for path in sorted(scene.rglob("*")):
            relative = path.relative_to(scene)
            if any(part.startswith(".") for part in relative.parts) or not path.is_file():
                continue
            if relative.parts[0] == FLOW_FOLDER and (len(relative.parts) < 3 or relative.parts[1] not in flow_scales):
                continue
            files[relative.as_posix()] = path.stat().st_size
            if path.suffix.lower() in HASHED_SUFFIXES:
                hashes[relative.as_posix()] = hashlib.sha256(path.read_bytes()).hexdigest()
    return {"format": PRINT_FORMAT, "files": files, "hashes": hashes}


def write_scene_print(run_dir: Path, scene: Path, flow_scales: tuple[str, ...] = ()) -> Path:
    """The print of `scene`, with the flow/<k>x folders (`flow_scales`) the run trains from."""
    return write_json_atomic(Path(run_dir) / SCENE_PRINT, scene_print(scene, flow_scales))


def _flow_scales(recorded: dict) -> tuple[str, ...]:
    """The flow/<k>x folders a recorded print holds."""
    names = (Path(name).parts for name in recorded.get("files", {}))
    return tuple(sorted({parts[1] for parts in names if len(parts) > 2 and parts[0] == FLOW_FOLDER}))


def _difference(recorded: dict, now: dict) -> str:
    """The first difference, as a user reads it."""
    old, new = recorded.get("files", {}), now["files"]
    missing, added = sorted(old.keys() - new.keys()), sorted(new.keys() - old.keys())
    if missing:
        return f"{len(missing)} file(s) missing, e.g. {missing[0]}"
    if added:
        return f"{len(added)} file(s) added, e.g. {added[0]}"
    changed = [name for name in old if old[name] != new[name] or recorded.get("hashes", {}).get(name)
               != now["hashes"].get(name)]  # fmt: skip
    return f"{len(changed)} file(s) changed, e.g. {changed[0]}"


def check_scene_print(run_dir: Path, scene: Path) -> None:
    """Refuse a scene that differs from the one the run in run_dir was trained on (one line)."""
    path = Path(run_dir) / SCENE_PRINT
    if not path.is_file():
        return  # a run made before scene prints: unchecked, as it was
    try:
        recorded = json.loads(path.read_text())
        if not isinstance(recorded, dict) or recorded.get("format") != PRINT_FORMAT:
            raise ValueError(f"format is not {PRINT_FORMAT}")
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise ConfigError(f"{path}: unreadable scene print ({err})") from None
    now = scene_print(scene, _flow_scales(recorded))
    if {k: recorded.get(k) for k in ("files", "hashes")} != {k: now[k] for k in ("files", "hashes")}:
        raise ConfigError(
            f"{scene}: not the scene the run in {run_dir} was trained on ({_difference(recorded, now)}); "
            "nothing was written"
        )
