"""The neighbour regularisers: zero for a rigid motion, positive for a stretch, on for captures only,
weighted by the field's kind unless set, and off in the paper's specs (whose identities stay those of
before)."""

from __future__ import annotations

import torch

from liquidgs.experiments.spec import BUILTIN_SPECS
from liquidgs.render.projection import quat_to_rotmat
from liquidgs.train.camera_opt import _half_angle_quaternion, _quat_multiply
from liquidgs.train.motion_reg import (
    MotionRegConfig,
    MotionRegulariser,
    holds_sizes,
    nearest_neighbours,
    regularisation,
)


def _cloud(n: int = 300):
    g = torch.Generator().manual_seed(0)
    return torch.rand(n, 3, generator=g), torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1)


def test_a_rigid_motion_costs_nothing_and_a_stretch_does():
    means, quats = _cloud()
    reg = MotionRegulariser(MotionRegConfig(anchors=100), (0.5, 0.5))
    turn = _half_angle_quaternion(torch.tensor([0.3, -0.2, 0.5]))
    turned = means @ quat_to_rotmat(turn[None])[0].T + torch.tensor([0.4, 0.1, -0.2])
    # Positions and Gaussians turned together: rigid, free.
    assert reg.loss(1, means, quats, turned, _quat_multiply(turn, quats)) < 1e-5
    # Positions turned, the Gaussians not: the offsets do not turn with their Gaussians.
    assert reg.loss(2, means, quats, turned, quats) > 0.01
    stretched = (means * torch.tensor([1.3, 1.0, 1.0])).requires_grad_()
    loss = reg.loss(3, means, quats, stretched, quats)
    loss.backward()
    assert loss > 0.01 and stretched.grad.abs().sum() > 0


def test_neighbours_exclude_the_point_itself():
    points = torch.tensor([[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0], [3.5, 0, 0]])
    assert nearest_neighbours(points, 1)[:, 0].tolist() == [1, 0, 3, 2]


def test_on_for_captures_off_for_dnerf_the_static_model_and_the_paper_specs():
    cfg = MotionRegConfig()
    assert regularisation(cfg, "nerfies", "hexplane") == (0.5, 0.5) and regularisation(cfg, "dnerf", "hexplane") is None
    assert regularisation(cfg, "nerfies", "static") is None
    assert regularisation(MotionRegConfig(apply="off"), "nerfies", "hexplane") is None
    for name in ("paper-dnerf", "paper-dnerf-3seeds", "paper-nerfds", "paper-nerfds-3seeds", "noise-study", "seeds"):
        for grid in BUILTIN_SPECS[name].grids:
            overrides = grid.overrides
            switches = (overrides["motion.apply"], overrides["cameras.refine"], overrides["exposure.apply"])
            assert switches == ("off", "off", "off"), name


def test_the_weights_follow_the_field_unless_set():
    """A grid field (registered with local_deformation) is held rigid by default; one network over
    all of space is not, but still has its sizes held; a weight given is the weight used."""
    cfg = MotionRegConfig()
    for field in ("mlp", "cfc", "sde"):
        assert regularisation(cfg, "nerfies", field) is None and holds_sizes(cfg, "nerfies", field)
    assert holds_sizes(cfg, "nerfies", "hexplane") and not holds_sizes(cfg, "dnerf", "hexplane")
    assert regularisation(MotionRegConfig(rigidity=0.2), "nerfies", "mlp") == (0.2, 0.0)
    assert regularisation(MotionRegConfig(rigidity=0, isometry=0), "nerfies", "hexplane") is None
    assert regularisation(MotionRegConfig(isometry=1.5), "nerfies", "hexplane") == (0.5, 1.5)
