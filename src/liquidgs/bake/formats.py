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

The model is fitted here by least squares to the baked (or field) motion sampled at FIT_SAMPLES
times: a cubic in dt for the position, a line for the (sign-aligned) quaternion, the mean of the
scale, the SH degree-0 colour (splatv has no view dependence), c = 0.5 and a temporal scale wide
enough that the opacity stays within 1e-6 of constant over [0, 1].
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
from liquidgs.bake.motion import POSITION, QUATERNION, SCALE, align_quaternion_signs, keyframe_times, pack_keyframe
from liquidgs.errors import DataError, check_finite
from liquidgs.gaussians.model import rgb_to_sh0
from liquidgs.gaussians.ply import ply_data
from liquidgs.sh import SH_C0
from liquidgs.train.model import Deformed
from liquidgs.train.run_folder import source_comment

SPLATV_MAGIC = 0x674B
TEXTURE_WIDTH = 4096
WORDS_PER_GAUSSIAN = 16
FIT_SAMPLES = 65
TEMPORAL_CENTRE = 0.5
TEMPORAL_SCALE = 500.0
"""exp(-(0.5 / 500)^2) > 1 - 1e-6: a flat temporal opacity over the capture."""

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
        opacity = self.opacity * torch.exp(-((dt[:, 0] / self.temporal[:, 1]) ** 2))
        colors = rgb_to_sh0(self.rgb)[:, None, :]
        return Deformed(means, quats, self.scale, opacity, colors)


def fit_splatv(run) -> tuple[SplatvModel, float | None]:
    """splaTV's model fitted to `run.at_time` (a run or a baked scene), and the share of the
    motion it keeps: 1 - (squared position residual) / (squared position deviation from each
    Gaussian's mean position), over the fit samples; None where no Gaussian moves (no motion to keep)."""
    times = keyframe_times(FIT_SAMPLES)
    states = []
    for t in times.tolist():
        g = run.at_time(t)
        states.append(pack_keyframe(g.means, g.quats, g.scales).float().cpu())
    states = align_quaternion_signs(torch.stack(states)).double()  # [S,N,10]
    dt = (times - TEMPORAL_CENTRE)[:, None]
    cubic = torch.cat([torch.ones_like(dt), dt, dt**2, dt**3], dim=1)  # [S,4]
    n = states.shape[1]
    positions = states[:, :, POSITION].reshape(FIT_SAMPLES, -1)
    position_coef = torch.linalg.lstsq(cubic, positions).solution  # [4, N*3]
    residual = positions - cubic @ position_coef
    deviation = positions - positions.mean(0, keepdim=True)
    moved = float((deviation**2).sum())
    # The cubic's constant term alone fits the mean, so the share is within [0, 1] but for rounding.
    kept = min(max(1.0 - float((residual**2).sum()) / moved, 0.0), 1.0) if moved > 0 else None
    quats = states[:, :, QUATERNION].reshape(FIT_SAMPLES, -1)
    quat_coef = torch.linalg.lstsq(cubic[:, :2], quats).solution  # [2, N*4]
    coef = position_coef.reshape(4, n, 3)
    activated_sh0 = run.params["sh0"].detach().cpu().reshape(n, 3).double()
    model = SplatvModel(
        position=coef[0].float(),
        motion=torch.cat([coef[1], coef[2], coef[3]], dim=1).float(),
        rotation=quat_coef[0].reshape(n, 4).float(),
        omega=quat_coef[1].reshape(n, 4).float(),
        scale=states[:, :, SCALE].abs().mean(0).float(),
        rgb=(activated_sh0 * SH_C0 + 0.5).clamp(0, 1).float(),
        opacity=torch.sigmoid(run.params["opacities"].detach().cpu().float()),
        temporal=torch.tensor([TEMPORAL_CENTRE, TEMPORAL_SCALE]).expand(n, 2).clone(),
    )
    return model, kept


def splatv_camera(camera, name: str) -> dict:
    """A camera in 3DGS' cameras.json form, which splaTV reads."""
    c2w = np.linalg.inv(camera.viewmat.double().numpy())
    return {
        "img_name": name,
        "width": int(camera.width),
        "height": int(camera.height),
        "position": c2w[:3, 3].tolist(),
        "rotation": c2w[:3, :3].tolist(),
        "fx": float(camera.K[0, 0]),
        "fy": float(camera.K[1, 1]),
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


def write_splatv(path: Path, model: SplatvModel, cameras: list[dict], source: dict | None = None) -> Path:
    data = splatv_bytes(model, cameras, source)
    return write_atomic(path, lambda tmp: tmp.write_bytes(data))


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
