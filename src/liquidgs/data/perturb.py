"""Perturbed supervision for stress tests: corrupt or thin out the training split, keep test views clean.

Each perturbation draws from its own random stream keyed by (seed, perturbation), so a run's
corruption is reproducible from its seed, and switching one perturbation on leaves the draws
of another unchanged. Test frames are never altered; only time_split chooses which of them
are scored.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import torch

from liquidgs.cameras import Camera, camera_centre
from liquidgs.data.scene import Frame, SceneDataset
from liquidgs.errors import ConfigError, check_number

# Random stream of each perturbation (the second word of its numpy seed).
_STREAMS = {"time_jitter": 1, "pose_rot_deg": 2, "pose_trans": 3, "image_noise": 4, "exposure": 5}


@dataclass
class PerturbConfig:
    """Corruptions of the training split (all off by default)."""

    time_jitter: float = 0.0
    """Standard deviation of Gaussian noise added to each training timestamp (then clipped to [0, 1])."""
    pose_rot_deg: float = 0.0
    """Rotate each training camera about its centre by a random angle ~ N(0, R^2) degrees (so R is the
    RMS angle) around a uniformly random axis."""
    pose_trans: float = 0.0
    """Shift each training camera centre by a random vector of RMS length T x the clean train cameras'
    extent (isotropic Gaussian)."""
    keep_frames: int | None = None
    """Train on this many frames, evenly spaced in time order (None: all)."""
    time_split: float | None = None
    """Extrapolation in time: train on the training frames with t < T0 and score the test split's
    frames with t >= T0 (None: off)."""
    image_noise: float = 0.0
    """Standard deviation of additive Gaussian noise on training pixel values in [0, 1], clipped to
    [0, 1] and rounded to 8 bits like a stored photo; fixed per frame."""
    exposure: float = 0.0
    """Exposure flicker: each training frame's pixel values multiplied by a per-channel gain 1 + N(0, E^2)
    (a camera's automatic exposure and white balance), clipped to [0, 1] and rounded to 8 bits; fixed per frame."""

    @property
    def active(self) -> bool:
        return self != PerturbConfig()

    @property
    def moves_cameras(self) -> bool:
        """Whether the training cameras are made noisy (their true poses are then known to the run)."""
        return self.pose_rot_deg > 0 or self.pose_trans > 0

    def settings(self) -> dict:
        """The perturbations switched on, by name."""
        default = PerturbConfig()
        return {k: v for k, v in dataclasses.asdict(self).items() if v != getattr(default, k)}

    def __post_init__(self) -> None:  # checked when built, as every config
        for name in ("time_jitter", "pose_rot_deg", "pose_trans", "image_noise", "exposure"):
            check_number(f"perturb.{name.replace('_', '-')}", getattr(self, name))
        keep = self.keep_frames
        if keep is not None and (isinstance(keep, bool) or not isinstance(keep, int) or keep < 1):
            raise ConfigError(f"perturb.keep-frames must be an integer >= 1 (omit it to keep all), got {keep!r}")
        split = self.time_split
        is_number = isinstance(split, (int, float)) and not isinstance(split, bool)
        if split is not None and not (is_number and 0 < split < 1):
            raise ConfigError(f"perturb.time-split must be a number in (0, 1), got {split!r}")


@dataclass(eq=False)
class NoisyFrame(Frame):
    """A training frame whose pixels carry a fixed per-channel gain and additive noise (the same on
    every read)."""

    noise_std: float = 0.0
    noise_seed: tuple[int, ...] = ()
    gain: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def image_uint8(self) -> np.ndarray:
        clean = super().image_uint8().astype(np.float64) / 255.0
        noise = np.random.default_rng(self.noise_seed).normal(0.0, self.noise_std, clean.shape)
        gain = np.ones(clean.shape[-1])
        gain[:3] = self.gain  # an alpha channel keeps its values
        noisy = np.rint(np.clip(clean * gain + noise, 0.0, 1.0) * 255.0).astype(np.uint8)
        noisy.flags.writeable = False
        return noisy


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues: the rotation by `angle` radians about the unit vector `axis`."""
    x, y, z = axis
    cross = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * cross + (1.0 - math.cos(angle)) * cross @ cross


def _rng(seed: int, name: str) -> np.random.Generator:
    return np.random.default_rng([seed, _STREAMS[name]])


def _unit_vectors(rng: np.random.Generator, count: int) -> np.ndarray:
    vectors = rng.normal(size=(count, 3))
    return vectors / np.linalg.norm(vectors, axis=1, keepdims=True)


def _moved_camera(camera: Camera, rotation: np.ndarray, shift: np.ndarray) -> Camera:
    """The camera rotated by `rotation` (in world axes, about its centre) and its centre moved by `shift`."""
    r = camera.viewmat.double().numpy()[:3, :3]
    centre = camera_centre(camera.viewmat.double()).numpy() + shift
    r_new = r @ rotation.T  # camera-to-world rotation R^T becomes rotation @ R^T
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = r_new, -r_new @ centre
    return dataclasses.replace(camera, viewmat=torch.from_numpy(out).to(camera.viewmat.dtype))


def _select(train: list[Frame], test: list[Frame], cfg: PerturbConfig) -> tuple[list[Frame], list[Frame]]:
    if cfg.time_split is not None:
        t0 = cfg.time_split
        train = [f for f in train if f.time < t0]
        test = [f for f in test if f.time >= t0]
        if not train or not test:
            empty = "training frame has t <" if not train else "test frame has t >="
            raise ConfigError(f"perturb.time-split {t0:g}: no {empty} {t0:g}")
    if cfg.keep_frames is not None:
        if cfg.keep_frames > len(train):
            raise ConfigError(f"perturb.keep-frames {cfg.keep_frames}: only {len(train)} training frames to keep")
        by_time = sorted(range(len(train)), key=lambda i: train[i].time)
        picks = np.rint(np.linspace(0, len(train) - 1, cfg.keep_frames)).astype(int)
        train = [train[i] for i in sorted(by_time[p] for p in picks)]
    return train, test


def perturb_dataset(dataset: SceneDataset, cfg: PerturbConfig, seed: int) -> SceneDataset:
    """The dataset with its training split perturbed as `cfg` says (itself when nothing is on)."""
    if not cfg.active:
        return dataset
    train, test = _select(dataset.train, dataset.test, cfg)
    n = len(train)
    times = np.array([f.time for f in train])
    if cfg.time_jitter > 0:
        times = np.clip(times + _rng(seed, "time_jitter").normal(0.0, cfg.time_jitter, n), 0.0, 1.0)
    rotations = [np.eye(3)] * n
    if cfg.pose_rot_deg > 0:
        rng = _rng(seed, "pose_rot_deg")
        axes, angles = _unit_vectors(rng, n), np.radians(rng.normal(0.0, cfg.pose_rot_deg, n))
        rotations = [rotation_about(a, float(angle)) for a, angle in zip(axes, angles)]
    shifts = np.zeros((n, 3))
    if cfg.pose_trans > 0:
        # Per-axis std T*extent/sqrt(3): the shift's RMS length is T x the clean extent.
        scale = cfg.pose_trans * dataset.camera_extent / math.sqrt(3.0)
        shifts = _rng(seed, "pose_trans").normal(0.0, scale, (n, 3))
    moved = cfg.pose_rot_deg > 0 or cfg.pose_trans > 0
    gains = np.ones((n, 3))
    if cfg.exposure > 0:
        gains = np.clip(1.0 + _rng(seed, "exposure").normal(0.0, cfg.exposure, (n, 3)), 0.0, None)
    frames = []
    for i, frame in enumerate(train):
        values = {f.name: getattr(frame, f.name) for f in dataclasses.fields(Frame)}
        values["time"] = float(times[i])
        if moved:
            values["camera"] = _moved_camera(frame.camera, rotations[i], shifts[i])
        if cfg.image_noise > 0 or cfg.exposure > 0:
            noise_seed = (seed, _STREAMS["image_noise"], i)
            frames.append(NoisyFrame(**values, noise_std=cfg.image_noise, noise_seed=noise_seed,
                                     gain=tuple(float(g) for g in gains[i])))  # fmt: skip
        else:
            frames.append(Frame(**values))
    splits = {**dataset.splits, "train": frames, "test": test}
    return dataclasses.replace(dataset, splits=splits, warnings=list(dataset.warnings))
