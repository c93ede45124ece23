"""`liquidgs export --format web`: a static folder that plays a baked scene in a browser, offline.

index.html   the page: canvas, play / pause, time slider, camera list; drag orbits, wheel zooms
player.js    the WebGL2 player (bake/web/player.js): no library, nothing fetched but the two below
scene.json   Gaussian and keyframe counts, SH degree, background, the dataset's cameras
scene.bin    float32 little-endian: keyframes [K, N, 10] (bake/motion.py), opacities [N] (activated),
             SH coefficients [N, B, 3]
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import torch

from liquidgs.bake.distil import BakeSettings, distil
from liquidgs.bake.motion import POSITION, interpolate
from liquidgs.data.capture import build_atomically, refuse_taken

PLAYER_FILES = ("index.html", "player.js")
PLAYER_DIR = Path(__file__).parent / "web"
LOOP_FPS = 24.0
"""Playback runs through the capture's distinct frame times at this rate."""


def web_camera(frame) -> dict:
    camera = frame.camera
    return {
        "name": frame.name,
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


def write_web(out: Path, run, dataset) -> Path:
    refuse_taken(out)
    keyframes = keyframes_of(run).detach().float().cpu()
    n = keyframes.shape[1]
    sh = torch.cat([run.params["sh0"], run.params["shN"]], dim=1).detach().float().cpu()
    frames = [*dataset.test, *dataset.train]
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
        "cameras": [web_camera(f) for f in frames],
    }
    blob = b"".join(
        np.ascontiguousarray(t.numpy(), dtype="<f4").tobytes()
        for t in (keyframes, torch.sigmoid(run.params["opacities"].detach().float().cpu()), sh)
    )

    def build(folder: Path) -> None:
        for name in PLAYER_FILES:
            shutil.copyfile(PLAYER_DIR / name, folder / name)
        (folder / "scene.bin").write_bytes(blob)
        (folder / "scene.json").write_text(json.dumps(meta))

    build_atomically(out, build)
    return out
