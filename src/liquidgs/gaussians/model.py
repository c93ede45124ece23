"""Canonical Gaussians as a dict of parameters, in gsplat's layout and 3DGS activations.

params["means"]     [N,3]     world position
params["scales"]    [N,3]     log of the standard deviations       (activation: exp)
params["quats"]     [N,4]     rotation, wxyz, unnormalised          (activation: normalise)
params["opacities"] [N]       logit of the opacity                  (activation: sigmoid)
params["sh0"]       [N,1,3]   degree-0 SH coefficient
params["shN"]       [N,K-1,3] higher SH coefficients, K = (degree+1)^2
"""

from __future__ import annotations

import math

import torch

from liquidgs.gaussians.neighbors import mean_sq_dist_to_neighbors
from liquidgs.sh import SH_C0, num_sh_bases

PARAM_KEYS = ("means", "scales", "quats", "opacities", "sh0", "shN")


def rgb_to_sh0(rgb: torch.Tensor) -> torch.Tensor:
    return (rgb - 0.5) / SH_C0


def _params_from(means: torch.Tensor, sh0: torch.Tensor, sh_degree: int, init_opacity: float) -> torch.nn.ParameterDict:
    n = means.shape[0]
    d2 = mean_sq_dist_to_neighbors(means, k=3).clamp_min(1e-7)
    log_scale = torch.log(torch.sqrt(d2))[:, None].repeat(1, 3)
    quats = torch.zeros(n, 4, device=means.device)
    quats[:, 0] = 1.0
    opacities = torch.full((n,), math.log(init_opacity / (1.0 - init_opacity)), device=means.device)
    shN = torch.zeros(n, num_sh_bases(sh_degree) - 1, 3, device=means.device)
    tensors = {
        "means": means.float(),
        "scales": log_scale,
        "quats": quats,
        "opacities": opacities,
        "sh0": sh0.reshape(n, 1, 3).float(),
        "shN": shN,
    }
    return torch.nn.ParameterDict({k: torch.nn.Parameter(v.contiguous()) for k, v in tensors.items()})


def init_random_box(
    n: int,
    half_extent: float,
    sh_degree: int = 3,
    seed: int = 0,
    init_opacity: float = 0.1,
    device: str | torch.device = "cpu",
) -> torch.nn.ParameterDict:
    """D-3DGS synthetic initialisation: n points uniform in [-h, h]^3, near-grey colour.

    The reference draws the SH DC coefficient uniformly in [0, 1/255], which renders as grey
    (0.5 plus a hair).
    """
    gen = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=gen) * 2.0 - 1.0) * half_extent
    sh0 = torch.rand(n, 3, generator=gen) / 255.0
    return _params_from(means.to(device), sh0.to(device), sh_degree, init_opacity)


def init_from_points(
    points: torch.Tensor,
    colors: torch.Tensor | None = None,
    sh_degree: int = 3,
    init_opacity: float = 0.1,
) -> torch.nn.ParameterDict:
    """Initialise from a point cloud [N,3], with optional RGB colours in [0,1] (else grey)."""
    points = torch.as_tensor(points, dtype=torch.float32)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape [N,3], got {tuple(points.shape)}")
    if colors is None:
        colors = torch.full_like(points, 0.5)
    sh0 = rgb_to_sh0(torch.as_tensor(colors, dtype=torch.float32, device=points.device))
    return _params_from(points, sh0, sh_degree, init_opacity)


def activate(params: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The rasteriser's inputs: wxyz quats (normalised), std-devs, opacities in [0,1], SH [N,K,3]."""
    return {
        "means": params["means"],
        "quats": torch.nn.functional.normalize(params["quats"], dim=-1),
        "scales": torch.exp(params["scales"]),
        "opacities": torch.sigmoid(params["opacities"]),
        "colors": torch.cat([params["sh0"], params["shN"]], dim=1),
    }
