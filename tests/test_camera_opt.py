"""Camera refinement: the rigid correction, its gradients, pose recovery on a frozen scene, the
run-away bound, the settings' identity, and checkpoints (bit-exact resume, runs made before it)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import yaml

from liquidgs.cameras import Camera, camera_centre, look_at
from liquidgs.commands.train import resolve_config
from liquidgs.data import generate_synthetic
from liquidgs.data.perturb import rotation_about
from liquidgs.errors import LiquidGSError
from liquidgs.eval.poses import pose_errors, reprojection_error
from liquidgs.train.camera_opt import (
    Alignment,
    CameraRefineConfig,
    CameraRefinement,
    align_camera,
    corrected_viewmat,
    move_gaussians,
)
from liquidgs.train.config import config_hash, differing_settings, identity, load_yaml
from liquidgs.train.exposure import expose
from liquidgs.train.model import Deformed, render_frame
from shared_data import use_optional_lpips
from tiny_runs import interrupt_at, one_line_error, run_cli, run_train, tiny_flags

SIZE = 40


def _scene(n: int = 400, spread: float = 1.6, scale: float = 0.06) -> Deformed:
    """Frozen Gaussians: a cube of `spread` of small coloured Gaussians around the origin."""
    g = torch.Generator().manual_seed(0)
    means = (torch.rand(n, 3, generator=g) - 0.5) * spread
    return Deformed(
        means=means,
        quats=torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1),
        scales=torch.full((n, 3), scale),
        opacities=torch.full((n,), 0.9),
        colors=torch.rand(n, 1, 3, generator=g),
    )


def _camera(viewmat: torch.Tensor) -> Camera:
    return Camera.from_fov(viewmat, math.radians(50.0), SIZE, SIZE)


def _render(gaussians: Deformed, camera: Camera, backend: str = "auto") -> torch.Tensor:
    return render_frame(gaussians, camera, sh_degree=0, background=torch.zeros(3), backend=backend).rgb


TRUE_VIEW = look_at(torch.tensor([0.3, -0.4, 3.5]), torch.zeros(3), torch.tensor([0.0, -1.0, 0.0]))


def _moved(viewmat: torch.Tensor, degrees: float, shift: list[float], axis=(0.48, 0.6, 0.64)) -> torch.Tensor:
    """The camera turned about its centre by `degrees` around `axis` (unit) and its centre moved."""
    rotation = rotation_about(np.array(axis), math.radians(degrees))
    r = viewmat.double().numpy()[:3, :3] @ rotation.T
    centre = camera_centre(viewmat.double()).numpy() + np.array(shift)
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = r, -r @ centre
    return torch.from_numpy(out).float()


def _pose_error(a: torch.Tensor, b: torch.Tensor) -> tuple[float, float]:
    """Rotation angle (degrees) and centre distance between two world->camera matrices."""
    relative = a[:3, :3].double() @ b[:3, :3].double().T
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (float(torch.trace(relative)) - 1) / 2))))
    return angle, float((camera_centre(a.double()) - camera_centre(b.double())).norm())


def test_moving_the_gaussians_is_moving_the_camera():
    """Rendering M x with V is rendering x with D V (SH degree 0: no view-dependent colour)."""
    scene, camera = _scene(), _camera(TRUE_VIEW)
    omega, tau = torch.tensor([0.02, -0.03, 0.01]), torch.tensor([0.05, -0.02, 0.04])
    moved = _render(move_gaussians(scene, camera.viewmat, omega, tau), camera, "torch")
    direct = _render(scene, _camera(corrected_viewmat(camera.viewmat, omega, tau)), "torch")
    assert (moved - direct).abs().max() < 2e-4
    assert (moved - _render(scene, camera, "torch")).abs().max() > 0.05  # the correction did move the view


def test_a_zero_correction_is_the_camera_as_given_and_passes_gradients():
    scene, camera = _scene(), _camera(TRUE_VIEW)
    omega = torch.zeros(3, requires_grad=True)
    tau = torch.zeros(3, requires_grad=True)
    rgb = _render(move_gaussians(scene, camera.viewmat, omega, tau), camera)  # compiled CPU kernels where built
    assert torch.equal(rgb.detach(), _render(scene, camera))
    (rgb * torch.linspace(0, 1, SIZE)[None, :, None]).sum().backward()
    assert omega.grad.abs().sum() > 0 and tau.grad.abs().sum() > 0 and torch.isfinite(omega.grad).all()


def test_alignment_recovers_a_perturbed_camera_on_a_frozen_scene():
    """The pose-only optimisation of aligned evaluation (and of refinement, one camera at a time).
    The scene spans depth (points 1.5-5.5 from the camera), or a turn and a sideways move look
    alike and the pose is not determined by the image."""
    scene = _scene(n=1500, spread=4.0, scale=0.08)
    truth = _render(scene, _camera(TRUE_VIEW))
    noisy = _camera(_moved(TRUE_VIEW, 2.0, [0.04, -0.03, 0.02]))
    before = _pose_error(noisy.viewmat, TRUE_VIEW)
    omega, tau, gain, offset = align_camera(_render, scene, noisy, truth, steps=100, lr=5e-3, extent=1.0)
    after = _pose_error(corrected_viewmat(noisy.viewmat, omega, tau), TRUE_VIEW)
    assert before[0] > 1.9 and before[1] > 0.05
    assert after[0] < 0.25 * before[0] and after[1] < 0.25 * before[1], (before, after)
    assert not gain.any() and not offset.any()  # a run without exposure compensation: the render's colours as they are


def test_alignment_with_exposure_recovers_the_pose_and_a_changed_exposure_together():
    """A test view shot darker and bluer than the frozen scene (a phone's automatic exposure), from a
    moved camera: the aligned evaluation of a run that compensates exposure finds both."""
    scene = _scene(n=1500, spread=4.0, scale=0.08)
    true_gain, true_offset = torch.tensor([-0.15, -0.10, 0.05]), torch.tensor([0.02, 0.0, 0.03])
    truth = expose(_render(scene, _camera(TRUE_VIEW)), true_gain, true_offset)
    noisy = _camera(_moved(TRUE_VIEW, 2.0, [0.04, -0.03, 0.02]))
    before = _pose_error(noisy.viewmat, TRUE_VIEW)
    omega, tau, gain, offset = align_camera(_render, scene, noisy, truth, steps=150, lr=5e-3, extent=1.0,
                                            alignment=Alignment(pose=True, exposure=True))  # fmt: skip
    after = _pose_error(corrected_viewmat(noisy.viewmat, omega, tau), TRUE_VIEW)
    assert after[0] < 0.3 * before[0] and after[1] < 0.3 * before[1], (before, after)
    pose_only = align_camera(_render, scene, noisy, truth, steps=150, lr=5e-3, extent=1.0)
    aligned = [expose(_render(scene, _camera(corrected_viewmat(noisy.viewmat, o, t))), g, b)
               for o, t, g, b in ((omega, tau, gain, offset), pose_only)]  # fmt: skip
    errors = [float((image - truth).abs().mean()) for image in aligned]
    assert errors[0] < 0.5 * errors[1], errors  # the exposure, not fitted, stays in the error
    # (gain and offset trade off on a narrow range of colours: what must match is the colour shown)
    assert (aligned[0].mean((0, 1)) - truth.mean((0, 1))).abs().max() < 0.01
    assert (aligned[1].mean((0, 1)) - truth.mean((0, 1))).abs().max() > 0.02


def test_a_correction_past_its_bound_is_one_line_naming_the_frame():
    frames = [SimpleNamespace(name=name, camera=_camera(TRUE_VIEW)) for name in ("000001", "000002")]
    refinement = CameraRefinement(CameraRefineConfig(max_rotation_deg=5.0), frames, 2.0, 100, "cpu", 1e-15)
    refinement.check_bounds(1)
    with torch.no_grad():
        refinement.rotations[1] = torch.tensor([0.0, math.radians(6.0), 0.0])
    with pytest.raises(LiquidGSError, match="train frame '000002' turned 6.00 deg") as err:
        refinement.check_bounds(7)
    assert "\n" not in str(err.value) and "iteration 7" in str(err.value)


# ---------------------------------------------------------------------- runs
@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    """The built-in puppet in both layouts: nerfies/ is a capture, dnerf/ has exact cameras."""
    return generate_synthetic("puppet", tmp_path_factory.mktemp("capture") / "puppet", size=24, frames=16, seed=2)


@pytest.fixture(autouse=True)
def optional_lpips(monkeypatch):
    use_optional_lpips(monkeypatch)


def test_refinement_is_on_for_captures_only_and_off_leaves_the_identity_as_it_was(capture):
    nerfies, _ = resolve_config(["--data", str(capture / "nerfies"), "--preset", "tiny"])
    off, _ = resolve_config(["--data", str(capture / "nerfies"), "--preset", "tiny", "--cameras.refine", "off"])
    dnerf, _ = resolve_config(["--data", str(capture / "dnerf"), "--preset", "tiny"])
    assert identity(nerfies)["cameras"]["refine"] == "on"
    assert "cameras" not in identity(off) and "cameras" not in identity(dnerf)  # the identity of before
    assert {"cameras.refine", "cameras.rotation_lr"} <= set(differing_settings(nerfies, off))
    assert config_hash(nerfies) != config_hash(off)
    explicit, _ = resolve_config(["--data", str(capture / "nerfies"), "--preset", "tiny", "--cameras.refine", "on"])
    assert config_hash(explicit) == config_hash(nerfies)


REFINE_RUN = tiny_flags({"iterations": 30, "checkpoint_every": 10, "eval.start": 30, "cameras.align_steps": 5})


@pytest.mark.slow
def test_a_refining_run_resumes_bit_exactly_and_writes_its_corrections(capture, tmp_path, monkeypatch):
    flags = ["--data", str(capture / "nerfies"), "--field", "mlp", *REFINE_RUN]
    whole = run_train([*flags, "--out", str(tmp_path / "whole")])
    assert whole.final_aligned["n_views"] == whole.final["n_views"] and "aligned" in whole.final_aligned["cameras"]

    interrupt_at(15, [*flags, "--out", str(tmp_path / "cut")], monkeypatch)
    run_train([*flags, "--out", str(tmp_path / "cut"), "--resume"])

    a = torch.load(tmp_path / "whole" / "checkpoint.pt", weights_only=True)
    b = torch.load(tmp_path / "cut" / "checkpoint.pt", weights_only=True)
    assert a["cameras"]["rotations"].abs().max() > 0  # the corrections were learned
    for key in ("rotations", "translations"):
        assert torch.equal(a["cameras"][key], b["cameras"][key]), key
    for key, value in a["params"].items():
        assert torch.equal(value, b["params"][key]), key
    written = json.loads((tmp_path / "whole" / "cameras_refined.json").read_text())
    assert written["iteration"] == 30 and len(written["frames"]) == whole.views["train"]
    assert written["max_rotation_deg"] == max(f["rotation_deg"] for f in written["frames"]) > 0


@pytest.mark.slow  # 300 iterations
def test_a_run_on_noisy_poses_reports_how_far_refinement_brought_them_back(tmp_path, capsys):
    """What the stress tests' pose noise asks of refinement, inside training: on the still scene
    (nothing moves, so only the cameras can explain a view's misfit) the refined training cameras
    reproject the scene's points closer to where the true cameras do than those given did. Measured
    at 64 px, 48 frames, 600 iterations: 1.42 px -> 0.30 px (static model); here (48 px, 300
    iterations) 1.07 -> 0.31 px, while the rotation error falls only from 0.90 to 0.72 deg."""
    scene = generate_synthetic("still", tmp_path / "still", size=48, frames=48, seed=0)
    flags = ["--data", str(scene / "nerfies"), "--field", "static", "--out", str(tmp_path / "run"), *tiny_flags({
        "iterations": 300, "optim.means_lr_steps": 300, "densify.stop": 250, "densify.opacity_reset_interval": 150,
        "eval.start": 300, "checkpoint_every": 300, "cameras.align_steps": 5,
        "perturb.pose_rot_deg": 1.0, "perturb.pose_trans": 0.01,
    })]  # fmt: skip
    run_train(flags)
    recovery = json.loads((tmp_path / "run" / "cameras_refined.json").read_text())["pose_recovery"]
    before, after = recovery["before"], recovery["after"]
    assert before["aligned_rotation_deg"] > 0.5 and before["reprojection_px"] > 0.5
    assert after["reprojection_px"] < 0.6 * before["reprojection_px"], recovery
    printed = capsys.readouterr().err
    assert "test cameras aligned to the scene: PSNR" in printed
    assert (f"pose recovery: reprojection {before['reprojection_px']:.2f} -> {after['reprojection_px']:.2f} px, "
            f"rotation {before['aligned_rotation_deg']:.3f} -> {after['aligned_rotation_deg']:.3f} deg") in printed


def test_a_run_made_before_refinement_resumes_without_it(capture, tmp_path, monkeypatch, capsys):
    """Its config.yml has no `cameras` (nor `exposure`, which came later) and its checkpoint none: it
    continues as it was trained."""
    out = tmp_path / "old"
    flags = ["--data", str(capture / "nerfies"), "--field", "static", *REFINE_RUN, "--out", str(out)]
    interrupt_at(15, [*flags, "--cameras.refine", "off", "--exposure.apply", "off"], monkeypatch)
    stored = yaml.safe_load((out / "config.yml").read_text())
    del stored["cameras"], stored["exposure"]
    (out / "config.yml").write_text(yaml.safe_dump(stored, sort_keys=False))
    payload = torch.load(out / "checkpoint.pt", weights_only=True)
    del payload["cameras"], payload["exposure"], payload["sizes_held"]
    torch.save(payload, out / "checkpoint.pt")
    assert load_yaml(out / "config.yml").cameras.refine == "off"
    code, _, _ = run_cli(["train", "--out", str(out), "--resume"])
    assert code == 0 and not (out / "cameras_refined.json").exists()
    assert "final_aligned" not in json.loads((out / "results.json").read_text())
    # Turning refinement on for it is a changed setting, refused in one line.
    code, _, err = run_cli(["train", "--out", str(out), "--resume", "--iterations", "40", "--cameras.refine", "on"])
    assert code == 2 and "cameras.refine" in err


def test_a_refining_checkpoint_without_corrections_is_one_line(capture, tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    flags = ["--data", str(capture / "nerfies"), "--field", "static", *REFINE_RUN, "--out", str(out)]
    interrupt_at(15, flags, monkeypatch)
    payload = torch.load(out / "checkpoint.pt", weights_only=True)
    payload["cameras"] = None
    torch.save(payload, out / "checkpoint.pt")
    shutil.copy(out / "checkpoint.pt", tmp_path / "kept.pt")
    capsys.readouterr()
    from liquidgs.cli import main as cli

    assert cli(["train", "--out", str(out), "--resume"]) == 2
    assert "trained without camera refinement" in one_line_error(capsys)


# ---------------------------------------------------------------------- refinement recovers poses
def _ring(n: int) -> list[torch.Tensor]:
    """n cameras on an arc 3.5 from the origin, looking at it (a capture's layout)."""
    eyes = [torch.tensor([3.5 * math.sin(a), -0.5, 3.5 * math.cos(a)]) for a in torch.linspace(-0.6, 0.6, n)]
    return [look_at(eye, torch.zeros(3), torch.tensor([0.0, -1.0, 0.0])) for eye in eyes]


def test_pose_errors_see_through_the_gauge():
    """The same cameras in a moved, turned and scaled world: raw errors, no aligned error."""
    truth = torch.stack(_ring(6)).double()
    turn = torch.from_numpy(rotation_about(np.array([0.0, 0.6, 0.8]), math.radians(3.0)))
    world = torch.eye(4, dtype=torch.float64)  # x_world -> 1.1 turn x + shift, applied to every camera
    world[:3, :3], world[:3, 3] = 1.1 * turn, torch.tensor([0.2, 0.0, -0.1], dtype=torch.float64)
    moved = truth @ torch.linalg.inv(world)
    moved[:, :3, :] /= torch.linalg.norm(moved[:, :3, :3], dim=-1, keepdim=True)  # rotation rows unit again
    errors = pose_errors(moved, truth)
    assert errors["rotation_deg"] > 2.9 and errors["translation"] > 0.2
    assert errors["aligned_rotation_deg"] < 1e-3 and errors["aligned_translation"] < 1e-4
    assert abs(errors["gauge_scale"] - 1 / 1.1) < 1e-4 and abs(errors["gauge_rotation_deg"] - 3.0) < 1e-3


def test_reprojection_error_sees_what_the_images_see():
    """Cameras orbited by a degree about the object they look at (alternately left and right, so no
    gauge absorbs it) are a degree off in rotation, yet put the object nearly where the true ones do;
    turned by the same degree about their own centres they put it about f x 1 deg = 0.75 px off."""
    truth = torch.stack(_ring(6)).double()
    points = (torch.rand(500, 3, generator=torch.Generator().manual_seed(1)) - 0.5) * 0.5
    intrinsics = torch.stack([_camera(v.float()).K for v in truth])
    up = np.array([0.0, 1.0, 0.0])
    orbited, turned = [], []
    for i, view in enumerate(truth):
        sign = 1.0 if i % 2 else -1.0
        orbit = torch.eye(4, dtype=torch.float64)
        orbit[:3, :3] = torch.from_numpy(rotation_about(up, math.radians(sign)))
        orbited.append(view @ orbit.T)  # the world turned the other way about the origin: the camera orbits it
        turned.append(_moved(view.float(), sign, [0.0, 0.0, 0.0], axis=tuple(view[1, :3].tolist())).double())
    orbit_errors, turn_errors = pose_errors(torch.stack(orbited), truth), pose_errors(torch.stack(turned), truth)
    assert orbit_errors["aligned_rotation_deg"] > 0.5 and turn_errors["aligned_rotation_deg"] > 0.5
    # Measured 0.21 px against 0.75 (the centres' gauge fit shrinks the alternating orbit by 1.3%).
    orbit_pixels = reprojection_error(torch.stack(orbited), truth, intrinsics, points)
    turn_pixels = reprojection_error(torch.stack(turned), truth, intrinsics, points)
    assert orbit_pixels < 0.3 and turn_pixels > 0.6 and turn_pixels > 3 * orbit_pixels
    # The same cameras in a moved, turned and scaled world reproject exactly.
    world = torch.eye(4, dtype=torch.float64)
    world[:3, :3] = 1.2 * torch.from_numpy(rotation_about(np.array([0.0, 0.6, 0.8]), math.radians(4.0)))
    world[:3, 3] = torch.tensor([0.3, -0.1, 0.2], dtype=torch.float64)
    moved = truth @ torch.linalg.inv(world)
    moved[:, :3, :] /= torch.linalg.norm(moved[:, :3, :3], dim=-1, keepdim=True)
    assert reprojection_error(moved, truth, intrinsics, points) < 1e-6


def test_refinement_recovers_perturbed_poses_on_a_frozen_scene():
    """What a user checks: from poses off by about a degree and 1-2% of the cameras' extent, the
    refinement's defaults (its Adam, learning rates and schedule), given the updates per camera a
    quick look gives (20), turn the cameras back: measured 1.08 -> 0.60 deg gauge-aligned (lr 1e-2:
    0.28). The shift (0.030) barely moves at the default learning rate (0.024), so it is only held
    to not growing."""
    scene = _scene(n=1500, spread=4.0, scale=0.08)
    truth = _ring(6)
    images = [_render(scene, _camera(v)) for v in truth]
    rng = np.random.default_rng(3)
    axes = rng.normal(size=(len(truth), 3))
    noisy = [_moved(v, 1.2, list(rng.normal(0.0, 0.03, 3)), a / np.linalg.norm(a)) for v, a in zip(truth, axes)]
    frames = [SimpleNamespace(name=f"{i:06d}", camera=_camera(v)) for i, v in enumerate(noisy)]
    steps = 20 * len(frames)
    refinement = CameraRefinement(CameraRefineConfig(), frames, 3.5, steps, "cpu", 1e-15)
    for step in range(steps):
        index = step % len(frames)
        rgb = _render(refinement.correct(scene, index, frames[index].camera, step), frames[index].camera)
        (rgb - images[index]).abs().mean().backward()
        refinement.step(step)
    refined = torch.stack([
        corrected_viewmat(v, refinement.rotations[i].detach(), refinement.translations[i].detach())
        for i, v in enumerate(noisy)
    ])  # fmt: skip
    before, after = pose_errors(torch.stack(noisy), torch.stack(truth)), pose_errors(refined, torch.stack(truth))
    assert before["aligned_rotation_deg"] > 1.0 and before["aligned_translation"] > 0.025, before
    assert after["aligned_rotation_deg"] < 0.7 * before["aligned_rotation_deg"], (before, after)
    assert after["aligned_translation"] < before["aligned_translation"], (before, after)
