"""`liquidgs export --format spz --time T`: the Gaussians at one time as an SPZ file (Niantic's
compressed 3DGS format), written here from the format's description (github.com/nianticlabs/spz,
README "File Format"), version 3: the gzip-compressed single stream every SPZ reader of today
opens (version 4, zstd streams, is newer than most players).

Layout, little-endian, gzip-compressed as a whole:
  header (16 bytes)  magic 0x5053474e, version 3, count, SH degree, fractional bits, flags, 0
  positions          count x 3 x 24-bit signed fixed point, `fractional bits` after the point
  alphas             count x uint8: sigmoid(opacity) x 255
  colours            count x 3 x uint8: SH DC x (0.15 x 255) + 127.5
  scales             count x 3 x uint8: (log scale + 10) x 16
  rotations          count x uint32: the quaternion (x, y, z, w order) by its smallest three: the
                     largest's index in the top 2 bits, then per other component a sign bit and 9
                     bits of |q| / sqrt(1/2), largest made positive
  SH                 count x coefficients x 3 (colour fastest) x uint8: round(c x 128) + 128, on
                     buckets of 8 (degree 1) or 16 (higher) as the reference packer leaves them

SPZ holds its data in RUB axes (x right, y up, z back, as OpenGL and three.js); liquidgs' scenes,
like the 3DGS PLYs players read, are RDF (OpenCV: y down, z forward): y and z of positions and of
the quaternion's vector part are negated on the way out, as Niantic's PLY-to-SPZ converter does, so
a player shows the SPZ as it shows our PLY.
"""

from __future__ import annotations

import gzip
import math
from pathlib import Path

import numpy as np
import torch

from liquidgs.atomic import write_atomic
from liquidgs.errors import ConfigError

MAGIC = 0x5053474E
VERSION = 3
FRACTIONAL_BITS = 12
"""As the reference packer: 1/4096 of a unit, positions up to +-2048 units; scenes that reach further
get fewer fractional bits (the header says how many)."""
COLOUR_SCALE = 0.15
RDF_TO_RUB = np.array([1.0, -1.0, -1.0])
SH_BUCKET = {1: 8, 2: 16, 3: 16}
"""The reference packer's default SH precision: 5 bits for degree 1, 4 bits above."""


def fractional_bits(means: np.ndarray, path: Path) -> int:
    """The most fractional bits (at most FRACTIONAL_BITS) that hold every position in 24 bits."""
    reach = float(np.abs(means).max(initial=0.0))
    limit = (1 << 23) - 1
    for bits in range(FRACTIONAL_BITS, -1, -1):
        if reach * (1 << bits) <= limit:
            return bits
    raise ConfigError(f"{path}: a position reaches {reach:g}, beyond SPZ's 24-bit fixed point (+-{limit:,})")


def packed_positions(means: np.ndarray, bits: int) -> bytes:
    fixed = np.round(means * (1 << bits)).astype(np.int64) & 0xFFFFFF
    return np.stack([fixed & 0xFF, (fixed >> 8) & 0xFF, (fixed >> 16) & 0xFF], axis=-1).astype(np.uint8).tobytes()


def to_uint8(values: np.ndarray) -> np.ndarray:
    return np.clip(np.round(values), 0, 255).astype(np.uint8)


def packed_rotations(quats_xyzw: np.ndarray) -> bytes:
    """Smallest three: the largest component's index, then the other three as sign and magnitude."""
    q = quats_xyzw / np.linalg.norm(quats_xyzw, axis=1, keepdims=True)
    largest = np.abs(q).argmax(axis=1)
    q = q * np.where(q[np.arange(len(q)), largest] < 0, -1.0, 1.0)[:, None]  # -q is the same rotation
    word = largest.astype(np.uint32)
    for component in range(4):
        keep = largest != component
        magnitude = np.floor(511 * np.abs(q[:, component]) / math.sqrt(0.5) + 0.5).astype(np.uint32)
        code = ((q[:, component] < 0).astype(np.uint32) << 9) | np.minimum(magnitude, 511)
        word = np.where(keep, (word << 10) | code, word)
    return word.astype("<u4").tobytes()


def packed_sh(sh_rest: np.ndarray, degree: int) -> bytes:
    """sh_rest: [N, bases - 1, 3] (coefficient, then colour), liquidgs' own order."""
    if degree == 0:
        return b""
    quantised = np.round(sh_rest * 128.0) + 128.0
    buckets = np.array([SH_BUCKET[1] if k < 3 else SH_BUCKET[2] for k in range(sh_rest.shape[1])])[None, :, None]
    quantised = (quantised + buckets // 2) // buckets * buckets
    return to_uint8(quantised).tobytes()


def spz_bytes(params: dict[str, torch.Tensor], sh_degree: int, path: Path) -> bytes:
    """The SPZ file (gzip included) for Gaussians in PLY parameter form (liquidgs.bake.formats.frame_params)."""

    def array(name):
        return params[name].detach().double().cpu().numpy()

    means = array("means") * RDF_TO_RUB
    n = means.shape[0]
    quats = array("quats")  # w, x, y, z
    quats_xyzw = np.concatenate([quats[:, 1:] * RDF_TO_RUB, quats[:, :1]], axis=1)
    bits = fractional_bits(means, path)
    bases = (sh_degree + 1) ** 2
    sh_rest = array("shN")[:, : bases - 1] if sh_degree else np.zeros((n, 0, 3))
    # SH bases of odd degree in y or z change sign with the axes: the RDF -> RUB flip negates y and z.
    sh_rest = sh_rest * sh_axis_signs(sh_degree)[None, :, None]
    header = np.array([MAGIC, VERSION, n], dtype="<u4").tobytes() + bytes([sh_degree, bits, 0, 0])
    body = b"".join(
        [
            header,
            packed_positions(means, bits),
            to_uint8(255.0 / (1.0 + np.exp(-array("opacities").reshape(n)))).tobytes(),
            to_uint8(array("sh0").reshape(n, 3) * (COLOUR_SCALE * 255.0) + 127.5).tobytes(),
            to_uint8((array("scales") + 10.0) * 16.0).tobytes(),
            packed_rotations(quats_xyzw),
            packed_sh(sh_rest, sh_degree),
        ]
    )
    return gzip.compress(body, compresslevel=9, mtime=0)


def sh_axis_signs(degree: int) -> np.ndarray:
    """Per SH basis above degree 0 (liquidgs' / 3DGS' order), its sign when y and z are negated: the
    real SH basis functions are polynomials in x, y, z, each of fixed parity in y and in z."""
    # Exponents (of y, of z) of each basis' terms, in the order of liquidgs.sh: parity is what counts.
    parities = [
        (1, 0), (0, 1), (0, 0),  # y, z, x
        (1, 0), (1, 1), (0, 0), (0, 1), (0, 0),  # xy, yz, 3z^2-1, xz, x^2-y^2
        (1, 0), (1, 1), (1, 0), (0, 1), (0, 0), (0, 1), (0, 0),  # degree 3: y(3x^2-y^2), xyz, ...
    ]  # fmt: skip
    count = (degree + 1) ** 2 - 1
    return np.array([(-1.0) ** (py + pz) for py, pz in parities[:count]])


def write_spz(path: Path, params: dict[str, torch.Tensor], sh_degree: int) -> Path:
    data = spz_bytes(params, sh_degree, path)
    return write_atomic(path, lambda tmp: tmp.write_bytes(data))
