"""The neighbour regularisers: zero for a rigid motion, positive for a stretch, on for captures only,
weighted by the field's kind unless set, and off in the paper's specs (whose identities stay those of
before)."""

from __future__ import annotations

import pytest
import torch
import yaml

from liquidgs.data import generate_synthetic
from liquidgs.experiments.spec import BUILTIN_SPECS
from liquidgs.render.projection import quat_to_rotmat
from liquidgs.train.camera_opt import _half_angle_quaternion, _quat_multiply
from liquidgs.train.config import load_yaml
from liquidgs.train.model import deform
from liquidgs.train.motion_reg import (
    GLOBAL_FIELD_STILLNESS,
    MotionRegConfig,
    MotionRegulariser,
    holds_sizes,
    nearest_neighbours,
    regularisation,
)
from liquidgs.train.run import load_run
from tiny_runs import interrupt_at, run_train, tiny_flags


def _cloud(n: int = 300):
    g = torch.Generator().manual_seed(0)
    return torch.rand(n, 3, generator=g), torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1)


def test_a_rigid_motion_costs_nothing_and_a_stretch_does():
    means, quats = _cloud()
    sizes = torch.full_like(means, 0.01)
    reg = MotionRegulariser(MotionRegConfig(anchors=100), (0.5, 0.5, 0.0))
    turn = _half_angle_quaternion(torch.tensor([0.3, -0.2, 0.5]))
    turned = means @ quat_to_rotmat(turn[None])[0].T + torch.tensor([0.4, 0.1, -0.2])
    # Positions and Gaussians turned together: rigid, free.
    assert reg.loss(1, means, quats, turned, _quat_multiply(turn, quats), sizes) < 1e-5
    # Positions turned, the Gaussians not: the offsets do not turn with their Gaussians.
    assert reg.loss(2, means, quats, turned, quats, sizes) > 0.01
    stretched = (means * torch.tensor([1.3, 1.0, 1.0])).requires_grad_()
    loss = reg.loss(3, means, quats, stretched, quats, sizes)
    loss.backward()
    assert loss > 0.01 and stretched.grad.abs().sum() > 0


def test_neighbours_exclude_the_point_itself():
    points = torch.tensor([[0.0, 0, 0], [1.0, 0, 0], [3.0, 0, 0], [3.5, 0, 0]])
    assert nearest_neighbours(points, 1)[:, 0].tolist() == [1, 0, 3, 2]


def test_on_for_captures_off_for_dnerf_the_static_model_and_the_paper_specs():
    cfg = MotionRegConfig()
    assert regularisation(cfg, "nerfies", "hexplane") == (0.5, 0.5, 0.0)
    assert regularisation(cfg, "dnerf", "hexplane") is None and regularisation(cfg, "dnerf", "mlp") is None
    assert regularisation(cfg, "nerfies", "static") is None
    assert regularisation(MotionRegConfig(apply="off"), "nerfies", "hexplane") is None
    for name in ("paper-dnerf", "paper-dnerf-3seeds", "paper-nerfds", "paper-nerfds-3seeds", "noise-study", "seeds"):
        for grid in BUILTIN_SPECS[name].grids:
            overrides = grid.overrides
            switches = (overrides["motion.apply"], overrides["cameras.refine"], overrides["exposure.apply"])
            assert switches == ("off", "off", "off"), name


def test_the_weights_follow_the_field_unless_set():
    """A grid field (registered with local_deformation) is held rigid by default; one network over
    all of space is held still where the pictures do not pay for motion instead; both have their
    sizes held; a weight given is the weight used."""
    cfg = MotionRegConfig()
    for field in ("mlp", "cfc", "sde"):
        assert regularisation(cfg, "nerfies", field) == (0.0, 0.0, 0.1) and holds_sizes(cfg, "nerfies", field)
    assert regularisation(cfg, "nerfies", "hexplane") == (0.5, 0.5, 0.0)
    assert holds_sizes(cfg, "nerfies", "hexplane") and not holds_sizes(cfg, "dnerf", "hexplane")
    assert regularisation(MotionRegConfig(rigidity=0.2), "nerfies", "mlp") == (0.2, 0.0, 0.1)
    assert regularisation(MotionRegConfig(rigidity=0, isometry=0), "nerfies", "hexplane") is None
    assert regularisation(MotionRegConfig(stillness=0), "nerfies", "cfc") is None
    assert regularisation(MotionRegConfig(isometry=1.5, stillness=0.1), "nerfies", "hexplane") == (0.5, 1.5, 0.1)


def test_stillness_costs_how_far_each_gaussian_moves_in_scene_extents():
    """Nothing moved costs nothing; a shift costs its length over the scene extent; a turn costs the
    Gaussian's largest axis times the angle; the gradient pulls the shift back."""
    means, quats = _cloud()
    sizes = torch.full((len(means), 3), 0.01)
    sizes[:, 0] = 0.04
    reg = MotionRegulariser(MotionRegConfig(anchors=100), (0.0, 0.0, 2.0), scene_extent=4.0)
    assert reg.loss(1, means, quats, means.clone(), quats.clone(), sizes) < 1e-7
    shifted = (means + torch.tensor([0.3, 0.0, 0.4])).requires_grad_()
    loss = reg.loss(2, means, quats, shifted, quats, sizes)
    assert abs(loss.item() - 2.0 * 0.5 / 4.0) < 1e-5
    loss.backward()
    assert (shifted.grad @ torch.tensor([0.3, 0.0, 0.4]) >= 0).all() and shifted.grad.abs().sum() > 0
    angle = 0.2
    turn = _half_angle_quaternion(torch.tensor([0.0, 0.0, angle]))
    turned = _quat_multiply(turn.expand_as(quats), quats)
    # Either sign of a quaternion is the same rotation: -q costs what q does.
    for q in (turned, -turned):
        cost = reg.loss(3, means, quats, means.clone(), q, sizes).item()
        assert abs(cost - 2.0 * 0.04 * angle / 4.0) < 2e-3 * cost


def _moved(run_dir) -> float:
    """Mean distance the field moves a Gaussian, over the clip's times."""
    run = load_run(run_dir, "cpu")
    canonical = deform(run.params, None, 0.0).means
    return float(torch.stack([(run.at_time(t).means - canonical).norm(dim=-1) for t in (0.0, 0.5, 1.0)]).mean())


@pytest.mark.slow  # two trainings of 150 iterations
def test_the_stillness_term_holds_the_mlp_still_on_a_capture_where_nothing_moves(tmp_path):
    """The MLP's default on a capture: trained on the still scene, it moves its Gaussians a fraction of
    what it moves them without the term."""
    scene = generate_synthetic("still", tmp_path / "still", size=32, frames=16, seed=0)
    flags = ["--data", str(scene / "nerfies"), "--field", "mlp",
             *tiny_flags({"iterations": 150, "cameras.align_steps": 2})]  # fmt: skip
    run_train([*flags, "--out", str(tmp_path / "default")])
    run_train([*flags, "--out", str(tmp_path / "without"), "--motion.stillness", "0"])
    assert load_yaml(tmp_path / "default" / "config.yml").motion.weights("mlp") == (0.0, 0.0, GLOBAL_FIELD_STILLNESS)
    held, free = _moved(tmp_path / "default"), _moved(tmp_path / "without")
    assert free > 0 and held < 0.5 * free, (held, free)


@pytest.mark.slow
def test_a_run_made_before_the_stillness_term_resumes_without_it(tmp_path, monkeypatch):
    """Its config.yml's motion has no stillness: it resumes as trained, to the same Gaussians as a run
    without the term from the start."""
    scene = generate_synthetic("still", tmp_path / "still", size=24, frames=12, seed=1)
    flags = ["--data", str(scene / "nerfies"), "--field", "mlp", "--motion.stillness", "0",
             *tiny_flags({"iterations": 30, "cameras.align_steps": 2})]  # fmt: skip
    old = tmp_path / "old"
    interrupt_at(15, [*flags, "--out", str(old)], monkeypatch)
    stored = yaml.safe_load((old / "config.yml").read_text())
    del stored["motion"]["stillness"]
    (old / "config.yml").write_text(yaml.safe_dump(stored, sort_keys=False))
    assert load_yaml(old / "config.yml").motion.stillness == 0
    run_train(["--out", str(old), "--resume"])
    run_train([*flags, "--out", str(tmp_path / "whole")])
    a, b = (torch.load(tmp_path / name / "checkpoint.pt", weights_only=True)["params"] for name in ("whole", "old"))
    assert all(torch.equal(value, b[key]) for key, value in a.items())
