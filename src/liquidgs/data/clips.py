"""`liquidgs data download real-clips DIR`: the real-clip benchmark's videos, fetched and checked.

The clips are public demo videos of other projects (a handheld camera; a person, an animal or an
object moving, or nothing moving), pinned to a commit. None of them is in this repository: each
licence is the clip's repository's, noted in CLIPS and written beside the clips (DIR/clips.json),
and most forbid commercial use. Nothing appears at DIR until every clip has been fetched and
matched its recorded size and SHA-256; on any failure, Ctrl-C included, the temporary folder beside
DIR is removed.

LIQUIDGS_REAL_CLIPS (a JSON object {"apple": {"url": ..., "size": ..., "sha256": ...}}), when set,
is the set: the clips it names, each with its CLIPS entry's fields unless it gives them (a mirror,
or the tests' server on 127.0.0.1).

What to do with them (register each with `data video`, then the benchmark's experiment):
docs/results/real-clips.md and scripts/real_clips.sh.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

from liquidgs.data.fetch import fetch, table_entry
from liquidgs.errors import ConfigError

CLIPS_ENV = "LIQUIDGS_REAL_CLIPS"
SET_NAME = "real-clips"

_COTRACKER = "https://raw.githubusercontent.com/facebookresearch/co-tracker/82e02e8029753ad4ef13cf06be7f4fc5facdda4d"
_COTRACKER_LICENCE = "CC BY-NC 4.0 (the LICENSE.md of facebookresearch/co-tracker)"
_DAVIS = "; a DAVIS 2017 sequence (DAVIS: CC BY 4.0 for its sequences unless stated otherwise)"


@dataclass(frozen=True)
class Clip:
    url: str
    size: int
    sha256: str
    licence: str
    moving: str
    """What moves in front of the moving camera; '' when nothing does."""


CLIPS = {
    "apple": Clip(f"{_COTRACKER}/gradio_demo/videos/apple.mp4", 1_219_872,
                  "c7f48c5cfb1479e1dbc1df2373d5cad4f55c198bbdb379da0ece10087971542a", _COTRACKER_LICENCE, ""),
    "bear": Clip(f"{_COTRACKER}/gradio_demo/videos/bear.mp4", 893_943,
                 "eeffab1780be601b19b2097be81a8c2d4fa2b624ac1028be0a32191d25acca0f", _COTRACKER_LICENCE + _DAVIS,
                 "a bear walking over rocks"),
    "cat": Clip(f"{_COTRACKER}/gradio_demo/videos/cat.mp4", 253_409,
                "a41ab94e89fd0f44f829d545ab6e604437146608357266709e0cc726378d1872", _COTRACKER_LICENCE,
                "a cat on a sofa turning its head"),
    "lady-running": Clip(
        "https://raw.githubusercontent.com/Junyi42/monst3r/574cc77ad278bad582f470e5382624e01f8769a7/demo_data/"
        "lady-running.mp4", 1_480_079, "57acc2a05b8afa05a42977b4db0c99596d9cd02f9703868c83fb0dfdf855167e",
        "CC BY-NC-SA 4.0 (the LICENSE of Junyi42/monst3r)" + _DAVIS, "a woman running through a room"),
    "backpack": Clip(f"{_COTRACKER}/gradio_demo/videos/backpack.mp4", 1_208_738,
                     "4b5ac6b2285ffb48e3a740e419e38c781df9c963589a5fd894e5b4e13dd6a8b8", _COTRACKER_LICENCE,
                     "a person on stairs swinging a backpack"),
    "teddy": Clip(f"{_COTRACKER}/gradio_demo/videos/teddy.mp4", 1_337_504,
                  "720503173c3b23b1d3d3fefa0e930558f944f0562e6a7b3c23810fc7046b39c7", _COTRACKER_LICENCE,
                  "a teddy bear turned about in a person's hands"),
    "pillow": Clip(f"{_COTRACKER}/gradio_demo/videos/pillow.mp4", 1_407_147,
                   "8f05818f586d7b0796fcd4714ea4be489c93701598cadc86ce7973fc24655fee", _COTRACKER_LICENCE,
                   "a pillow swung about in a person's hands"),
    "paragliding-launch": Clip(f"{_COTRACKER}/gradio_demo/videos/paragliding-launch.mp4", 829_010,
                               "4cdc5c670b372cc93763a4cbed99a79080ff98185b9386cea90920d71c14d31f",
                               _COTRACKER_LICENCE + _DAVIS, "a paraglider running down a slope and taking off"),
}  # fmt: skip


def clips() -> dict[str, Clip]:
    """CLIPS, or the set LIQUIDGS_REAL_CLIPS names."""
    raw = os.environ.get(CLIPS_ENV)
    if not raw:
        return dict(CLIPS)
    try:
        chosen = json.loads(raw)
    except ValueError as err:
        raise ConfigError(f"{CLIPS_ENV}: not a JSON object of clip -> {{url, size, sha256, ...}} ({err})") from None
    if not isinstance(chosen, dict) or not chosen:
        raise ConfigError(f"{CLIPS_ENV}: not a non-empty object of objects (clip -> {{url, size, sha256, ...}})")
    table = {name: table_entry(CLIPS_ENV, name, given, Clip, CLIPS.get(name)) for name, given in chosen.items()}
    for name in table:
        if not name or name.startswith(".") or {"/", "\\"} & set(name):
            raise ConfigError(f"{CLIPS_ENV}: clip name {name!r} is not a file name")
    return table


def download_clips(dest: Path, report: Callable[[str], None]) -> dict[str, Clip]:
    """Fetch every clip into the new folder `dest` as <name>.mp4, each checked against its recorded
    size and SHA-256, with clips.json (source, licence, what moves); nothing at `dest` on failure."""
    table = clips()
    staged = dest.with_name(f".{dest.name}.download-{os.getpid()}")
    try:
        staged.mkdir()
        for name, clip in table.items():
            size, sha256 = fetch(clip.url, clip.size, staged / f"{name}.mp4", report)
            if size != clip.size:
                raise ConfigError(f"{clip.url}: got {size:,} bytes, the clip is {clip.size:,} bytes")
            if sha256 != clip.sha256.lower():
                raise ConfigError(f"{clip.url}: SHA-256 {sha256}, the clip's is {clip.sha256.lower()}")
            report(f"got {name}.mp4: {size:,} bytes, SHA-256 as recorded; licence: {clip.licence}")
        listing = {name: asdict(clip) for name, clip in table.items()}
        (staged / "clips.json").write_text(json.dumps(listing, indent=2) + "\n")
        staged.rename(dest)
    finally:
        with contextlib.suppress(FileNotFoundError):
            shutil.rmtree(staged)
    return table
