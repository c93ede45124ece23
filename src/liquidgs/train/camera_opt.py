"""Camera refinement: a learned rigid correction per training camera, and the alignment of a test
view to a frozen scene, its pose and (for a run that compensates exposure) its exposure: the second
way a refined model is scored.

A correction (omega, tau) acts in the camera's own axes: the corrected world->camera matrix is
D @ V with D = [exp(omega) | tau], so omega rotates the camera about its centre (|omega| is the
angle) and tau moves it (|tau| in world units). It starts at zero, the camera as given.

How it reaches the renderer: rendering the Gaussians x with D @ V is rendering M x with V, where
M = V^-1 D V is a rigid map of the world. The Gaussians of the view are moved by M (means and
rotations; M is a rotation, so sizes stay) and rendered with the camera as given. The gradient
then reaches the correction through the means and rotations, which every backend
differentiates, and the compiled CPU projection kernel keeps its fast path (it has no gradient
for a view matrix: a camera that needs one falls back to the slower torch projection). The one
difference from moving the camera: spherical-harmonic colours are evaluated along directions
rotated by M's rotation, an error of the correction's angle (at most a few degrees) in the
view-dependent part of the colour only.

Choices learned from gsplat's simple_trainer (pose_opt: a zero-initialised per-camera embedding
in its own Adam) and nerfstudio's camera optimizer (SO(3) x R^3 on the left of the pose, an
exponentially decaying learning rate); the parametrisation and code are this project's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch

from liquidgs.cameras import Camera
from liquidgs.data.loading import check_capture_switch, detect_format, for_captures
from liquidgs.data.scene import DataConfig
from liquidgs.errors import ConfigError, DataError, LiquidGSError, check_integer, check_number
from liquidgs.eval.metrics import ssim
from liquidgs.eval.poses import pose_recovery
from liquidgs.train.exposure import expose
from liquidgs.train.frame_corrections import FrameCorrections
from liquidgs.train.model import Deformed
from liquidgs.train.schedules import log_linear_lr


@dataclass
class CameraRefineConfig:
    """Camera refinement (per training camera) and the alignment of test views (align_steps, align_lr)."""

    refine: Literal["auto", "on", "off"] = "auto"
    """Learn a rotation and translation correction for each training camera. auto: on for captures
    (the Nerfies layout: Nerfies, HyperNeRF, NeRF-DS, `data video`, `data images`), off for D-NeRF.
    A config.yml made before refinement existed has none, and trains without it (off)."""
    start: int = 0
    """First iteration that updates the corrections."""
    rotation_lr: float = 1e-3
    """Adam learning rate of the rotation (radians), decaying log-linearly to rotation_lr_final."""
    rotation_lr_final: float = 1e-5
    """The rotation correction's learning rate at the end of training."""
    translation_lr: float = 1e-3
    """Adam learning rate of the translation, in units of the train cameras' extent."""
    translation_lr_final: float = 1e-5
    """The translation correction's learning rate at the end of training."""
    lr_steps: int | None = None
    """Iterations of the decay (None: the run's)."""
    max_rotation_deg: float = 10.0
    """A correction past this angle ran away: training stops naming the frame."""
    max_translation: float = 0.2
    """A correction moving a camera further than this x the train cameras' extent ran away."""
    align_steps: int = 100
    """Aligned evaluation: Adam steps per test camera on the frozen scene."""
    align_lr: float = 5e-3
    """Aligned evaluation: learning rate of rotation (radians) and translation (x extent), decaying
    log-linearly to 1/100 of it over the steps."""

    def __post_init__(self) -> None:
        check_capture_switch("cameras.refine", self.refine)
        for name in ("start", "align_steps"):
            check_integer(f"cameras.{name.replace('_', '-')}", getattr(self, name), 0)
        steps = self.lr_steps
        if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
            raise ConfigError(f"cameras.lr-steps must be an integer >= 1 or null, got {steps!r}")
        for name in ("rotation_lr", "rotation_lr_final", "translation_lr", "translation_lr_final", "align_lr",
                     "max_rotation_deg", "max_translation"):  # fmt: skip
            check_number(f"cameras.{name.replace('_', '-')}", getattr(self, name), positive=True)


def refines(cfg: CameraRefineConfig, data_format: str | None) -> bool:
    """Whether a run on data of this format refines its cameras (None: the format is unknown)."""
    return for_captures(cfg.refine, data_format)


def known_format(data: DataConfig) -> str | None:
    """The scene's format as the run will read it, or None where its folder cannot say (yet)."""
    if data.format != "auto":
        return data.format
    try:
        return detect_format(data.path)
    except DataError:
        return None


# ---------------------------------------------------------------------- rigid maps
def _half_angle_quaternion(omega: torch.Tensor) -> torch.Tensor:
    """The unit wxyz quaternion [..., 4] of the rotation vector omega [..., 3] (smooth at zero)."""
    theta = torch.sqrt((omega * omega).sum(-1, keepdim=True) + 1e-24)  # no 0/0 in the gradient at zero
    half = 0.5 * theta
    return torch.cat([torch.cos(half), omega * (torch.sin(half) / theta)], dim=-1)


def _quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of wxyz quaternions (broadcasting)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], dim=-1)  # fmt: skip


def _quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(*q.shape[:-1], 3, 3)  # fmt: skip


def corrected_viewmat(viewmat: torch.Tensor, omega: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
    """D @ V: the camera after the correction (omega, tau) in its own axes."""
    correction = torch.eye(4, dtype=viewmat.dtype, device=viewmat.device)
    correction[:3, :3] = _quat_to_matrix(_half_angle_quaternion(omega.to(viewmat.dtype)))
    correction[:3, 3] = tau.to(viewmat.dtype)
    return correction @ viewmat


def move_gaussians(gaussians: Deformed, viewmat: torch.Tensor, omega: torch.Tensor, tau: torch.Tensor) -> Deformed:
    """The Gaussians moved by M = V^-1 D V, so that rendering them with V shows the scene from D V."""
    rotation, translation = viewmat[:3, :3].to(omega.dtype), viewmat[:3, 3].to(omega.dtype)
    q_world = _half_angle_quaternion(rotation.T @ omega)  # M's rotation: D's about R^T omega
    r_world = _quat_to_matrix(q_world)
    r_correction = _quat_to_matrix(_half_angle_quaternion(omega))
    # M x = R^T (R_D (R x + t) + tau - t) = r_world x + R^T ((R_D - I) t + tau)
    shift = rotation.T @ ((r_correction - torch.eye(3, dtype=omega.dtype, device=omega.device)) @ translation + tau)
    return Deformed(
        means=gaussians.means @ r_world.T + shift,
        quats=_quat_multiply(q_world, gaussians.quats),
        scales=gaussians.scales,
        opacities=gaussians.opacities,
        colors=gaussians.colors,
    )


def rotation_deg(omega: torch.Tensor) -> torch.Tensor:
    return torch.rad2deg(omega.norm(dim=-1))


# ---------------------------------------------------------------------- training
class CameraRefinement(FrameCorrections):
    """The corrections of a run's training cameras, their Adam and their schedule."""

    KEYS = ("rotations", "translations")
    WHAT, VERB, OFF_FLAG = "camera refinement", "refines", "--cameras.refine off"

    def __init__(
        self,
        cfg: CameraRefineConfig,
        frames: list,
        extent: float,
        iterations: int,
        device,
        adam_eps: float,
        true_cameras: list[Camera] | None = None,
        points: torch.Tensor | None = None,
    ):
        """`true_cameras`: where the frames' cameras really are, when the run made them noisy on purpose
        (the pose perturbation): the report then says how far refinement brought them back, measured
        with the scene's `points` too when it has them."""
        super().__init__(frames, device)
        self.cfg = cfg
        self.given = torch.stack([frame.camera.viewmat for frame in frames]).cpu()
        self.intrinsics = torch.stack([frame.camera.K for frame in frames]).cpu()
        self.truth = None if true_cameras is None else torch.stack([camera.viewmat for camera in true_cameras]).cpu()
        self.points = points
        self.extent = extent
        self.lr_steps = cfg.lr_steps or iterations
        self.optimizer = torch.optim.Adam(
            [dict(params=[self.rotations], name="rotation"), dict(params=[self.translations], name="translation")],
            lr=cfg.rotation_lr, eps=adam_eps,
        )  # fmt: skip
        self._updated = False

    def active(self, step: int) -> bool:
        return step >= self.cfg.start

    def correct(self, gaussians: Deformed, index: int, camera: Camera, step: int) -> Deformed:
        """The Gaussians as train camera `index`, corrected, sees them (as given before `start`), for a
        training step: the corrections used are stepped after it."""
        if self.active(step):
            self._updated = True
        return self.seen_by(gaussians, index, camera, step)

    def seen_by(self, gaussians: Deformed, index: int, camera: Camera, step: int) -> Deformed:
        """As `correct`, outside a training step (nothing is stepped for it)."""
        if not self.active(step):
            return gaussians
        return move_gaussians(gaussians, camera.viewmat.to(self.rotations.device),
                              self.rotations[index], self.translations[index])  # fmt: skip

    def step(self, step: int) -> None:
        """Adam on the corrections used this step, then the run-away check."""
        if not self._updated:
            return
        self._updated = False
        c = self.cfg
        rotation, translation = self.optimizer.param_groups
        rotation["lr"] = log_linear_lr(step, c.rotation_lr, c.rotation_lr_final, self.lr_steps)
        translation["lr"] = self.extent * log_linear_lr(step, c.translation_lr, c.translation_lr_final, self.lr_steps)
        self.optimizer.step()
        self.optimizer.zero_grad(set_to_none=True)
        self.check_bounds(step)

    def check_bounds(self, step: int) -> None:
        with torch.no_grad():
            degrees = rotation_deg(self.rotations)
            moved = self.translations.norm(dim=-1) / self.extent
        for i in range(len(self.names)):
            if not (degrees[i] <= self.cfg.max_rotation_deg and moved[i] <= self.cfg.max_translation):
                raise LiquidGSError(
                    f"camera refinement ran away at iteration {step}: train frame '{self.names[i]}' turned "
                    f"{float(degrees[i]):.2f} deg (bound {self.cfg.max_rotation_deg:g}) and moved "
                    f"{float(moved[i]):.3f} x the camera extent (bound {self.cfg.max_translation:g}); its pose "
                    "is likely wrong: drop the frame, or train with --cameras.refine off"
                )

    def refined_viewmats(self) -> torch.Tensor:
        """The training cameras' world->camera matrices [N, 4, 4] with their corrections."""
        with torch.no_grad():
            rotations, translations = self.rotations.detach().cpu(), self.translations.detach().cpu()
            return torch.stack([corrected_viewmat(v, rotations[i], translations[i]) for i, v in enumerate(self.given)])

    def report(self, iteration: int) -> dict:
        """cameras_refined.json: how far each training camera moved, readable by a user."""
        with torch.no_grad():
            degrees = rotation_deg(self.rotations).cpu()
            translations = self.translations.detach().cpu()
        frames = [
            {
                "name": name,
                "rotation_deg": round(float(degrees[i]), 4),
                "translation": round(float(translations[i].norm()), 6),
                "rotation_vector_rad": [round(float(v), 6) for v in self.rotations[i].detach().cpu()],
                "translation_vector": [round(float(v), 6) for v in translations[i]],
            }
            for i, name in enumerate(self.names)
        ]
        recovery = {}
        if self.truth is not None:
            recovery = {"pose_recovery": {
                "about": "the training cameras were made noisy on purpose (perturb.pose-*): mean error against the "
                "true cameras of those trained from (before) and of the refined ones (after): rotation (degrees) and "
                "centre (world units), raw and after the similarity that best maps them onto the true ones (the "
                "world's placement is free), and reprojection_px, how far the scene's points land (pixels) from "
                "where the true cameras put them after that similarity",
                **pose_recovery(self.given, self.refined_viewmats(), self.truth, self.intrinsics, self.points),
            }}  # fmt: skip
        return {
            "iteration": iteration,
            "about": "per training frame, the learned correction D of its world->camera matrix V (the camera "
            "trained is D @ V), in the camera's own axes (x right, y down, z forward): a rotation about the "
            "camera centre by rotation_deg degrees (rotation_vector_rad: axis x angle) and a move of the "
            "centre by translation (world units; translation_vector in camera axes)",
            "camera_extent": self.extent,
            "max_rotation_deg": max((f["rotation_deg"] for f in frames), default=0.0),
            "max_translation": max((f["translation"] for f in frames), default=0.0),
            **recovery,
            "frames": frames,
        }


# ---------------------------------------------------------------------- aligned evaluation
@dataclass(frozen=True)
class Alignment:
    """What a test view is fitted by before it is scored: its pose, its exposure, or both."""

    pose: bool = True
    exposure: bool = False

    def protocol(self, cfg: CameraRefineConfig) -> str:
        fitted = " and ".join(
            what for what, on in (("a rotation and translation correction", self.pose),
                                  ("a per-channel gain and offset of the render (its exposure)", self.exposure)) if on
        )  # fmt: skip
        rates = []
        if self.pose:
            rates.append(
                f"rotation lr {cfg.align_lr:g} rad, translation lr {cfg.align_lr:g} x the train cameras' extent"
            )
        if self.exposure:
            rates.append(f"gain and offset lr {cfg.align_lr:g}")
        return (
            f"each test view aligned to the frozen scene: {cfg.align_steps} Adam steps on {fitted} "
            f"({', '.join(rates)}, decaying log-linearly to 1/100), training loss"
        )


POSE_ONLY = Alignment()


def align_camera(
    render,
    gaussians: Deformed,
    camera: Camera,
    truth: torch.Tensor,
    *,
    steps: int,
    lr: float,
    extent: float,
    ssim_weight: float = 0.2,
    alignment: Alignment = POSE_ONLY,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The correction (omega, tau, gain, offset) that aligns `camera` to frozen Gaussians: `steps` Adam
    steps on what `alignment` fits, minimising the training loss ((1 - w) L1 + w D-SSIM) of
    render(gaussians, camera) against `truth`. Rotation at `lr` radians, translation at `lr` x extent,
    gain and offset at `lr`, all decaying log-linearly to lr / 100. The aligned view is
    expose(render(move_gaussians(gaussians, V, omega, tau), camera), gain, offset); what is not
    fitted stays zero."""
    device = gaussians.means.device
    frozen = Deformed(*(t.detach() for t in (gaussians.means, gaussians.quats, gaussians.scales,
                                             gaussians.opacities, gaussians.colors)))  # fmt: skip
    omega, tau, gain, offset = (torch.zeros(3, device=device, requires_grad=True) for _ in range(4))
    groups = ([(omega, 1.0), (tau, extent)] if alignment.pose else []) + (
        [(gain, 1.0), (offset, 1.0)] if alignment.exposure else []
    )
    if not groups:
        return omega.detach(), tau.detach(), gain.detach(), offset.detach()
    optimizer = torch.optim.Adam([dict(params=[p], scale=scale) for p, scale in groups], lr=lr)
    viewmat = camera.viewmat.to(device)
    with torch.enable_grad():
        for step in range(steps):
            rate = log_linear_lr(step, lr, lr / 100, max(steps - 1, 1))
            for group in optimizer.param_groups:
                group["lr"] = rate * group["scale"]
            rgb = expose(render(move_gaussians(frozen, viewmat, omega, tau), camera), gain, offset)
            loss = (1.0 - ssim_weight) * (rgb - truth).abs().mean() + ssim_weight * (1.0 - ssim(rgb, truth))
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
    return omega.detach(), tau.detach(), gain.detach(), offset.detach()


def aligned_render(deformed_at, render, cfg: CameraRefineConfig, extent: float, ssim_weight: float,
                   alignment: Alignment = POSE_ONLY):  # fmt: skip
    """A render function for evaluate_views that scores a view aligned to the frozen scene (its pose,
    its exposure, as `alignment` says): deformed_at(time) gives the Gaussians, render(gaussians,
    camera) the image."""

    def render_aligned(frame):
        gaussians = deformed_at(frame.time)
        truth = frame.image().to(gaussians.means.device)
        omega, tau, gain, offset = align_camera(render, gaussians, frame.camera, truth, steps=cfg.align_steps,
                                                lr=cfg.align_lr, extent=extent, ssim_weight=ssim_weight,
                                                alignment=alignment)  # fmt: skip
        viewmat = frame.camera.viewmat.to(gaussians.means.device)
        return expose(render(move_gaussians(gaussians, viewmat, omega, tau), frame.camera), gain, offset)

    return render_aligned
