"""`liquidgs export --format web`: a static folder that plays a baked scene in a browser, offline;
`--format html`: the same page as one file with the scene inside it, which opens from disk.

index.html   the page: a canvas filling the window, play / pause, time slider, camera list, a link
             (#t=TIME&camera=NAME) to the time and camera shown; drag orbits, right-drag pans,
             wheel zooms
player.js    the WebGL2 player (bake/web/player.js): no library, nothing fetched but the two below
scene.json   Gaussian and keyframe counts, SH degree, background, the dataset's cameras, and the
             source record of the run or baked scene it plays (run_folder.provenance)
scene.bin    little-endian: float32 low [N, 10] and span [N, 10] of each Gaussian's channels over
             time, opacities [N] (activated), SH coefficients [N, B, 3]; then the keyframes [K, N, 10]
             (bake/motion.py) as uint16 q, value = low + span * q / 65535 (error <= span / 131070:
             half the bytes of float32, for differences no pixel shows)

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
from liquidgs.bake.motion import POSITION, interpolate
from liquidgs.data.capture import refuse_taken
from liquidgs.errors import check_finite

PLAYER_FILES = ("index.html", "player.js")
PLAYER_DIR = Path(__file__).parent / "web"
LOOP_FPS = 24.0
"""Playback runs through the capture's distinct frame times at this rate."""


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


def keyframes_of(run) -> torch.Tensor:
    """A baked scene's keyframes, or a run's distilled with the default budget."""
    if run.field is None:
        return run.keyframes
    return distil(run, BakeSettings()).keyframes


def quantise(keyframes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """Per Gaussian and channel: the lowest value over the keyframes, the range, and each keyframe
    as a 16-bit fraction of the range."""
    low = keyframes.amin(dim=0)
    span = keyframes.amax(dim=0) - low
    fraction = (keyframes - low) / torch.where(span > 0, span, torch.ones_like(span))
    return low, span, (fraction * 65535).round().clamp(0, 65535).numpy().astype(np.uint16)


def web_scene(run, dataset) -> tuple[dict, bytes]:
    """scene.json's content and scene.bin's bytes for `run` (baked on the way if it is a run)."""
    keyframes = keyframes_of(run).detach().float().cpu()
    n = keyframes.shape[1]
    sh = torch.cat([run.params["sh0"], run.params["shN"]], dim=1).detach().float().cpu()
    opacities = torch.sigmoid(run.params["opacities"].detach().float().cpu())
    check_finite(run.run_dir, "the Gaussians and their keyframes", [keyframes, opacities, sh])
    frames = [*dataset.test, *dataset.train]
    splits = ["test"] * len(dataset.test) + ["train"] * len(dataset.train)
    times = {round(float(f.time), 6) for f in frames}
    meta = {
        "format": "liquidgs-web/1",
        "gaussians": n,
        "keyframes": keyframes.shape[0],
        "sh_degree": run.sh_degree,
        "sh_bases": (run.sh_degree + 1) ** 2,
        "sh_stored": sh.shape[1],
        "background": [float(c) for c in dataset.background],
        "target": interpolate(keyframes, 0.5)[:, POSITION].median(dim=0).values.tolist(),
        "duration_s": max(len(times) / LOOP_FPS, 2.0),
        "cameras": [web_camera(f, split) for f, split in zip(frames, splits)],
        "source": run.source(),
    }
    low, span, quantised = quantise(keyframes)
    blob = b"".join(np.ascontiguousarray(t.numpy(), dtype="<f4").tobytes() for t in (low, span, opacities, sh))
    blob += np.ascontiguousarray(quantised, dtype="<u2").tobytes()
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
