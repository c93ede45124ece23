"""The D-3DGS training loop with a pluggable deformation field.

Order of one iteration, as in the reference: learning rates, SH degree, one camera from a
reshuffled stack, deform (zero deltas during warm-up), rasterise, 0.8 L1 + 0.2 D-SSIM,
backward, densification statistics / densify / prune / opacity reset, Adam steps.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import resource
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from liquidgs.data import SceneDataset, load_dataset, spread_extent
from liquidgs.data.flow import flow_folder, image_scale, read_flow_pairs
from liquidgs.data.scene import MIN_CAMERA_EXTENT
from liquidgs.errors import ConfigError, LiquidGSError
from liquidgs.eval import LPIPS, LPIPSUnavailable, evaluate_views, ssim
from liquidgs.eval.collapse import BACKGROUND_MARGIN_DB, LEARNED_MARGIN_DB, background_psnr, collapse_reason
from liquidgs.eval.metrics import MIN_MSE, psnr_from_mse
from liquidgs.fields import build_field
from liquidgs.gaussians import PARAM_KEYS, init_from_points, init_random_box
from liquidgs.train.camera_opt import CameraRefinement, aligned_render, refines
from liquidgs.train.config import TrainConfig, motion_evidence_note, save_yaml, with_motion_evidence
from liquidgs.train.dataset import load_run_dataset
from liquidgs.train.dynamic_split import (
    DYNAMIC,
    MotionVotes,
    Seen,
    moving_indices,
    split_applies,
    surface_depth,
    where_they_stand,
)
from liquidgs.train.exposure import ExposureCompensation, compensates
from liquidgs.train.flow_loss import FlowLoss
from liquidgs.train.model import deform, hold_sizes, render_frame
from liquidgs.train.motion_reg import MotionRegulariser, holds_sizes, regularisation, surface_move
from liquidgs.train.phases import NoClock, PhaseClock
from liquidgs.train.run import resolve_device
from liquidgs.train.run_folder import (
    CAMERAS_REFINED,
    CHECKPOINT,
    CONFIG,
    EXPOSURE,
    FAILURE,
    PER_VIEW,
    TENSORBOARD,
    RunResults,
    read_checkpoint,
    write_checkpoint,
    write_failure,
    write_per_view,
    write_results,
)
from liquidgs.train.schedules import log_linear_lr, smooth_time_noise_scale
from liquidgs.train.strategy import D3DGSStrategy

# The PSNR guard checks from this iteration on, each time once this many steps have entered the
# smoothed PSNR since it last started over (one step's PSNR depends on the camera drawn).
GUARD_START = 100
GUARD_SETTLE = 20
# After a scheduled disturbance the guard gives training this many iterations to recover: meanwhile
# it measures the smoothed PSNR against its best since the disturbance, then against the run's best.
GUARD_GRACE = 100
# A densification step that adds or removes this fraction of the Gaussians is a burst.
DENSIFY_BURST_FRACTION = 0.25


def _smooth(average: float | None, value: float) -> float:
    """The guard's exponential moving average (None: starting over)."""
    return value if average is None else 0.95 * average + 0.05 * value


class TrainingDiverged(LiquidGSError):
    pass


class RunCollapsed(TrainingDiverged):
    """The renders collapsed (eval.collapse): the run is failed, never recorded as finished."""


class FieldGroupsChanged(LiquidGSError):
    """A checkpoint's field optimizer groups the parameters otherwise than the field now does."""


def make_lpips(cfg: TrainConfig, device: torch.device) -> tuple[LPIPS | None, str | None]:
    """The LPIPS metric, or None and the reason it is unavailable (reported, never skipped silently)."""
    try:
        return LPIPS(
            backbone=cfg.eval.lpips_backbone,
            normalize=cfg.eval.lpips_normalize,
            weights=cfg.eval.lpips_weights,
            device=device,
        ), None
    except LPIPSUnavailable as err:
        return None, str(err)


@dataclass
class TrainState:
    """Everything a checkpoint holds beyond the tensors, so a resumed run continues bit-exactly."""

    iteration: int = 0
    sh_degree: int = 0
    camera_stack: list[int] = field(default_factory=list)
    psnr_ema: float | None = None
    best_psnr_ema: float = -math.inf
    background_psnr_ema: float | None = None
    """The same smoothing of each step's background-only image's PSNR (eval.collapse)."""
    best_margin: float = -math.inf
    """Best psnr_ema - background_psnr_ema: how far training once was above an empty render."""
    guard_samples: int = 0
    """Steps in psnr_ema since the guard last started over (at a scheduled disturbance)."""
    grace_until: int = 0
    """Last iteration of the recovery window after the latest scheduled disturbance."""
    grace_best: float = -math.inf
    """Best psnr_ema inside that window."""
    grace_since: str = ""
    """That disturbance, for the guard's message: 'the opacity reset at iteration 600'."""
    train_seconds: float = 0.0
    evaluations: list[dict] = field(default_factory=list)


def _say(progress, line: str) -> None:
    """A line above the progress bar (or among the plain progress lines), where there is one."""
    if progress is not None:
        progress.console.print(line, highlight=False)


class Trainer:
    def __init__(self, cfg: TrainConfig, run_dir: Path, dataset: SceneDataset | None = None):
        given, cfg = cfg, with_motion_evidence(cfg)  # decided once, at the start, and recorded so in config.yml
        self.cfg = cfg
        self.run_dir = Path(run_dir)
        self.device = resolve_device(cfg.device)
        if cfg.backend == "gsplat" and self.device.type != "cuda":
            raise ConfigError("--backend gsplat needs a CUDA device (gsplat has no CPU path); use auto or torch")
        clean = dataset if dataset is not None else load_dataset(cfg.data)  # `dataset`, when given, is the clean scene
        self.dataset = load_run_dataset(cfg, clean)
        if not self.dataset.train:
            raise LiquidGSError(f"{cfg.data.path}: the training split is empty")
        self.background = torch.tensor(self.dataset.background, dtype=torch.float32, device=self.device)
        torch.manual_seed(cfg.seed)
        self.camera_rng = np.random.default_rng(cfg.seed)
        self.params = self._initial_gaussians().to(self.device)
        self.field = build_field(cfg.field_config()).to(self.device)
        self.sizes_held = holds_sizes(cfg.motion, self.dataset.format, cfg.field)
        if self.sizes_held:
            hold_sizes(self.field)
        self.field.begin_training(self.params["means"].detach())  # its set-up hook; checks its outputs
        self.optimizers = {key: self._adam([self.params[key]], self._static_lr(key)) for key in PARAM_KEYS}
        self.field_optimizer = self._field_adam()
        self.notes: list[str] = [note for note in [motion_evidence_note(given, cfg)] if note]
        """Things the user should know about this run (printed by the train command)."""
        self.strategy = D3DGSStrategy(cfg.densify, self._scene_extent())
        self.strategy_state = self.strategy.initial_state(self.params["means"].shape[0], self.device)
        self.cameras = (  # camera refinement: a correction per training camera, or None
            CameraRefinement(cfg.cameras, self.dataset.train, self.strategy.scene_extent, cfg.iterations,
                             self.device, cfg.optim.adam_eps, self._true_cameras(clean), self.dataset.points)
            if refines(cfg.cameras, self.dataset.format) else None
        )  # fmt: skip
        self.split = self._motion_votes()
        """The motion masks that label each Gaussian static or dynamic, or None (the run does not split)."""
        if self.split is not None:
            self.strategy_state[DYNAMIC] = self.split.held(where_they_stand(self.params["means"].detach()))
        weights = regularisation(cfg.motion, self.dataset.format, cfg.field)
        if weights is not None and self.split is not None:  # static Gaussians are held still exactly
            weights = weights[:2] + (0.0,) if any(weights[:2]) else None
        # Rigidity / isometry over neighbours and stillness on the deformation, or None (every weight 0).
        self.motion = (
            MotionRegulariser(cfg.motion, weights, self.strategy.scene_extent) if weights is not None else None
        )
        self.exposure = (  # a colour correction per training frame, or None
            ExposureCompensation(cfg.exposure, self.dataset.train, cfg.iterations, self.device, cfg.optim.adam_eps)
            if compensates(cfg.exposure, self.dataset.format) else None
        )  # fmt: skip
        self.flow_loss = self._flow_loss()
        self.alignment = cfg.alignment(self.dataset.format)
        """How test views are aligned for the second score (None: the run has only the first)."""
        self.state = TrainState()
        self.checkpoint_iteration: int | None = None
        """Iteration of the checkpoint on disk, once this trainer has written or read one."""
        self.lpips, self.lpips_error = make_lpips(cfg, self.device)
        self._writer = None
        self._resumed_from: int | None = None
        self.clock: PhaseClock | NoClock = NoClock()
        """Times the phases of each training step when set to a PhaseClock (bench train)."""

    # ----------------------------------------------------------------- set-up
    def _true_cameras(self, clean: SceneDataset) -> list | None:
        """The training frames' cameras before the pose perturbation made them noisy (None without one)."""
        if not self.cfg.perturb.moves_cameras:
            return None
        by_name = {frame.name: frame.camera for frame in clean.train}
        return [by_name[frame.name] for frame in self.dataset.train]

    def _motion_votes(self) -> MotionVotes | None:
        """The train frames' motion masks when the run splits its Gaussians (split.apply), else None."""
        if not split_applies(self.cfg.split, self.cfg.field):
            return None
        if self.dataset.format != "nerfies":
            raise ConfigError(
                f"split.apply: static and dynamic Gaussians are decided from a capture's motion masks; "
                f"{self.cfg.data.path} is D-NeRF"
            )
        return MotionVotes(self.cfg.split, self.cfg.data.path, self.dataset.train, self.strategy.scene_extent,
                           self.device)  # fmt: skip

    def flow_scales(self) -> tuple[str, ...]:
        """The flow/<k>x folders of the scene this run trains from (its scene print holds them)."""
        if self.flow_loss is None and self.split is None:
            return ()
        return (flow_folder(self.cfg.data.path, image_scale(self.cfg.data.path, self.dataset.train)).name,)

    def moving(self) -> torch.Tensor | None:
        """Indices of the Gaussians the field moves (None: all of them)."""
        return None if self.split is None else moving_indices(self.strategy_state[DYNAMIC])

    def _flow_loss(self) -> FlowLoss | None:
        """The optical-flow loss over the scene's flow at the training scale, or None (weight 0)."""
        if not self.cfg.flow.weight:
            return None
        if self.dataset.format != "nerfies":
            raise ConfigError(
                f"flow.weight: the optical-flow loss needs a capture with flow; {self.cfg.data.path} is D-NeRF"
            )
        # At the scale of the images trained on: flow.json's hashes tie it to those very files.
        scale = image_scale(self.cfg.data.path, self.dataset.train)
        pairs = read_flow_pairs(self.cfg.data.path, scale, tracks=bool(self.cfg.flow.tracks))
        if self.cfg.flow.tracks and not any(pair.track for pair in pairs):
            raise ConfigError(
                f"flow.tracks: the flow of {self.cfg.data.path} at {scale}x holds no tracks (computed before "
                f"them); compute it again: liquidgs data flow {self.cfg.data.path} --downscale {scale}"
            )
        names = [frame.name for frame in self.dataset.train]
        return FlowLoss(self.cfg.flow.weight, pairs, names, self.device)

    def _initial_gaussians(self) -> torch.nn.ParameterDict:
        cfg, ds = self.cfg, self.dataset
        if ds.points is not None:
            return init_from_points(ds.points, ds.point_colors, sh_degree=cfg.sh_degree)
        return init_random_box(cfg.init_points, cfg.init_extent, sh_degree=cfg.sh_degree, seed=cfg.seed)

    def _scene_extent(self) -> float:
        """The camera extent, or, when the cameras sit at one position, the initial points' extent."""
        extent = self.dataset.camera_extent
        if not self.dataset.camera_extent_degenerate:
            return extent
        fallback = spread_extent(self.params["means"].detach())
        if fallback < MIN_CAMERA_EXTENT:
            raise LiquidGSError(
                f"{self.cfg.data.path}: the train cameras and the initial points each sit at one position; "
                "there is no scene extent to densify by"
            )
        self.notes.append(
            f"camera extent is {extent:.4f} (the {len(self.dataset.train)} train camera(s) sit at one position); "
            f"densification uses {fallback:.4f}, 1.1 x the largest distance of an initial point from their mean"
        )
        return fallback

    def _adam(self, params: list[torch.nn.Parameter] | list[dict], lr: float) -> torch.optim.Adam:
        # fused: one kernel per step instead of about ten small ops (the same update rule).
        return torch.optim.Adam(params, lr=lr, eps=self.cfg.optim.adam_eps, fused=True)

    def _field_adam(self) -> torch.optim.Adam | None:
        """Adam over the field's parameter groups (its param_groups hook), each at the field learning
        rate times its scale, kept in the group as "lr_scale"; None for a field without parameters."""
        groups = self.field.checked_param_groups()
        if not any(params for _, params, _ in groups):
            return None
        lr = self.cfg.optim.field_lr_init
        adam_groups = [dict(params=params, lr=lr * scale, name=name, lr_scale=scale) for name, params, scale in groups]
        return self._adam(adam_groups, lr)

    def _static_lr(self, key: str) -> float:
        o = self.cfg.optim
        return {
            "means": o.means_lr_init * o.spatial_lr_scale,
            "scales": o.scales_lr,
            "quats": o.quats_lr,
            "opacities": o.opacities_lr,
            "sh0": o.sh0_lr,
            "shN": o.shN_lr,
        }[key]

    def _update_learning_rates(self, step: int) -> None:
        o = self.cfg.optim
        means_lr = log_linear_lr(
            step,
            o.means_lr_init * o.spatial_lr_scale,
            o.means_lr_final * o.spatial_lr_scale,
            o.means_lr_steps,
        )
        for group in self.optimizers["means"].param_groups:
            group["lr"] = means_lr
        if self.field_optimizer is not None:
            field_lr = log_linear_lr(step, o.field_lr_init, o.field_lr_final, o.field_lr_steps)
            for group in self.field_optimizer.param_groups:
                group["lr"] = field_lr * group["lr_scale"]

    @property
    def writer(self):
        if self._writer is None:
            from torch.utils.tensorboard import SummaryWriter

            # A resumed run replays the steps after its checkpoint: purge_step hides the first
            # attempt's events from those steps, so TensorBoard shows each step once.
            purge_step = self._resumed_from + 1 if self._resumed_from else None
            self._writer = SummaryWriter(str(self.run_dir / TENSORBOARD), purge_step=purge_step)
        return self._writer

    # ----------------------------------------------------------------- the loop
    def next_camera(self) -> int:
        if not self.state.camera_stack:
            self.state.camera_stack = list(range(len(self.dataset.train)))
        return self.state.camera_stack.pop(int(self.camera_rng.integers(0, len(self.state.camera_stack))))

    def field_active(self, step: int) -> bool:
        return self.cfg.field != "static" and step >= self.cfg.warmup

    def time_noise(self, step: int) -> float:
        cfg = self.cfg
        if not (cfg.smooth_time and self.field_active(step)):
            return 0.0
        frames = len(self.dataset.train) if cfg.smooth_time_scale == "frames" else len(self.state.camera_stack) + 1
        scale = smooth_time_noise_scale(step, cfg.smooth_time_steps) / frames
        return float(torch.randn(()).item()) * scale

    def train_step(self, step: int) -> dict:
        cfg = self.cfg
        clock = self.clock
        clock.start()
        self._update_learning_rates(step)
        sh_degree = self.state.sh_degree
        if step % cfg.sh_interval == 0:
            self.state.sh_degree = min(self.state.sh_degree + 1, cfg.sh_degree)
        sh_raised = self.state.sh_degree > sh_degree
        index = self.next_camera()
        frame = self.dataset.train[index]
        gt = frame.image().to(self.device)
        use_field = self.field_active(step)
        self.field.train()
        self.field.set_progress(step)
        clock.mark("data")
        n_before = self.params["means"].shape[0]
        if self.split is not None and self.split.decides_afresh(step, cfg.warmup):
            self._relabel(self.split.held(self._seen_by(step, moved=False)))  # the warm-up's scene
        moving = self.moving()
        gaussians = deform(self.params, self.field if use_field else None, frame.time, self.time_noise(step), moving)
        if not all(torch.isfinite(t).all() for t in (gaussians.means, gaussians.quats, gaussians.scales)):
            raise self._diverged(f"non-finite Gaussians at iteration {step}")
        deformed = gaussians
        if self.cameras is not None:
            gaussians = self.cameras.correct(gaussians, index, frame.camera, step)
        flow = self._flow_draw(gaussians, index, frame, use_field, step, moving) if self.flow_loss is not None else None
        clock.mark("field_forward")
        out = self._render(
            gaussians, frame, absgrad=cfg.densify.gradient == "absolute", features=None if flow is None else flow.motion
        )
        clock.mark("raster_forward")
        rgb = out.rgb if self.exposure is None else self.exposure.correct(out.rgb, index)
        l1 = (rgb - gt).abs().mean()
        loss = (1.0 - cfg.ssim_weight) * l1 + cfg.ssim_weight * (1.0 - ssim(rgb, gt))
        regulariser = self.field.regulariser_loss() if use_field else None  # the field's own term
        if regulariser is not None:
            loss = loss + regulariser
        if self.motion is not None and use_field:
            loss = loss + self._motion_term(step, deformed, moving)
        if flow is not None and (flow_term := self.flow_loss.loss(out, flow)) is not None:
            loss = loss + flow_term
        if not torch.isfinite(loss):
            raise self._diverged(f"non-finite loss at iteration {step}")
        clock.mark("loss_forward")
        clock.watch_backward(out.rgb, (gaussians.means, gaussians.quats, gaussians.scales, gaussians.colors))
        loss.backward()
        clock.end_backward()
        report = self.strategy.step_post_backward(self.params, self.optimizers, self.strategy_state, step, out.info)
        clock.mark("densification")
        if report["pruned_all"]:
            raise self._diverged(
                f"densification would have pruned every Gaussian at iteration {step} (opacity below "
                f"{cfg.densify.prune_opacity}, or too large for the scene extent {self.strategy.scene_extent:.4g})"
            )
        for optimizer in self.optimizers.values():
            optimizer.step()
            optimizer.zero_grad(set_to_none=True)
        if self.field_optimizer is not None:
            if use_field:
                self.field_optimizer.step()
            self.field_optimizer.zero_grad(set_to_none=True)
        if self.cameras is not None:
            self.cameras.step(step)
        if self.exposure is not None:
            self.exposure.step(step)
        if self.split is not None and use_field and self.split.redecides(step, cfg.warmup, cfg.densify.stop):
            self._redecide_labels(step)
        clock.mark("optimizer_step")
        with torch.no_grad():
            mse = ((rgb.detach().clamp(0, 1) - gt) ** 2).mean()
            train_psnr = float(psnr_from_mse(mse.clamp_min(MIN_MSE)))
            empty_psnr = background_psnr(gt, self.background)
        self._guard_divergence(step, train_psnr, empty_psnr)
        disturbance = self._scheduled_disturbance(step, sh_raised, n_before, report)
        if disturbance:
            self._start_grace(step, disturbance)
        clock.mark("other")
        return {
            "loss": float(loss.detach()),
            "psnr": train_psnr,
            "n_gaussians": self.params["means"].shape[0],
            **report,
        }

    def _motion_term(self, step: int, deformed, moving: torch.Tensor | None):
        """The motion regularisers, over the dynamic Gaussians alone in a split run."""
        p = self.params
        if moving is None:
            return self.motion.loss(step, p["means"], p["quats"], deformed.means, deformed.quats, deformed.scales)
        if moving.numel() < 2:  # no neighbours to hold together
            return 0.0
        return self.motion.loss(step, p["means"][moving], p["quats"][moving], deformed.means[moving],
                                deformed.quats[moving], deformed.scales[moving])  # fmt: skip

    @torch.no_grad()
    def _redecide_labels(self, step: int) -> None:
        """The split's labels decided again (train.dynamic_split)."""
        self._relabel(self.split.redecide(self._seen_by(step), self.strategy_state[DYNAMIC], self._largest_move))

    def _relabel(self, new: torch.Tensor) -> None:
        """New labels for the split; the neighbour terms then look anew."""
        if not torch.equal(new, self.strategy_state[DYNAMIC]):
            self.strategy_state[DYNAMIC] = new
            if self.motion is not None:
                self.motion.forget_neighbours()

    def _seen_by(self, step: int, moved: bool = True) -> Callable[[int], Seen]:
        """What each train frame shows of the Gaussians at `step`, for the split's vote: with the
        occlusion test, the Gaussians at the frame's time (moved by the field, without its training
        noise, where `moved`) as its corrected camera sees them and the depth they render; without
        it, the centres where they stand."""
        if self.cfg.split.occlusion is None:
            return where_they_stand(self.params["means"].detach())
        field = self.field if moved and self.field_active(step) else None
        moving = self.moving()

        @torch.no_grad()
        def seen(index: int) -> Seen:
            frame = self.dataset.train[index]
            with self._field_evaluating():
                gaussians = deform(self.params, field, frame.time, moving=moving)
            if self.cameras is not None:
                gaussians = self.cameras.seen_by(gaussians, index, frame.camera, step)
            out = render_frame(gaussians, frame.camera, sh_degree=0, background=self.background,
                               backend=self.cfg.backend)  # fmt: skip
            return gaussians.means, surface_depth(out.depth[..., 0], out.alpha[..., 0])

        return seen

    def _largest_move(self, indices: torch.Tensor) -> torch.Tensor:
        """How far the field moves each Gaussian of `indices` (its surface, scene units), the most over
        the split's sample of train times; measured without the field's training noise."""
        p = self.params
        sizes = torch.exp(p["scales"][indices])
        largest = sizes.new_zeros(indices.shape[0])
        with self._field_evaluating():
            for time in self.split.sample_times():
                g = deform(p, self.field, time, moving=indices)
                moved = surface_move(p["means"][indices], p["quats"][indices], g.means[indices], g.quats[indices],
                                     sizes)  # fmt: skip
                largest = torch.maximum(largest, moved)
        return largest

    @contextlib.contextmanager
    def _field_evaluating(self) -> Iterator[None]:
        """The field in evaluation mode (no training noise) for the block, then training again."""
        self.field.eval()
        try:
            yield
        finally:
            self.field.train()

    def _flow_draw(self, gaussians, index: int, frame, use_field: bool, step: int, moving: torch.Tensor | None):
        """The Gaussians' screen motion from this step's frame to one of its neighbours, rendered with
        the frame's colour for the optical-flow loss (None where the frame has no flow)."""
        target = self.flow_loss.target(index, self.camera_rng)
        if target is None:
            return None
        other = self.dataset.train[target.neighbour]
        later = deform(self.params, self.field if use_field else None, other.time, moving=moving)
        if self.cameras is not None:
            later = self.cameras.correct(later, target.neighbour, other.camera, step)
        return self.flow_loss.draw(gaussians, frame.camera, later, other.camera, target)

    def _scheduled_disturbance(self, step: int, sh_raised: bool, n_before: int, report: dict) -> str | None:
        """The recipe's own step that may drop the training PSNR by design, if this step was one."""
        if report["reset"]:
            return "opacity reset"  # every opacity set to 0.01: the image fades, then recovers
        if sh_raised:
            return "SH degree step"
        if self.cfg.field != "static" and step == self.cfg.warmup:
            return "end of warm-up"  # the field's deltas switch on
        if abs(self.params["means"].shape[0] - n_before) >= DENSIFY_BURST_FRACTION * n_before:
            return "densification burst"
        return None

    def _start_grace(self, step: int, disturbance: str) -> None:
        """A drop the schedule caused is not a divergence: for GUARD_GRACE iterations the smoothed
        PSNR starts over and is held against its best since the disturbance (a collapse after a
        partial recovery still stops the run); after them, training must be back within reach of
        the run's best, or it did not recover and stops then."""
        s = self.state
        s.psnr_ema, s.background_psnr_ema, s.guard_samples = None, None, 0
        s.grace_until, s.grace_best = step + GUARD_GRACE, -math.inf
        s.grace_since = f"the {disturbance} at iteration {step}"

    def _guard_divergence(self, step: int, train_psnr: float, empty_psnr: float) -> None:
        """Stop a run whose smoothed training PSNR collapsed: by divergence_drop_db below its best
        (since the latest scheduled disturbance), or, outside the recovery windows, back to no
        better than the background alone (`empty_psnr`, this view's) after it had been better."""
        s = self.state
        s.psnr_ema = _smooth(s.psnr_ema, train_psnr)
        s.background_psnr_ema = _smooth(s.background_psnr_ema, empty_psnr)
        s.guard_samples += 1
        if s.guard_samples < GUARD_SETTLE:
            return
        s.best_psnr_ema = max(s.best_psnr_ema, s.psnr_ema)
        margin = s.psnr_ema - s.background_psnr_ema
        s.best_margin = max(s.best_margin, margin)
        if step <= s.grace_until:
            s.grace_best = max(s.grace_best, s.psnr_ema)
            best, since = s.grace_best, f" since {s.grace_since}"
        else:
            best, since = s.best_psnr_ema, ""
        if step >= GUARD_START and s.psnr_ema < best - self.cfg.divergence_drop_db:
            raise self._diverged(
                f"training PSNR collapsed at iteration {step} ({s.psnr_ema:.1f} dB, best {best:.1f} dB{since})",
                " - try a lower field learning rate",
            )
        learned = s.best_margin >= LEARNED_MARGIN_DB
        if step >= GUARD_START and step > s.grace_until and learned and margin < BACKGROUND_MARGIN_DB:
            raise self._diverged(
                f"training renders collapsed to no better than the background alone at iteration {step} "
                f"({s.psnr_ema:.1f} dB, background-only {s.background_psnr_ema:.1f} dB, "
                f"best {s.best_margin:.1f} dB above it)",
                " - try a lower field learning rate",
                collapsed=True,
            )

    def _diverged(self, what: str, advice: str = "", collapsed: bool = False) -> TrainingDiverged:
        kind = RunCollapsed if collapsed else TrainingDiverged
        if self.checkpoint_iteration is None:
            return kind(f"{what}; no checkpoint was written yet in {self.run_dir}{advice}")
        kept = f"the last good checkpoint in {self.run_dir} is kept (iteration {self.checkpoint_iteration})"
        return kind(f"{what}; {kept}{advice}")

    def is_eval_step(self, step: int) -> bool:
        e = self.cfg.eval
        periodic = step >= e.start and (step - e.start) % e.every == 0
        return step == self.cfg.iterations or periodic or step in e.also

    def run(self, progress=None) -> RunResults:
        """Train from self.state.iteration to cfg.iterations; returns what results.json records."""
        try:
            return self._run(progress)
        except TrainingDiverged as err:  # the run folder says why it stopped (a resume may retry)
            write_failure(self.run_dir, self.checkpoint_iteration, str(err))
            raise
        finally:  # flush the TensorBoard events of a stopped run too
            if self._writer is not None:
                self._writer.close()

    def _run(self, progress) -> RunResults:
        cfg = self.cfg
        save_yaml(cfg, self.run_dir / CONFIG)
        task = (
            progress.add_task(
                "train",
                total=cfg.iterations,
                completed=self.state.iteration,
                loss=float("nan"),
                psnr=float("nan"),
                gaussians=self.params["means"].shape[0],
            )
            if progress
            else None
        )
        while self.state.iteration < cfg.iterations:
            step = self.state.iteration + 1
            started = time.perf_counter()
            stats = self.train_step(step)
            self.state.train_seconds += time.perf_counter() - started
            self.state.iteration = step
            if step % 10 == 0 or step == 1:
                for key in ("loss", "psnr", "n_gaussians"):
                    self.writer.add_scalar(f"train/{key}", stats[key], step)
            if progress is not None:
                progress.update(
                    task,
                    completed=step,
                    loss=stats["loss"],
                    psnr=stats["psnr"],
                    gaussians=stats["n_gaussians"],
                )
            if step == cfg.iterations:
                self.save_checkpoint()  # before finish() evaluates: a failing evaluation loses no training
                _say(progress, f"training done; the final evaluation of {len(self.dataset.test)} test views starts")
                break
            if self.is_eval_step(step):
                _say(progress, f"evaluation at iteration {step} ({len(self.dataset.test)} test views)")
                self.evaluate_and_record(step)
            if step % cfg.checkpoint_every == 0:
                self.save_checkpoint()
        return self.finish()

    # ----------------------------------------------------------------- evaluation
    def _render(self, gaussians, frame, absgrad: bool = False, features=None):
        return render_frame(
            gaussians, frame.camera,
            sh_degree=self.state.sh_degree, background=self.background, backend=self.cfg.backend, absgrad=absgrad,
            features=features,
        )  # fmt: skip

    def render_fn(self, frame):
        field = self.field if self.cfg.field != "static" else None
        gaussians = deform(self.params, field, frame.time, moving=self.moving())
        if not all(torch.isfinite(t).all() for t in (gaussians.means, gaussians.quats, gaussians.scales)):
            mode = "training" if self.field.training else "evaluation"
            raise self._diverged(
                f"field '{self.cfg.field}' gives non-finite Gaussians in {mode} mode at iteration "
                f"{self.state.iteration} (view {frame.name})"
            )
        return self._render(gaussians, frame).rgb

    @torch.no_grad()
    def evaluate(self) -> tuple[dict, list[dict]]:
        with self._field_evaluating():
            return evaluate_views(
                self.render_fn,
                self.dataset.test,
                lpips=self.lpips,
                lpips_error=self.lpips_error,
                quantize=self.cfg.eval.quantize_8bit,
                background=self.background,
            )

    def evaluate_aligned(self) -> dict:
        """The test split scored with each test view aligned to the frozen scene (its pose, its exposure,
        as self.alignment says): the second, labelled score of a run that refines either."""
        render = aligned_render(
            lambda time: deform(self.params, self.field if self.cfg.field != "static" else None, time,
                                moving=self.moving()),
            lambda gaussians, camera: render_frame(gaussians, camera, sh_degree=self.state.sh_degree,
                                                   background=self.background, backend=self.cfg.backend).rgb,
            self.cfg.cameras, self.dataset.camera_extent, self.cfg.ssim_weight, self.alignment,
        )  # fmt: skip
        with self._field_evaluating():
            summary, _ = evaluate_views(render, self.dataset.test, lpips=self.lpips, lpips_error=self.lpips_error,
                                        quantize=self.cfg.eval.quantize_8bit)  # fmt: skip
        return {"iteration": self.cfg.iterations, **summary, "cameras": self.alignment.protocol(self.cfg.cameras)}

    def evaluate_and_record(self, step: int) -> None:
        summary, per_view = self.evaluate()
        record = {"iteration": step, **summary}
        self.state.evaluations.append(record)
        for key in ("psnr", "ssim", "lpips"):
            if isinstance(summary.get(key), (int, float)):
                self.writer.add_scalar(f"test/{key}", summary[key], step)
        if step == self.cfg.iterations:
            self._final_per_view = per_view

    @torch.no_grad()
    def measure_fps(self) -> float:
        """Field + rasteriser per frame, device-synchronised, first 5 frames dropped, no I/O."""
        self.field.eval()
        frames = self.dataset.test or self.dataset.train
        n, warm = self.cfg.eval.fps_frames, 5
        sync = torch.cuda.synchronize if self.device.type == "cuda" else (lambda: None)
        started = 0.0
        for i in range(n + warm):
            if i == warm:
                sync()
                started = time.perf_counter()
            self.render_fn(frames[i % len(frames)])
        sync()
        return n / max(time.perf_counter() - started, 1e-9)

    def finish(self) -> RunResults:
        cfg = self.cfg
        evaluations = self.state.evaluations
        if not any(e["iteration"] == cfg.iterations for e in evaluations):
            # A resume that ends the run at its checkpoint's iteration, which was no evaluation step.
            self.evaluate_and_record(cfg.iterations)
        final = next(e for e in reversed(evaluations) if e["iteration"] == cfg.iterations)
        self._check_collapse(final)
        best = max(evaluations, key=lambda e: e["psnr"])
        per_view = getattr(self, "_final_per_view", None)
        if per_view is None:  # resumed after the final evaluation but before results.json
            _, per_view = self.evaluate()
        if self.device.type == "cuda":
            peak_mb, peak_kind = torch.cuda.max_memory_allocated() / 2**20, "cuda_max_memory_allocated"
        else:
            peak_mb, peak_kind = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "process_peak_rss"
        results = RunResults(
            scene=self.dataset.scene_name,
            data=str(cfg.data.path),
            field=cfg.field,
            preset=cfg.preset,
            lambda_=cfg.resolved_lambda(),
            seed=cfg.seed,
            iterations=cfg.iterations,
            final=final,
            best_of={
                **best,
                "note": "best test PSNR over the evaluations during training (test-set model selection, "
                "as the D-3DGS reference reports); use 'final' for an unbiased number",
            },
            evaluated_at=[e["iteration"] for e in evaluations],
            fps=self.measure_fps(),
            num_gaussians=int(self.params["means"].shape[0]),
            field_parameters=int(self.field.num_parameters()),
            field_flops_per_gaussian=int(self.field.flops_per_gaussian()),
            train_seconds=round(self.state.train_seconds, 3),
            peak_memory_mb=round(peak_mb, 1),
            peak_memory_kind=peak_kind,
            device=str(self.device),
            backend=cfg.backend,
            torch=torch.__version__,
            lpips_backbone=cfg.eval.lpips_backbone,
            lpips_normalize=cfg.eval.lpips_normalize,
            resolution=[self.dataset.train[0].camera.width, self.dataset.train[0].camera.height],
            perturb=cfg.perturb.settings(),
            views={"train": len(self.dataset.train), "test": len(self.dataset.test)},
            final_aligned=self.evaluate_aligned() if self.alignment is not None else {},
            threads=torch.get_num_threads(),
            dynamic_gaussians=None if self.split is None else int(self.strategy_state[DYNAMIC].sum()),
        )
        write_per_view(self.run_dir / PER_VIEW, cfg.iterations, per_view)
        (self.run_dir / FAILURE).unlink(missing_ok=True)  # of an earlier attempt this resume got past
        write_results(self.run_dir, results)
        return results

    def _check_collapse(self, final: dict) -> None:
        """A final evaluation whose renders collapsed is a failed run, not a result."""
        if "background_psnr" not in final:  # recorded by a liquidgs from before the check
            return
        margins = [e["psnr"] - e["background_psnr"] for e in self.state.evaluations if "background_psnr" in e]
        learned = max([self.state.best_margin, *margins]) >= LEARNED_MARGIN_DB
        reason = collapse_reason(final, learned)
        if reason is not None:
            raise RunCollapsed(
                f"the run collapsed: {reason} at iteration {final['iteration']}; not recorded as finished, "
                f"its checkpoint in {self.run_dir} is kept - try a lower field learning rate"
            )

    # ----------------------------------------------------------------- checkpoints
    def save_checkpoint(self) -> Path:
        if not all(torch.isfinite(p).all() for p in self.params.values()):
            raise self._diverged(f"non-finite Gaussian parameters at iteration {self.state.iteration}")
        contents = {
            "params": {k: v.detach().cpu() for k, v in self.params.items()},
            "optimizers": {k: o.state_dict() for k, o in self.optimizers.items()},
            "field": self.field.state_dict(),
            "field_optimizer": self.field_optimizer.state_dict() if self.field_optimizer else None,
            "strategy": {k: v.cpu() for k, v in self.strategy_state.items()},
            "state": dataclasses.asdict(self.state),
            "torch_rng": torch.get_rng_state(),
            "camera_rng": self.camera_rng.bit_generator.state,
            "cameras": self.cameras.state_dict() if self.cameras is not None else None,
            "motion": self.motion.state_dict() if self.motion is not None else None,
            "exposure": self.exposure.state_dict() if self.exposure is not None else None,
            "sizes_held": self.sizes_held,
        }
        path = write_checkpoint(self.run_dir, contents)
        if self.cameras is not None:
            self.cameras.write(self.run_dir / CAMERAS_REFINED, self.state.iteration)
        if self.exposure is not None:
            self.exposure.write(self.run_dir / EXPOSURE, self.state.iteration)
        self.checkpoint_iteration = self.state.iteration
        return path

    def load_checkpoint(self, path: Path | None = None) -> None:
        path = path or self.run_dir / CHECKPOINT
        payload = read_checkpoint(path)
        try:
            self._restore(payload)
            if self.cameras is not None:  # a checkpoint made before refinement existed holds no "cameras"
                self.cameras.load_state_dict(payload.get("cameras"), path)
            if self.motion is not None:
                self.motion.load_state_dict(payload.get("motion"))
            if self.exposure is not None:  # likewise "exposure"
                self.exposure.load_state_dict(payload.get("exposure"), path)
        except FieldGroupsChanged as err:
            raise LiquidGSError(f"{path}: {err}") from None
        except (KeyError, TypeError, ValueError, RuntimeError) as err:  # weights of another config
            raise LiquidGSError(f"{path}: checkpoint does not fit {CONFIG} ({type(err).__name__})") from None
        self.checkpoint_iteration = self._resumed_from = self.state.iteration

    def _restore(self, payload: dict) -> None:
        params = payload["params"]
        self.params = torch.nn.ParameterDict({k: torch.nn.Parameter(params[k].to(self.device)) for k in PARAM_KEYS})
        for key in PARAM_KEYS:
            optimizer = self._adam([self.params[key]], self._static_lr(key))
            optimizer.load_state_dict(payload["optimizers"][key])
            self.optimizers[key] = optimizer
        self.field.load_state_dict(payload["field"])
        if self.field_optimizer is not None and payload["field_optimizer"] is not None:
            self._load_field_optimizer(payload["field_optimizer"])
        self.strategy_state = {k: v.to(self.device) for k, v in payload["strategy"].items()}
        self.state = TrainState(**payload["state"])
        torch.set_rng_state(payload["torch_rng"])
        self.camera_rng.bit_generator.state = payload["camera_rng"]

    def _load_field_optimizer(self, saved: dict) -> None:
        """The field's Adam state from a checkpoint. The groups' names and scales stay the field's:
        a checkpoint made before fields had groups holds one group without them."""
        groups = self.field_optimizer.param_groups
        if len(saved["param_groups"]) != len(groups):
            raise FieldGroupsChanged(
                f"the checkpoint trains field '{self.field.name}' in {len(saved['param_groups'])} parameter "
                f"group(s), this code in {len(groups)} ({', '.join(g['name'] for g in groups)}): it was made by "
                "another version of the field; train the run again in a new folder"
            )
        own = [(g["name"], g["lr_scale"]) for g in groups]
        self.field_optimizer.load_state_dict(saved)
        for group, (name, scale) in zip(self.field_optimizer.param_groups, own):
            group.update(name=name, lr_scale=scale)
