"""The standard 3DGS PLY layout (binary little-endian float32), read by property name.

x y z nx ny nz f_dc_0..2 f_rest_0..(3*(K-1)-1) opacity scale_0..2 rot_0..3, with opacity
as a logit, scales as logs, rotation wxyz and f_rest channel-major (all of R, then G, B).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement, PlyParseError

from liquidgs.atomic import write_atomic
from liquidgs.errors import DataError


def _attribute_names(num_rest: int) -> list[str]:
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(num_rest)]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    return names


def write_ply(path: str | Path, params: dict[str, torch.Tensor], comments: tuple[str, ...] = ()) -> Path:
    """Write canonical (or deformed) Gaussians, with header `comments`; the file appears atomically."""
    ply = ply_data(params, comments)
    return write_atomic(Path(path), lambda tmp: ply.write(str(tmp)))


def ply_data(params: dict[str, torch.Tensor], comments: tuple[str, ...] = ()) -> PlyData:
    """The Gaussians as a PLY document (write it to a path or a binary stream); `comments` go into
    the header, where every PLY reader skips them."""
    means = params["means"].detach().float().cpu().numpy()
    n = means.shape[0]
    shN = params["shN"].detach().float().cpu()
    f_rest = shN.transpose(1, 2).reshape(n, -1).numpy()  # channel-major
    columns = [
        means,
        np.zeros_like(means),
        params["sh0"].detach().float().cpu().reshape(n, 3).numpy(),
        f_rest,
        params["opacities"].detach().float().cpu().reshape(n, 1).numpy(),
        params["scales"].detach().float().cpu().numpy(),
        params["quats"].detach().float().cpu().numpy(),
    ]
    data = np.concatenate(columns, axis=1).astype("<f4")
    names = _attribute_names(f_rest.shape[1])
    vertex = np.empty(n, dtype=[(name, "<f4") for name in names])
    for i, name in enumerate(names):
        vertex[name] = data[:, i]
    return PlyData([PlyElement.describe(vertex, "vertex")], byte_order="<", comments=list(comments))


MAX_HEADER_BYTES = 1 << 16


def read_ply_comments(path: str | Path) -> list[str]:
    """The header comments of a PLY, reading the header only."""
    path = Path(path)
    comments = []
    try:
        with open(path, "rb") as file:
            header = file.read(MAX_HEADER_BYTES)
    except OSError as err:
        raise DataError(path, f"unreadable ({err.strerror or err})") from None
    for line in header.split(b"\n"):
        if line.startswith(b"end_header"):
            return comments
        if line.startswith(b"comment "):
            comments.append(line[len(b"comment ") :].decode("utf-8", "replace").rstrip("\r"))
    raise DataError(path, f"not a readable 3DGS PLY (no end_header in its first {MAX_HEADER_BYTES} bytes)")


def read_ply(path: str | Path, device: str | torch.device = "cpu") -> dict[str, torch.Tensor]:
    """Read a 3DGS PLY into the parameter layout of liquidgs.gaussians.model."""
    path = Path(path)
    try:
        vertex = PlyData.read(str(path))["vertex"]
    except (OSError, ValueError, KeyError, PlyParseError) as err:
        raise DataError(path, f"not a readable 3DGS PLY ({err})") from None
    props = {p.name for p in vertex.properties}
    required = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
    required += [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)]
    for name in required:
        if name not in props:
            raise DataError(path, "missing vertex property", field=name)
    rest_names = sorted((p for p in props if p.startswith("f_rest_")), key=lambda s: int(s[7:]))
    if len(rest_names) % 3:
        raise DataError(path, f"{len(rest_names)} f_rest properties is not a multiple of 3", field="f_rest")

    def col(*names: str) -> torch.Tensor:
        return torch.from_numpy(np.stack([np.asarray(vertex[nm], dtype=np.float32) for nm in names], axis=1))

    n = len(vertex.data)
    k_rest = len(rest_names) // 3
    shN = col(*rest_names) if rest_names else torch.zeros(n, 0)
    out = {
        "means": col("x", "y", "z"),
        "scales": col("scale_0", "scale_1", "scale_2"),
        "quats": col("rot_0", "rot_1", "rot_2", "rot_3"),
        "opacities": col("opacity")[:, 0],
        "sh0": col("f_dc_0", "f_dc_1", "f_dc_2").reshape(n, 1, 3),
        "shN": shN.reshape(n, 3, k_rest).transpose(1, 2).contiguous(),
    }
    return {k: v.to(device) for k, v in out.items()}
