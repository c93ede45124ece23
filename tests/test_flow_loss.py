"""The optical-flow loss (train.flow_loss): the Gaussians' screen motion, composited like colour."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from liquidgs.cameras import Camera
from liquidgs.data.flow import FlowPair
from liquidgs.train.flow_loss import FlowLoss, project, rendered_flow
from liquidgs.train.model import Deformed

WIDTH, HEIGHT, FOCAL = 48, 32, 40.0


def camera(x: float = 0.0) -> Camera:
    viewmat = torch.eye(4)
    viewmat[0, 3] = -x  # the camera at (x, 0, 0), looking along +z
    K = torch.tensor([[FOCAL, 0, WIDTH / 2], [0, FOCAL, HEIGHT / 2], [0, 0, 1.0]])
    return Camera(viewmat, K, WIDTH, HEIGHT)


def two_gaussians(shift: torch.Tensor | None = None) -> Deformed:
    """Two opaque Gaussians side by side at depth 4, each about 6 pixels across; `shift` [2, 3] moves them."""
    means = torch.tensor([[-0.9, 0.0, 4.0], [0.9, 0.1, 4.0]], dtype=torch.float64)
    if shift is not None:
        means = means + shift
    return Deformed(
        means=means,
        quats=torch.tensor([[1.0, 0, 0, 0]] * 2, dtype=torch.float64),
        scales=torch.full((2, 3), 0.25, dtype=torch.float64),
        opacities=torch.full((2,), 0.999, dtype=torch.float64),
        colors=torch.zeros(2, 3, dtype=torch.float64),
    )


def test_the_composited_flow_of_two_gaussians_is_their_own_motion():
    now = two_gaussians()
    shift = torch.tensor([[0.2, 0.0, 0.0], [0.0, -0.1, 0.0]], dtype=torch.float64)
    later = two_gaussians(shift)
    flow, alpha = rendered_flow(now, camera(), later, camera(0.1), backend="torch")
    expected = project(later.means, camera(0.1)) - project(now.means, camera())
    assert expected[0].tolist() == pytest.approx([(0.2 - 0.1) * FOCAL / 4, 0.0])  # its move less the camera's
    assert expected[1].tolist() == pytest.approx([-0.1 * FOCAL / 4, -0.1 * FOCAL / 4])
    for centre, motion in zip(project(now.means, camera()), expected):
        col, row = int(centre[0]), int(centre[1])
        assert alpha[row, col] > 0.9
        assert flow[row, col].tolist() == pytest.approx(motion.tolist(), abs=1e-6)
    assert alpha[0, 0] < 1e-3  # a corner no Gaussian covers


def test_the_compiled_cpu_kernel_composites_it_as_the_reference_does_gradients_included():
    results = {}
    for backend in ("torch", "cpu"):
        now = two_gaussians()
        shift = torch.tensor([[0.2, 0.05, 0.1], [0.0, -0.1, 0.0]], dtype=torch.float32, requires_grad=True)
        later = Deformed(**{k: v.float() for k, v in vars(two_gaussians()).items()})
        later.means = later.means + shift
        now = Deformed(**{k: v.float().requires_grad_(k == "means") for k, v in vars(now).items()})
        flow, alpha = rendered_flow(now, camera(), later, camera(0.1), backend=backend)
        (flow.square().sum() + alpha.sum()).backward()
        results[backend] = (flow.detach(), shift.grad.clone(), now.means.grad.clone())
    for reference, fast in zip(results["torch"], results["cpu"]):
        torch.testing.assert_close(fast, reference, rtol=1e-4, atol=1e-4)
    assert results["torch"][1].abs().sum() > 0  # the later positions learn from the loss


def test_the_loss_is_zero_for_the_true_flow_and_the_l1_of_the_error_otherwise():
    now, later = two_gaussians(), two_gaussians(torch.tensor([[0.2, 0, 0], [0, -0.1, 0]], dtype=torch.float64))
    flow, alpha = rendered_flow(now, camera(), later, camera(0.1), backend="torch")
    valid = np.ones((HEIGHT, WIDTH), bool)
    measured = flow.detach().numpy().astype(np.float32)
    pair = FlowPair("a", "b", measured, -measured, valid, valid)
    loss = FlowLoss(0.5, [pair], ["a", "b"], torch.device("cpu"), "torch")
    target = loss.target(0, np.random.default_rng(0))
    assert target.neighbour == 1 and loss.target(1, np.random.default_rng(0)).neighbour == 0
    assert float(loss.loss(now, camera(), later, camera(0.1), target)) == pytest.approx(0.0, abs=1e-6)
    target.flow = target.flow + torch.tensor([1.0, -2.0])
    assert float(loss.loss(now, camera(), later, camera(0.1), target)) == pytest.approx(0.5 * 1.5, rel=1e-5)
    target.valid = torch.zeros_like(target.valid)
    assert loss.loss(now, camera(), later, camera(0.1), target) is None  # nothing to compare
    assert loss.target(7, np.random.default_rng(0)) is None  # a frame without flow
