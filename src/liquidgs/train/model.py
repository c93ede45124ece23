"""A trained dynamic scene: canonical Gaussians plus a deformation field, renderable at a time."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from liquidgs.cameras import Camera
from liquidgs.gaussians.model import activate
from liquidgs.render import RenderOutput, rasterize


@dataclass
class Deformed:
    """Activated Gaussians at one time: the rasteriser's inputs."""

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor
    colors: torch.Tensor


def deform(
    params: torch.nn.ParameterDict,
    field: torch.nn.Module | None,
    time: float | torch.Tensor,
    time_noise: float = 0.0,
    moving: torch.Tensor | None = None,
) -> Deformed:
    """Apply the field's deltas the way D-3DGS does.

    means = xyz + d_xyz; scales = exp(log_scale) + d_scaling (after the activation);
    rotation = normalize(q) + d_rotation (renormalised by the rasteriser). With field None
    (the static model, or the warm-up) the deltas are zero. `moving` (int64 indices, the dynamic
    Gaussians of a split run) limits the field to those Gaussians: the others keep zero deltas and
    cost nothing.
    """
    act = activate(params)
    if field is None or (moving is not None and moving.numel() == 0):
        return Deformed(act["means"], act["quats"], act["scales"], act["opacities"], act["colors"])
    # One time for every Gaussian stays a [1, 1] column: the field encodes it once.
    t = torch.as_tensor(time, dtype=params["means"].dtype, device=params["means"].device).reshape(-1, 1) + time_noise
    if moving is None:
        d_xyz, d_rotation, d_scaling = field(params["means"], t)
        return Deformed(
            means=act["means"] + d_xyz,
            quats=act["quats"] + d_rotation,
            scales=act["scales"] + d_scaling,
            opacities=act["opacities"],
            colors=act["colors"],
        )
    d_xyz, d_rotation, d_scaling = field(params["means"][moving], t)
    return Deformed(
        means=act["means"].index_add(0, moving, d_xyz),
        quats=act["quats"].index_add(0, moving, d_rotation),
        scales=act["scales"].index_add(0, moving, d_scaling),
        opacities=act["opacities"],
        colors=act["colors"],
    )


def hold_sizes(field: torch.nn.Module) -> torch.nn.Module:
    """The field with its size deltas dropped: it moves and turns Gaussians, never resizes them (the
    motion setting fixed_sizes). A forward hook, so any registered field takes it and its weights and
    checkpoints are unchanged."""

    def without_size_deltas(_module, _inputs, deltas):
        d_xyz, d_rotation, d_scaling = deltas
        return d_xyz, d_rotation, torch.zeros_like(d_scaling)

    field.register_forward_hook(without_size_deltas)
    return field


def render_frame(
    gaussians: Deformed,
    camera: Camera,
    *,
    sh_degree: int,
    background: torch.Tensor,
    backend: str = "auto",
    absgrad: bool = False,
    features: torch.Tensor | None = None,
) -> RenderOutput:
    """The Gaussians seen by `camera`; `features` [N, C], if given, composited in the same pass."""
    device = gaussians.means.device
    return rasterize(
        gaussians.means,
        gaussians.quats,
        gaussians.scales,
        gaussians.opacities,
        gaussians.colors,
        camera.viewmat.to(device),
        camera.K.to(device),
        camera.width,
        camera.height,
        sh_degree=sh_degree,
        background=background.to(device),
        backend=backend,
        absgrad=absgrad,
        features=features,
    )
