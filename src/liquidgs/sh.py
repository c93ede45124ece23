"""Real spherical harmonics up to degree 3, in the INRIA 3DGS / gsplat basis order and signs.

Shared by the scene model (gaussians/: colour <-> degree-0 coefficient) and the rasteriser (render/).
"""

from __future__ import annotations

import torch
from torch import Tensor

MAX_SH_DEGREE = 3

SH_C0 = 0.28209479177387814
"""The degree-0 basis function, a constant: colour = SH_C0 * coefficient (+ 0.5 in 3DGS)."""
_C1 = 0.4886025119029199
_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
_C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def num_sh_bases(sh_degree: int) -> int:
    """Number of SH coefficients a degree needs: (degree + 1)^2."""
    return (sh_degree + 1) ** 2


def eval_sh_bases(sh_degree: int, dirs: Tensor) -> Tensor:
    """SH basis functions [..., (sh_degree + 1)^2] at unit directions [..., 3]."""
    if not 0 <= sh_degree <= MAX_SH_DEGREE:
        raise ValueError(f"sh_degree must be in 0..{MAX_SH_DEGREE}, got {sh_degree}")
    x, y, z = dirs.unbind(-1)
    bases = [torch.full_like(x, SH_C0)]
    if sh_degree >= 1:
        bases += [-_C1 * y, _C1 * z, -_C1 * x]
    if sh_degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        bases += [
            _C2[0] * x * y,
            _C2[1] * y * z,
            _C2[2] * (2.0 * zz - xx - yy),
            _C2[3] * x * z,
            _C2[4] * (xx - yy),
        ]
    if sh_degree >= 3:
        bases += [
            _C3[0] * y * (3.0 * xx - yy),
            _C3[1] * x * y * z,
            _C3[2] * y * (4.0 * zz - xx - yy),
            _C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            _C3[4] * x * (4.0 * zz - xx - yy),
            _C3[5] * z * (xx - yy),
            _C3[6] * x * (xx - 3.0 * yy),
        ]
    return torch.stack(bases, dim=-1)


def eval_sh(sh_degree: int, coeffs: Tensor, dirs: Tensor) -> Tensor:
    """Evaluate SH colours: coeffs [..., K, C] with K >= (sh_degree + 1)^2, dirs [..., 3] -> [..., C].

    Directions need not be unit length; they are normalised here as gsplat does. Only the first
    (sh_degree + 1)^2 coefficients are used. No +0.5 offset or clamping is applied.
    """
    n_bases = num_sh_bases(sh_degree)
    if coeffs.shape[-2] < n_bases:
        raise ValueError(
            f"coeffs must have at least {n_bases} SH coefficients for degree {sh_degree}, "
            f"got shape {tuple(coeffs.shape)}"
        )
    unit_dirs = torch.nn.functional.normalize(dirs, dim=-1)
    bases = eval_sh_bases(sh_degree, unit_dirs)
    return (bases.unsqueeze(-1) * coeffs[..., :n_bases, :]).sum(dim=-2)
