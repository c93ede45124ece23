"""The optical-flow loss (train.flow_loss): the Gaussians' screen motion, composited in the colour pass."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import gsplat_cpu_kernels
from liquidgs.cameras import Camera
from liquidgs.data.flow import FlowPair
from liquidgs.render import cpu_backend, gsplat_backend
from liquidgs.train.flow_loss import FlowLoss, project_with_depth, rendered_flow
from liquidgs.train.model import Deformed, render_frame

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
        colors=torch.zeros(2, 1, 3, dtype=torch.float64),  # SH degree 0
    )


@pytest.fixture
def gsplat_on_the_cpu(monkeypatch, one_torch_thread):
    """gsplat's kernels stood in for on the CPU (tests/gsplat_cpu_kernels.py); liquidgs told they run."""
    gsplat_cpu_kernels.install(monkeypatch)
    monkeypatch.setattr(gsplat_backend, "unavailable_reason", lambda means: None)


CPU_KERNEL = pytest.mark.skipif(cpu_backend.unavailable_reason() is not None, reason="no compiled CPU rasteriser")
BACKENDS = ["torch", pytest.param("cpu", marks=CPU_KERNEL), "gsplat"]


@pytest.mark.parametrize("backend", BACKENDS)
def test_the_composited_flow_of_two_gaussians_is_their_own_motion(backend, request):
    dtype = torch.float64
    if backend == "gsplat":
        request.getfixturevalue("gsplat_on_the_cpu")
        dtype = torch.float32  # gsplat rasterises float32 only
    now = Deformed(**{key: value.to(dtype) for key, value in vars(two_gaussians()).items()})
    shift = torch.tensor([[0.2, 0.0, 0.0], [0.0, -0.1, 0.0]], dtype=torch.float64)
    later = Deformed(**{key: value.to(dtype) for key, value in vars(two_gaussians(shift)).items()})
    flow, alpha = rendered_flow(now, camera(), later, camera(0.1), backend=backend)
    expected = project_with_depth(later.means, camera(0.1))[0] - project_with_depth(now.means, camera())[0]
    assert expected[0].tolist() == pytest.approx([(0.2 - 0.1) * FOCAL / 4, 0.0])  # its move less the camera's
    assert expected[1].tolist() == pytest.approx([-0.1 * FOCAL / 4, -0.1 * FOCAL / 4])
    for centre, motion in zip(project_with_depth(now.means, camera())[0], expected):
        col, row = int(centre[0]), int(centre[1])
        assert alpha[row, col] > 0.9
        assert flow[row, col].tolist() == pytest.approx(motion.tolist(), abs=1e-6 if dtype == torch.float64 else 1e-4)
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
    loss = FlowLoss(0.5, [pair], ["a", "b"], torch.device("cpu"))
    target = loss.target(0, np.random.default_rng(0))
    assert target.neighbour == 1 and loss.target(1, np.random.default_rng(0)).neighbour == 0
    drawn = loss.draw(now, camera(), later, camera(0.1), target)
    background = torch.zeros(3, dtype=torch.float64)
    out = render_frame(now, camera(), sh_degree=0, background=background, backend="torch", features=drawn.motion)
    assert float(loss.loss(out, drawn)) == pytest.approx(0.0, abs=1e-6)
    target.flow = target.flow + torch.tensor([1.0, -2.0])
    assert float(loss.loss(out, drawn)) == pytest.approx(0.5 * 1.5, rel=1e-5)
    target.valid = torch.zeros_like(target.valid)
    assert loss.loss(out, drawn) is None  # nothing to compare
    assert loss.target(7, np.random.default_rng(0)) is None  # a frame without flow


def test_a_frame_draws_its_neighbours_and_the_far_ends_of_its_tracks():
    flow = np.zeros((HEIGHT, WIDTH, 2), np.float32)
    valid = np.ones((HEIGHT, WIDTH), bool)
    names = ["a", "b", "c", "d", "e"]
    pairs = [FlowPair(x, y, flow, flow, valid, valid) for x, y in zip(names[:-1], names[1:])]
    tracks = [FlowPair(x, y, flow, flow, valid, valid, track=True) for x, y in (("a", "d"), ("b", "e"))]
    loss = FlowLoss(0.02, [*pairs, *tracks], names, torch.device("cpu"))
    rng = np.random.default_rng(0)
    drawn = {frame: {loss.target(frame, rng).neighbour for _ in range(64)} for frame in range(5)}
    assert drawn == {0: {1, 3}, 1: {0, 2, 4}, 2: {1, 3}, 3: {2, 4, 0}, 4: {3, 1}}


def test_a_gaussian_behind_or_beside_the_neighbours_camera_neither_counts_nor_learns():
    """On a real clip (lady-running) Gaussians in front of one camera but at or behind the next one's
    image plane composited thousands of pixels of motion into the flow and wrecked the training: such
    a Gaussian's pixels are left out, and its neighbour's flow is its own."""
    now = two_gaussians()
    shift = torch.tensor([[0.0, 0.0, -3.995], [0.0, 0.0, 0.0]], dtype=torch.float64)  # the first at depth 0.005
    later = two_gaussians(shift)
    later.means.requires_grad_(True)
    flow, covered = rendered_flow(now, camera(), later, camera(0.1), backend="torch")
    first, second = (project_with_depth(now.means, camera())[0][i].long().tolist() for i in (0, 1))
    assert covered[first[1], first[0]] < 1e-6 and covered[second[1], second[0]] > 0.9
    assert flow[second[1], second[0]].tolist() == pytest.approx([-0.1 * FOCAL / 4, 0.0])
    valid = np.ones((HEIGHT, WIDTH), bool)
    measured = np.zeros((HEIGHT, WIDTH, 2), np.float32)
    loss = FlowLoss(1.0, [FlowPair("a", "b", measured, measured, valid, valid)], ["a", "b"], torch.device("cpu"))
    drawn = loss.draw(now, camera(), later, camera(0.1), loss.target(0, np.random.default_rng(0)))
    out = render_frame(now, camera(), sh_degree=0, background=torch.zeros(3, dtype=torch.float64), backend="torch",
                       features=drawn.motion)  # fmt: skip
    value = loss.loss(out, drawn)
    value.backward()
    assert float(value.detach()) < 1.0  # the second Gaussian's 1 px over the pixels it covers, nothing of the first
    assert later.means.grad[0].abs().max() == 0 and later.means.grad[1].abs().max() > 0
    # A Gaussian still in front of both cameras but moving further than the image is wide counts neither.
    far = two_gaussians(torch.tensor([[60.0, 0.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64))
    _, covered = rendered_flow(now, camera(), far, camera(0.1), backend="torch")
    assert covered[first[1], first[0]] < 1e-6 and covered[second[1], second[0]] > 0.9
