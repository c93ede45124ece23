"""`liquidgs export --format web`: a static folder that plays a baked scene in a browser, offline.

index.html   the page: canvas, play / pause, time slider, camera list; drag orbits, wheel zooms
player.js    the WebGL2 player (bake/web/player.js): no library, nothing fetched but the two below
scene.json   Gaussian and keyframe counts, SH degree, background, the dataset's cameras, and the
             source record of the run or baked scene it plays (run_folder.provenance)
scene.bin    little-endian: float32 low [N, 10] and span [N, 10] of each Gaussian's channels over
             time, opacities [N] (activated), SH coefficients [N, B, 3]; then the keyframes [K, N, 10]
             (bake/motion.py) as uint16 q, value = low + span * q / 65535 (error <= span / 131070:
             half the bytes of float32, for differences no pixel shows)
"""

from __future__ import annotations

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


def quantise(keyframes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """Per Gaussian and channel: the lowest value over the keyframes, the range, and each keyframe
    as a 16-bit fraction of the range."""
    low = keyframes.amin(dim=0)
    span = keyframes.amax(dim=0) - low
    fraction = (keyframes - low) / torch.where(span > 0, span, torch.ones_like(span))
    return low, span, (fraction * 65535).round().clamp(0, 65535).numpy().astype(np.uint16)


def write_web(out: Path, run, dataset) -> Path:
    refuse_taken(out)
    keyframes = keyframes_of(run).detach().float().cpu()
    n = keyframes.shape[1]
    sh = torch.cat([run.params["sh0"], run.params["shN"]], dim=1).detach().float().cpu()
    opacities = torch.sigmoid(run.params["opacities"].detach().float().cpu())
    check_finite(run.run_dir, "the Gaussians and their keyframes", [keyframes, opacities, sh])
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
        "source": run.source(),
    }
    low, span, quantised = quantise(keyframes)
    blob = b"".join(np.ascontiguousarray(t.numpy(), dtype="<f4").tobytes() for t in (low, span, opacities, sh))
    blob += np.ascontiguousarray(quantised, dtype="<u2").tobytes()

    def build(folder: Path) -> None:
        for name in PLAYER_FILES:
            player = (PLAYER_DIR / name).read_bytes()
            write_atomic(folder / name, lambda tmp, data=player: tmp.write_bytes(data))
        write_atomic(folder / "scene.bin", lambda tmp: tmp.write_bytes(blob))
        write_text_atomic(folder / "scene.json", json.dumps(meta))

    build_atomically(out, build)
    return out
