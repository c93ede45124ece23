"""Animated-splat formats that other players open: a PLY sequence in a .zip, and splaTV's .splatv.

plyseq: frame_0000.ply ... frame_{N-1}.ply (the standard 3DGS PLY, gaussians/ply.py) at N evenly
spaced times over [0, 1], in one .zip (Brush plays such a .zip; SuperSplat's timeline a sequence).

splatv (the layout of splaTV, antimatter15's player of Spacetime Gaussians' lite model):

    uint32 magic 0x674b, uint32 n = byte length of the header
    n bytes of UTF-8 JSON: a list of chunks; here one {"type": "splat", "size", "texwidth",
        "texheight", "cameras"} (cameras as 3DGS' cameras.json: camera-to-world rotation rows,
        camera position, fx, fy, width, height; the player starts at the first)
    the chunk: a texwidth x texheight RGBA32UI texture, texwidth 4096, 16 uint32 per Gaussian
        (1024 Gaussians per texture row), little-endian:
        0-2  position at the temporal centre, float32 x y z
        3-4  rotation wxyz, float16 pairs (low half first)
        5-6  scale (std-devs) x y z, float16, then a float16 0
        7    colour: r g b opacity, one byte each
        8-12 motion m0..m8, float16, then 0: position(t) = xyz + m[0:3] dt + m[3:6] dt^2 + m[6:9] dt^3
        13-14 rotation change omega wxyz, float16: rotation(t) = normalise(rot + omega dt)
        15   temporal centre c and temporal scale s, float16: opacity(t) = opacity exp(-(dt / s)^2)
        with dt = t - c, t in [0, 1]; unused slots of the last row are zero.

The model is fitted to the baked (or field) motion in bake/pieces.py: one record per Gaussian
where one cubic holds its motion (c = 0.5 and a temporal scale wide enough that the opacity stays
within 1e-6 of constant over [0, 1]), several short-lived ones where it does not. The cameras are
written at SPLATV_CAMERA_WIDTH pixels wide (focal lengths scaled with it, the field of view kept):
splaTV draws with the file's focal lengths in its own window, so training-size focal lengths
(64 px for the demo) would show the scene a few pixels tall.
"""

from __future__ import annotations

import io
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from liquidgs.atomic import write_atomic
from liquidgs.errors import DataError, check_finite
from liquidgs.gaussians.model import rgb_to_sh0
from liquidgs.gaussians.ply import ply_data
from liquidgs.train.model import Deformed
from liquidgs.train.run_folder import source_comment

SPLATV_MAGIC = 0x674B
TEXTURE_WIDTH = 4096
WORDS_PER_GAUSSIAN = 16
SPLATV_CAMERA_WIDTH = 1024
TEMPORAL_CENTRE = 0.5
TEMPORAL_SCALE = 500.0
"""exp(-(0.5 / 500)^2) > 1 - 1e-6: a flat temporal opacity over the capture."""
PLAYER_CUT = 0.02
"""splaTV and gsplat.js skip a record whose window exp(-(dt / s)^2) is below this (their vertex shader)."""

SPLATV_RECORD = np.dtype(
    [
        ("position", "<f4", 3),
        ("rotation", "<f2", 4),
        ("scale", "<f2", 4),
        ("rgba", "u1", 4),
        ("motion", "<f2", 10),
        ("omega", "<f2", 4),
        ("temporal", "<f2", 2),
    ]
)
assert SPLATV_RECORD.itemsize == 4 * WORDS_PER_GAUSSIAN


def frame_params(run, time: float) -> dict[str, torch.Tensor]:
    """The Gaussians at `time` in PLY parameter form (the rasteriser squares the scale, so a
    negative one is stored as log|s|)."""
    g = run.at_time(time)
    return {
        "means": g.means,
        "scales": torch.log(g.scales.abs().clamp_min(1e-12)),
        "quats": torch.nn.functional.normalize(g.quats, dim=-1),
        "opacities": run.params["opacities"],
        "sh0": run.params["sh0"],
        "shN": run.params["shN"],
    }


def sequence_times(frames: int) -> list[float]:
    """`frames` evenly spaced times over [0, 1]."""
    return [i / max(frames - 1, 1) for i in range(frames)]


def check_frames_finite(run, times: list[float]) -> None:
    """Refuse (one line, before anything is written) a run whose Gaussians are NaN or infinite, as
    they stand or at any of `times`: the field is evaluated once more per time, which costs less
    than a half-written export."""
    check_finite(run.run_dir, "the Gaussians", dict(run.params))
    for time in times:
        check_finite(run.run_dir, f"the Gaussians at time {time:g}", frame_params(run, time))


def write_plyseq(path: Path, run, frames: int) -> Path:
    """A .zip of `frames` PLYs at evenly spaced times over [0, 1], each with the run's source record."""
    check_frames_finite(run, sequence_times(frames))
    comments = (source_comment(run.source()),)

    def write(tmp: Path) -> None:
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
            for i, time in enumerate(sequence_times(frames)):
                stream = io.BytesIO()
                ply_data(frame_params(run, time), comments).write(stream)
                archive.writestr(f"frame_{i:04d}.ply", stream.getvalue())

    return write_atomic(path, write)


@dataclass
class SplatvModel:
    """Per Gaussian: splaTV's motion model (float32 here; the file stores float16)."""

    position: torch.Tensor  # [N,3] at the temporal centre
    motion: torch.Tensor  # [N,9] dt, dt^2, dt^3 coefficients (xyz each)
    rotation: torch.Tensor  # [N,4] wxyz
    omega: torch.Tensor  # [N,4]
    scale: torch.Tensor  # [N,3]
    rgb: torch.Tensor  # [N,3] in [0,1]
    opacity: torch.Tensor  # [N] in [0,1]
    temporal: torch.Tensor  # [N,2] centre, scale

    def at_time(self, time: float) -> Deformed:
        dt = time - self.temporal[:, :1]
        m = self.motion
        means = self.position + m[:, 0:3] * dt + m[:, 3:6] * dt**2 + m[:, 6:9] * dt**3
        quats = torch.nn.functional.normalize(self.rotation + self.omega * dt, dim=-1)
        window = torch.exp(-((dt[:, 0] / self.temporal[:, 1]) ** 2))
        opacity = self.opacity * torch.where(window < PLAYER_CUT, torch.zeros_like(window), window)
        colors = rgb_to_sh0(self.rgb)[:, None, :]
        return Deformed(means, quats, self.scale, opacity, colors)


def splatv_camera(camera, name: str, width: int | None = None) -> dict:
    """A camera in 3DGS' cameras.json form, which splaTV reads; with `width`, resized to that many
    pixels wide, the field of view kept."""
    c2w = np.linalg.inv(camera.viewmat.double().numpy())
    factor = 1.0 if width is None else width / camera.width
    return {
        "img_name": name,
        "width": round(camera.width * factor),
        "height": round(camera.height * factor),
        "position": c2w[:3, 3].tolist(),
        "rotation": c2w[:3, :3].tolist(),
        "fx": float(camera.K[0, 0]) * factor,
        "fy": float(camera.K[1, 1]) * factor,
    }


def splatv_bytes(model: SplatvModel, cameras: list[dict], source: dict | None = None) -> bytes:
    """The file; `source` (the run's source record) goes into the splat chunk's header, whose keys
    players other than liquidgs do not read."""
    n = model.position.shape[0]
    texheight = max(1, -(-n * WORDS_PER_GAUSSIAN // (TEXTURE_WIDTH * 4)))
    records = np.zeros(texheight * TEXTURE_WIDTH // 4, dtype=SPLATV_RECORD)
    used = records[:n]
    used["position"] = model.position.numpy()
    used["rotation"] = model.rotation.numpy()
    used["scale"][:, :3] = model.scale.numpy()
    rgba = torch.cat([model.rgb, model.opacity[:, None]], dim=1)
    used["rgba"] = (rgba * 255).round().clamp(0, 255).to(torch.uint8).numpy()
    used["motion"][:, :9] = model.motion.numpy()
    used["omega"] = model.omega.numpy()
    used["temporal"] = model.temporal.numpy()
    texture = records.tobytes()
    chunk = {"type": "splat", "size": len(texture), "texwidth": TEXTURE_WIDTH, "texheight": texheight}
    chunk["cameras"] = cameras
    header = [chunk if source is None else {**chunk, "source": source}]
    text = json.dumps(header).encode()
    return np.array([SPLATV_MAGIC, len(text)], dtype="<u4").tobytes() + text + texture


def read_splatv(path: Path) -> tuple[SplatvModel, dict]:
    """A .splatv file's first splat chunk (its Gaussians: records whose temporal scale is not
    zero) and that chunk's header."""
    return parse_splatv(Path(path).read_bytes(), path)


def parse_splatv(data: bytes, path: Path | str = "splatv") -> tuple[SplatvModel, dict]:
    if len(data) < 8:
        raise DataError(path, "too short for a splatv file")
    magic, length = np.frombuffer(data[:8], dtype="<u4")
    if magic != SPLATV_MAGIC:
        raise DataError(path, f"not a splatv file (magic {magic:#x}, expected {SPLATV_MAGIC:#x})")
    try:
        chunks = json.loads(data[8 : 8 + length])
    except ValueError as err:
        raise DataError(path, f"unreadable header ({err})") from None
    offset = 8 + int(length)
    for chunk in chunks:
        if chunk.get("type") == "splat":
            break
        offset += int(chunk["size"])
    else:
        raise DataError(path, "no splat chunk")
    size = int(chunk["texwidth"]) * int(chunk["texheight"]) * 16
    if int(chunk["size"]) != size or offset + size > len(data):
        raise DataError(path, f"splat chunk of {chunk['size']} bytes does not fit its texture or the file")
    records = np.frombuffer(data[offset : offset + size], dtype=SPLATV_RECORD)
    records = records[records["temporal"][:, 1] != 0]

    def tensor(column, width=None):
        values = records[column].astype(np.float32)
        return torch.from_numpy(values[:, :width] if width else values)

    rgba = torch.from_numpy(records["rgba"].astype(np.float32) / 255.0)
    model = SplatvModel(
        position=tensor("position"),
        motion=tensor("motion", 9),
        rotation=tensor("rotation"),
        omega=tensor("omega"),
        scale=tensor("scale", 3),
        rgb=rgba[:, :3],
        opacity=rgba[:, 3],
        temporal=tensor("temporal"),
    )
    return model, chunk
