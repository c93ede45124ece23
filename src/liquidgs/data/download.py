"""`liquidgs data download dnerf|nerfds DIR`: a dataset's public archive, fetched, checked and unpacked
(`real-clips`: the real-clip benchmark's videos, data.clips).

Nothing that looks like a dataset appears until every check has passed: the archive is downloaded
to a temporary file beside DIR, its size checked (against the server's Content-Length and, where
the table knows one, the archive's published size and SHA-256), its integrity checked (every
member's CRC), unpacked into a temporary folder beside DIR, every scene validated as `liquidgs
data check` does, and only then the folder renamed to DIR. On any failure, Ctrl-C included, the
temporary file and folder are removed; an existing DIR is refused before anything is fetched.

ARCHIVES is the one table of where each dataset comes from. LIQUIDGS_DATA_ARCHIVES (a JSON object
{"dnerf": {"url": ..., "size": ..., "sha256": ...}}) overrides entries of it: a mirror, or the
tests' server on 127.0.0.1.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sys
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from liquidgs.data.clips import SET_NAME as CLIP_SET
from liquidgs.data.clips import download_clips
from liquidgs.data.fetch import fetch, table_entry
from liquidgs.data.loading import check_dataset
from liquidgs.data.scene import DataConfig
from liquidgs.errors import ConfigError

ARCHIVES_ENV = "LIQUIDGS_DATA_ARCHIVES"


@dataclass(frozen=True)
class Archive:
    url: str
    source: str
    """Where the URL is published."""
    marker: str
    """A file every scene folder of the dataset holds."""
    size: int | None = None
    """Bytes, where the source states them; else the server's Content-Length is what is checked."""
    sha256: str | None = None
    """Where the source publishes one; else the archive's CRCs are what is checked."""
    suffix: str = ""
    """Cut from scene folder names, so the scenes are named as the experiment specs name them."""


ARCHIVES = {
    # The D-NeRF authors' README (albertpumarola/D-NeRF, "Download Dataset") links this Dropbox file
    # (?dl=1: the file itself rather than Dropbox's page). It unpacks to data/<scene>/. The README
    # states neither size nor checksum.
    "dnerf": Archive(
        url="https://www.dropbox.com/s/0bf6fl0ye2vz3vr/data.zip?dl=1",
        source="the D-NeRF README (github.com/albertpumarola/D-NeRF), its Dropbox link",
        marker="transforms_train.json",
    ),
    # The NeRF-DS authors' release v0.1-pre-release (github.com/JokerYan/NeRF-DS/releases), which
    # states no checksum. Its scenes are <scene>_novel_view/ Nerfies-layout folders; the specs name
    # them without the suffix (spec.NERFDS_SCENES).
    "nerfds": Archive(
        url="https://github.com/JokerYan/NeRF-DS/releases/download/v0.1-pre-release/NeRF-DS.dataset.zip",
        source="the NeRF-DS release v0.1-pre-release (github.com/JokerYan/NeRF-DS)",
        marker="dataset.json",
        suffix="_novel_view",
    ),
}
DATASETS = tuple(ARCHIVES)


def archives() -> dict[str, Archive]:
    """ARCHIVES with the entries LIQUIDGS_DATA_ARCHIVES overrides."""
    raw = os.environ.get(ARCHIVES_ENV)
    if not raw:
        return dict(ARCHIVES)
    try:
        overrides = json.loads(raw)
    except ValueError as err:
        raise ConfigError(f"{ARCHIVES_ENV}: not a JSON object of dataset -> {{url, size, sha256}} ({err})") from None
    if not isinstance(overrides, dict):
        raise ConfigError(f"{ARCHIVES_ENV}: not an object of objects (dataset -> {{url, size, sha256}})")
    table = dict(ARCHIVES)
    for name, fields in overrides.items():
        table[name] = table_entry(ARCHIVES_ENV, name, fields, Archive, ARCHIVES.get(name))
    return table


@dataclass(frozen=True)
class Downloaded:
    dataset: str
    folder: Path
    scenes: tuple[str, ...]
    size: int
    sha256: str
    checks: str
    """What the archive was checked against."""


def _check_archive(archive: Archive, path: Path, size: int, sha256: str) -> str:
    """The archive is the published one, as far as its source lets us tell; returns what was checked."""
    if archive.size is not None and size != archive.size:
        raise ConfigError(f"{archive.url}: got {size:,} bytes, the archive is {archive.size:,} bytes")
    if archive.sha256 is not None and sha256 != archive.sha256.lower():
        raise ConfigError(f"{archive.url}: SHA-256 {sha256}, the archive's is {archive.sha256.lower()}")
    try:
        with zipfile.ZipFile(path) as zipped:
            bad = zipped.testzip()
    except (zipfile.BadZipFile, OSError, EOFError) as err:
        raise ConfigError(f"{archive.url}: not a readable zip archive ({err})") from None
    if bad is not None:
        raise ConfigError(f"{archive.url}: archive member '{bad}' is corrupt (CRC mismatch)")
    checked = ["size " + ("as published" if archive.size is not None else "as the server announced")]
    checked.append("SHA-256 as published" if archive.sha256 is not None else "no published checksum")
    return ", ".join(checked) + ", every member's CRC"


def _scenes(root: Path, archive: Archive) -> list[Path]:
    folders = sorted(p.parent for p in root.rglob(archive.marker) if "__MACOSX" not in p.parts)
    return [p for p in folders if p != root]


def _new_folder(dest: Path) -> Path:
    """`dest`, refused when it exists or its parent does not, before anything is fetched."""
    dest = Path(dest)
    if dest.exists() or dest.is_symlink():
        raise ConfigError(f"{dest}: already exists (data download writes a new folder; remove it or name another)")
    if not dest.parent.is_dir():
        raise ConfigError(f"{dest.parent}: no such folder (data download creates {dest.name} inside it)")
    return dest


def download(dataset: str, dest: Path, report: Callable[[str], None] = print) -> Downloaded:
    """Fetch, check, unpack and validate `dataset` into the new folder `dest` (see the module's text)."""
    table = archives()
    if dataset not in table:
        raise ConfigError(f"unknown dataset '{dataset}' (choose from {', '.join([*table, CLIP_SET])})")
    archive = table[dataset]
    dest = _new_folder(dest)
    stem = f".{dest.name}.download-{os.getpid()}"
    zipped, unpacked = dest.with_name(stem + ".zip"), dest.with_name(stem)
    try:
        size, sha256 = fetch(archive.url, archive.size, zipped, report)
        checks = _check_archive(archive, zipped, size, sha256)
        report(f"got {size:,} bytes, SHA-256 {sha256} ({checks}); unpacking")
        with zipfile.ZipFile(zipped) as source:
            source.extractall(unpacked / "archive")
        zipped.unlink()
        scenes = _scenes(unpacked / "archive", archive)
        if not scenes:
            raise ConfigError(f"{archive.url}: no scene in the archive (no folder holds {archive.marker})")
        staged = unpacked / "scenes"
        staged.mkdir()
        names = []
        for scene in scenes:
            name = scene.name.removesuffix(archive.suffix) if archive.suffix else scene.name
            if (staged / name).exists():
                raise ConfigError(f"{archive.url}: two scene folders named '{name}' in the archive")
            lines = check_dataset(DataConfig(path=scene, cache_images=0)).lines()  # bad: one line naming the file
            report(f"checked {name}: " + "; ".join(line.split(":", 1)[1].strip() for line in lines[1:4]))
            scene.rename(staged / name)
            names.append(name)
        staged.rename(dest)
    finally:
        with contextlib.suppress(FileNotFoundError):
            zipped.unlink()
        shutil.rmtree(unpacked, ignore_errors=True)
    return Downloaded(dataset, dest, tuple(names), size, sha256, checks)


def main(dataset: str, dest: Path) -> int:
    report = lambda line: print(line, file=sys.stderr, flush=True)  # noqa: E731 - one line, used twice
    if dataset == CLIP_SET:
        table = download_clips(_new_folder(dest), report)
        print(f"{CLIP_SET}: {len(table)} clips in {dest}: {', '.join(f'{name}.mp4' for name in table)}")
        print(f"each checked against its recorded size and SHA-256; sources and licences: {Path(dest) / 'clips.json'}")
        return 0
    result = download(dataset, dest, report)
    print(f"{result.dataset}: {len(result.scenes)} scenes in {result.folder}: {', '.join(result.scenes)}")
    print(f"archive: {result.size:,} bytes, SHA-256 {result.sha256} ({result.checks})")
    return 0
