"""`liquidgs export --format web`: a static folder that plays a baked scene in a browser, offline;
`--format html`: the same page as one file with the scene inside it, which opens from disk.

index.html   the page: a canvas filling the window, play / pause, time slider, camera list, a link
             (#t=TIME&camera=NAME) to the time and camera shown; drag orbits, right-drag pans,
             wheel zooms
player.js    the WebGL2 player (bake/web/player.js): no library, nothing fetched but the two below
scene.json   Gaussian count, SH degree, background, the dataset's cameras, the source record of the
             run or baked scene it plays (run_folder.provenance), and scene.bin's sections
scene.bin    the baked scene as scene.pt stores it (bake/scene.py, stored_scene): each Gaussian's
             keyframes as many as its motion needs (one if it does not move), as the 8- or 16-bit
             codes of bake/tracks.py; opacity and SH degree 0 float16, the higher SH 8-bit codes.
             Little-endian sections one after another, named with their type and length in
             scene.json's "sections", the 4-byte ones first, then the 2-byte ones, then the bytes,
             so that each starts aligned for the typed array the page reads it into.

scene.html (--format html) is index.html with player.js, scene.json and scene.bin (base64) inline.
"""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
import torch

from liquidgs.atomic import build_atomically, write_atomic, write_text_atomic
from liquidgs.bake.distil import BakeSettings, distil
from liquidgs.bake.motion import POSITION
from liquidgs.bake.scene import stored_scene
from liquidgs.bake.tracks import ALL_WIDE, pack, unpack
from liquidgs.data.capture import refuse_taken
from liquidgs.errors import check_finite

WEB_FORMAT = "liquidgs-web/2"
PLAYER_FILES = ("index.html", "player.js")
PLAYER_DIR = Path(__file__).parent / "web"
LOOP_FPS = 24.0
"""Playback runs through the capture's distinct frame times at this rate."""
SECTION_TYPES = {"float32": "<f4", "int16": "<i2", "float16": "<f2", "uint8": "u1"}


def web_camera(frame, split: str) -> dict:
    """A camera as the page lists it and its links name it: the split before the frame's name, as
    test and train frames may share names."""
    camera = frame.camera
    return {
        "name": f"{split}/{frame.name}",
        "time": float(frame.time),
        "width": int(camera.width),
        "height": int(camera.height),
        "fx": float(camera.K[0, 0]),
        "fy": float(camera.K[1, 1]),
        "cx": float(camera.K[0, 2]),
        "cy": float(camera.K[1, 2]),
        "viewmat": camera.viewmat.double().flatten().tolist(),
    }


def baked_payload(run, frames) -> dict:
    """scene.pt's payload: a baked scene's as stored, a run's as `bake` would store it (its default
    budget, the pixel floor from `frames`' cameras)."""
    if run.field is not None:
        return stored_scene(run.params, distil(run, BakeSettings(), [f.camera for f in frames]).stored)
    if run.stored is not None:
        return run.stored
    # The format before (liquidgs-baked/2): float32 keyframes, stored here on 16 bits.
    wide = torch.full((run.tracks.gaussians,), ALL_WIDE, dtype=torch.uint8)
    return stored_scene(run.params, pack(run.tracks, wide))


def sections(payload: dict) -> list[tuple[str, str, torch.Tensor]]:
    """scene.bin's sections (name, type, values) in file order: wider types first."""
    tracks, params, sh_rest = payload["tracks"], payload["params"], payload["sh_rest"]
    return [
        ("low", "float32", tracks["low"]),
        ("counts", "int16", tracks["counts"]),
        ("codes16", "int16", tracks["codes16"]),
        ("span", "float16", tracks["span"]),
        ("opacities", "float16", params["opacities"]),
        ("sh0", "float16", params["sh0"]),
        ("sh_low", "float16", sh_rest["low"]),
        ("sh_span", "float16", sh_rest["span"]),
        ("wide", "uint8", tracks["wide"]),
        ("codes8", "uint8", tracks["codes8"]),
        ("sh_codes", "uint8", sh_rest["codes"]),
    ]


def web_scene(run, dataset) -> tuple[dict, bytes]:
    """scene.json's content and scene.bin's bytes for `run` (baked on the way if it is a run)."""
    frames = [*dataset.test, *dataset.train]
    payload = baked_payload(run, frames)
    parts = sections(payload)
    check_finite(run.run_dir, "the Gaussians and their keyframes as stored", [values for _, _, values in parts])
    n = int(payload["tracks"]["counts"].shape[0])
    splits = ["test"] * len(dataset.test) + ["train"] * len(dataset.train)
    times = {round(float(f.time), 6) for f in frames}
    positions = unpack(payload["tracks"], n).at_time(0.5)[:, POSITION]
    meta = {
        "format": WEB_FORMAT,
        "gaussians": n,
        "keyframes": int(payload["tracks"]["counts"].max()),
        "sh_degree": run.sh_degree,
        "sh_bases": (run.sh_degree + 1) ** 2,
        "sh_stored": 1 + int(payload["sh_rest"]["codes"].shape[1]),
        "background": [float(c) for c in dataset.background],
        "target": positions.median(dim=0).values.tolist(),
        "duration_s": max(len(times) / LOOP_FPS, 2.0),
        "cameras": [web_camera(f, split) for f, split in zip(frames, splits)],
        "source": run.source(),
        "sections": [[name, kind, int(values.numel())] for name, kind, values in parts],
    }
    blob = b"".join(
        np.ascontiguousarray(values.cpu().numpy(), dtype=SECTION_TYPES[kind]).tobytes() for _, kind, values in parts
    )
    return meta, blob


def write_web(out: Path, run, dataset) -> Path:
    refuse_taken(out)
    meta, blob = web_scene(run, dataset)

    def build(folder: Path) -> None:
        for name in PLAYER_FILES:
            player = (PLAYER_DIR / name).read_bytes()
            write_atomic(folder / name, lambda tmp, data=player: tmp.write_bytes(data))
        write_atomic(folder / "scene.bin", lambda tmp: tmp.write_bytes(blob))
        write_text_atomic(folder / "scene.json", json.dumps(meta))

    build_atomically(out, build)
    return out


PLAYER_TAG = '<script src="player.js"></script>'


def single_page(meta: dict, blob: bytes) -> str:
    """index.html with the player and the scene inline: one file, nothing to fetch."""
    page = (PLAYER_DIR / "index.html").read_text()
    player = (PLAYER_DIR / "player.js").read_text()
    # "<" escaped so no name or path in the JSON can close its <script> element.
    scene = json.dumps(meta).replace("<", "\\u003c")
    assert "</script" not in player.lower() and page.count(PLAYER_TAG) == 1
    inline = (
        f'<script id="scene-meta" type="application/json">{scene}</script>\n'
        f'<script id="scene-data" type="application/octet-stream">{base64.b64encode(blob).decode("ascii")}</script>\n'
        f"<script>\n{player}</script>"
    )
    return page.replace(PLAYER_TAG, inline)


def write_web_page(path: Path, run, dataset) -> Path:
    """--format html: scene.html, the page with the scene inside it."""
    meta, blob = web_scene(run, dataset)
    return write_text_atomic(path, single_page(meta, blob))
