"""HexPlane: the 4DGaussians deformation field (Wu et al., CVPR 2024), written from its description
and the public code (github.com/hustvl/4DGaussians: scene/hexplane.py, scene/deformation.py,
gaussian_model.compute_regulation, arguments/).

Six feature planes per resolution level - three in space (xy, xz, yz) and three in space-time
(xt, yt, zt) - are sampled bilinearly at a Gaussian's (position, time); the six samples are
multiplied channel by channel and the products of the levels concatenated. One Linear layer maps
that feature to a hidden width W, and three heads ReLU-Linear(W, W)-ReLU-Linear(W, 3 / 4 / 3)
give d_xyz, d_rotation, d_scaling.

As in 4DGaussians:
- positions are normalised into [-1, 1] by an axis-aligned box (`aabb`, a persistent buffer)
  that `fit_bounds` sets from the initial points (4DGaussians: the initial point cloud's
  min / max); until then it is the cube [-1.6, 1.6]^3 (4DGaussians' `bounds` default);
- the time enters the grid as it is: t in [0, 1] covers the upper half of the time planes' [-1, 1]
  axis, so the nodes below t = 0 (but the nearest) are never sampled, only regularised. Kept so
  that a time resolution means what it means in 4DGaussians' configs;
- sampling uses corner-aligned nodes and clamps outside the box (grid_sample with
  align_corners=True, padding_mode='border'); only spatial resolutions grow with the level;
- space planes start uniform in [0.1, 0.5] and time planes at 1, so at initialisation the
  deltas do not depend on the time; Linear weights are Xavier-uniform, biases PyTorch's default;
- the grid trains at `grid_lr_scale` (10) times the decoder's learning rate (param_groups).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
from torch import nn
from torch.nn import functional as F

from liquidgs.errors import ConfigError, LiquidGSError, check_integer, check_number
from liquidgs.fields.base import DeformationField, Deltas, ParamGroup, linear_flops, stacked_linear
from liquidgs.fields.config import FieldConfig
from liquidgs.fields.registry import register as register_field

# A plane 'ab' is stored [C, size of b, size of a]: its first axis runs along the columns, as
# grid_sample reads a coordinate pair (a, b).
SPACE_PLANES = ("xy", "xz", "yz")
TIME_PLANES = ("xt", "yt", "zt")

DEFAULT_BOUNDS = 1.6
"""Half-size of the box before fit_bounds (4DGaussians' ModelHiddenParams.bounds)."""


MAX_LEVEL_RESOLUTION = 4096
"""The most spatial nodes per axis at any level (resolution x multiplier): 16x the largest preset's 256."""
MAX_LEVELS = 32
"""The most levels (multires entries): 10x the largest preset's 3."""
SIZE_BOUNDS = {
    "resolution": (3, MAX_LEVEL_RESOLUTION),
    "time_resolution": (3, 2048),
    "features": (1, 512),
    "width": (1, 4096),
}
"""(lowest, highest) of each size: the smoothness takes second differences (3 nodes at least); the
highest are 13-32x the largest preset's (PRESETS below), as the planes' memory grows with them."""


@dataclass(frozen=True)
class HexPlaneConfig:
    """Sizes of a HexPlane field, the weights of its grid regularisers and its grid's learning rate."""

    resolution: int
    """Spatial nodes per axis at level multiplier 1 (4DGaussians' kplanes_config resolution[:3]);
    with the multiplier, at most 4,096 at any level."""
    time_resolution: int
    """Nodes along the time axis, the same at every level (resolution[3]); at most 2,048."""
    features: int
    """Channels of every plane (output_coordinate_dim); the fused feature has features x
    levels; at most 512."""
    multires: tuple[int, ...]
    """Spatial resolution multiplier of each level; at most 32 levels."""
    width: int
    """Hidden width W of the decoder (net_width); at most 4,096."""
    space_smoothness_weight: float
    """4DGaussians' plane_tv_weight (see HexPlaneField.regulariser_loss for what it weighs)."""
    time_smoothness_weight: float
    time_l1_weight: float
    """4DGaussians' l1_time_planes: mean |1 - time plane|."""
    grid_lr_scale: float
    """The planes' learning rate as a multiple of the decoder's, which is the run's field learning
    rate. 10 in every preset: 4DGaussians' arguments/__init__.py trains the grid at grid_lr_init
    1.6e-3 -> grid_lr_final 1.6e-4 and the decoder at deformation_lr_init 1.6e-4 -> 1.6e-5
    (arguments/dnerf/dnerf_default.py: 1.6e-3 -> 1.6e-5 against 1.6e-4 -> 1.6e-6), 10x at every step."""
    level_time_resolutions: tuple[int, ...] = ()
    """Nodes along time of each level, in place of time_resolution at every level (beyond 4DGaussians,
    whose levels share one): a coarse time on one level and a finer one on the next. Unset in every preset."""

    def __post_init__(self) -> None:
        for key, (lowest, highest) in SIZE_BOUNDS.items():
            check_integer(f"hexplane: {key}", getattr(self, key), lowest, highest)
        if not self.multires or min(self.multires) < 1:
            raise ConfigError(f"hexplane: multires must be one or more integers >= 1, got {self.multires}")
        check_integer("hexplane: levels (multires)", len(self.multires), 1, MAX_LEVELS)
        finest = self.resolution * max(self.multires)
        if finest > MAX_LEVEL_RESOLUTION:
            raise ConfigError(
                f"hexplane: resolution x multires must be at most {MAX_LEVEL_RESOLUTION:,} at every level, "
                f"got {self.resolution} x {max(self.multires)} = {finest:,}"
            )
        for key in ("space_smoothness_weight", "time_smoothness_weight", "time_l1_weight"):
            check_number(f"hexplane: {key}", getattr(self, key))
        check_number("hexplane: grid_lr_scale", self.grid_lr_scale, positive=True)
        object.__setattr__(self, "multires", tuple(self.multires))
        if self.level_time_resolutions:
            times = tuple(self.level_time_resolutions)
            if len(times) != len(self.multires):
                raise ConfigError(f"hexplane: level_time_resolutions needs one value per level ({len(self.multires)}), "
                                  f"got {len(times)}")  # fmt: skip
            for time_resolution in times:
                check_integer("hexplane: level_time_resolutions", time_resolution, *SIZE_BOUNDS["time_resolution"])
            object.__setattr__(self, "level_time_resolutions", times)

    def time_resolutions(self) -> tuple[int, ...]:
        """The nodes along time of each level."""
        return self.level_time_resolutions or (self.time_resolution,) * len(self.multires)

    @classmethod
    def preset(cls, name: str, **overrides) -> HexPlaneConfig:
        """The sizes of a preset (PRESETS), with some replaced."""
        if name not in PRESETS:
            raise ConfigError(f"unknown hexplane preset '{name}' (choose from {', '.join(PRESETS)})")
        unknown = sorted(set(overrides) - {f.name for f in dataclasses.fields(cls)})
        if unknown:
            raise ConfigError(f"hexplane: unknown setting(s) {', '.join(unknown)}")
        return cls(**{**PRESETS[name], **overrides})

    def resolved(self) -> HexPlaneConfig:
        """Complete as built (DeformationField stores config.resolved())."""
        return self


# dnerf: arguments/dnerf/dnerf_default.py with the kplanes_config default of arguments/__init__.py
#   (64^3 x 25, 32 channels; the per-scene files only change the time resolution, 25-100).
#   defor_depth 0 and 1 both build one Linear before the heads.
# nerfds: the real-scene config, arguments/hypernerf/default.py (also arguments/dycheck/default.py;
#   4DGaussians has no NeRF-DS config).
# tiny: CPU-sized for 64-128 px scenes with 5k-20k Gaussians: finest level 64 nodes (about half
#   the image width), time 40 = half of the 80 frames of the synthetic scenes (4DGaussians' rule
#   of thumb), a quarter of the channels and half the width of dnerf, dnerf's weights.
PRESETS: dict[str, dict] = {
    "dnerf": dict(
        resolution=64,
        time_resolution=25,
        features=32,
        multires=(1, 2),
        width=64,
        space_smoothness_weight=1e-4,
        time_smoothness_weight=1e-2,
        time_l1_weight=1e-4,
        grid_lr_scale=10.0,
    ),
    "nerfds": dict(
        resolution=64,
        time_resolution=150,
        features=16,
        multires=(1, 2, 4),
        width=128,
        space_smoothness_weight=2e-4,
        time_smoothness_weight=1e-3,
        time_l1_weight=1e-4,
        grid_lr_scale=10.0,
    ),
    "tiny": dict(
        resolution=32,
        time_resolution=40,
        features=8,
        multires=(1, 2),
        width=32,
        space_smoothness_weight=1e-4,
        time_smoothness_weight=1e-2,
        time_l1_weight=1e-4,
        grid_lr_scale=10.0,
    ),
}


def sample_planes(planes: torch.Tensor, coords: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of P planes [P, C, H, W] at coordinates [P, N, 2] in [-1, 1] (column, row;
    -1 and 1 are the outer nodes, outside is clamped): [P, C, N]."""
    return F.grid_sample(planes, coords[:, None], mode="bilinear", padding_mode="border", align_corners=True)[:, :, 0]


def smoothness(planes: torch.Tensor) -> torch.Tensor:
    """Sum over the planes [P, C, H, W] of the mean squared second difference along H
    (4DGaussians' compute_plane_smoothness, one plane at a time)."""
    second = planes[:, :, 2:] - 2 * planes[:, :, 1:-1] + planes[:, :, :-2]
    return second.square().mean(dim=(1, 2, 3)).sum()


class HexPlaneLevel(nn.Module):
    """The six planes of one resolution level, the space planes and the time planes each stacked."""

    def __init__(self, resolution: int, time_resolution: int, features: int):
        super().__init__()
        self.space = nn.Parameter(torch.empty(3, features, resolution, resolution).uniform_(0.1, 0.5))
        self.time = nn.Parameter(torch.ones(3, features, time_resolution, resolution))

    def forward(self, space_coords: torch.Tensor, time_coords: torch.Tensor) -> torch.Tensor:
        """The product of the six planes' samples, [C, N]."""
        # Written out: prod(0)'s backward handles zeros and costs more than all the products here.
        xy, xz, yz = sample_planes(self.space, space_coords)
        xt, yt, zt = sample_planes(self.time, time_coords)
        return xy * xz * yz * xt * yt * zt


class HexPlaneField(DeformationField):
    """The 4DGaussians field (see the module docstring). Deterministic: no noise, the same output in
    train and eval mode. dnerf preset: 2,444,170 parameters; nerfds: 7,411,466; tiny: 219,082
    (4DGaussians builds a time network and opacity / colour heads too, unused in these configs:
    left out)."""

    def __init__(self, config: HexPlaneConfig):
        super().__init__(config)
        cfg = self.config
        self.register_buffer("aabb", torch.tensor([[-DEFAULT_BOUNDS] * 3, [DEFAULT_BOUNDS] * 3]))
        self.levels = nn.ModuleList(
            HexPlaneLevel(cfg.resolution * m, time_resolution, cfg.features)
            for m, time_resolution in zip(cfg.multires, cfg.time_resolutions(), strict=True)
        )
        self.feature_out = nn.Linear(cfg.features * len(cfg.multires), cfg.width)
        self.hidden_xyz = nn.Linear(cfg.width, cfg.width)
        self.hidden_rotation = nn.Linear(cfg.width, cfg.width)
        self.hidden_scaling = nn.Linear(cfg.width, cfg.width)
        self.head_xyz = nn.Linear(cfg.width, 3)
        self.head_rotation = nn.Linear(cfg.width, 4)
        self.head_scaling = nn.Linear(cfg.width, 3)
        for layer in self.modules():
            if isinstance(layer, nn.Linear):
                nn.init.xavier_uniform_(layer.weight)

    @torch.no_grad()
    def fit_bounds(self, xyz: torch.Tensor) -> None:
        """Set the box that maps onto the grid to the points' extent (their min and max per axis)."""
        if xyz.dim() != 2 or xyz.shape[1] != 3 or xyz.shape[0] == 0:
            raise ValueError(f"fit_bounds needs points of shape [N, 3] with N >= 1, got {tuple(xyz.shape)}")
        if not torch.isfinite(xyz).all():
            raise ValueError("fit_bounds: the points must be finite")
        low, high = xyz.amin(0), xyz.amax(0)
        flat = ["xyz"[i] for i in range(3) if high[i] <= low[i]]
        if flat:
            raise ValueError(f"fit_bounds: the points have no extent along {', '.join(flat)}")
        self.aabb.copy_(torch.stack((low, high)))

    def setup(self, xyz: torch.Tensor) -> None:
        """The field contract's set-up hook: the box from the initial means, as 4DGaussians does."""
        try:
            self.fit_bounds(xyz)
        except ValueError as error:
            raise LiquidGSError(f"field 'hexplane': {error}") from None

    def grid_features(self, xyz: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """The fused multi-resolution feature [N, features x levels] at xyz [N, 3] and t [1 or N, 1]."""
        low, high = self.aabb
        unit = (xyz - low) * (2 / (high - low)) - 1
        n = xyz.shape[0]
        # [3 planes, N, 2]: (x, y), (x, z), (y, z) and (x, t), (y, t), (z, t), as SPACE_ / TIME_PLANES.
        space_coords = unit[:, [0, 1, 0, 2, 1, 2]].view(n, 3, 2).transpose(0, 1)
        time_coords = torch.stack((unit, t.expand(n, 3)), dim=2).transpose(0, 1)
        return torch.cat([level(space_coords, time_coords) for level in self.levels]).t()

    def deltas(self, xyz: torch.Tensor, t: torch.Tensor) -> Deltas:
        hidden = F.relu(self.feature_out(self.grid_features(xyz, t)))
        heads = (self.hidden_xyz, self.hidden_rotation, self.hidden_scaling)
        outs = (self.head_xyz, self.head_rotation, self.head_scaling)
        return tuple(out(F.relu(h)) for out, h in zip(outs, stacked_linear(hidden, list(heads))))

    def regulariser_loss(self) -> torch.Tensor:
        """The field contract's regulariser hook (the trainer adds it after the warm-up, as
        4DGaussians adds it in its fine stage only). 4DGaussians' grid regulariser, weighted:
        summed over the levels,
        space_smoothness_weight x smoothness of the space planes (4DGaussians calls this term
        plane TV, but its code takes the second difference along each space plane's second axis -
        y for xy, z for xz and yz - and never calls the K-Planes TV it ships),
        + time_smoothness_weight x smoothness of the time planes along t,
        + time_l1_weight x sum over the time planes of mean |1 - plane|."""
        cfg = self.config
        space = sum(smoothness(level.space) for level in self.levels)
        time = sum(smoothness(level.time) for level in self.levels)
        l1 = sum((1 - level.time).abs().mean(dim=(1, 2, 3)).sum() for level in self.levels)
        return cfg.space_smoothness_weight * space + cfg.time_smoothness_weight * time + cfg.time_l1_weight * l1

    def param_groups(self) -> list[ParamGroup]:
        """The field contract's learning-rate hook: the planes at grid_lr_scale, the decoder at 1."""
        grid = list(self.levels.parameters())
        decoder = [p for name, p in self.named_parameters() if not name.startswith("levels.")]
        return [("grid", grid, self.config.grid_lr_scale), ("decoder", decoder, 1.0)]

    def flops_per_gaussian(self) -> int:
        """The Linear layers only, as for every field; the grid lookups (per level 6 planes x
        features x 4 corners, then the products) are not counted, like an encoding."""
        return linear_flops(self)


def build(config: FieldConfig) -> HexPlaneField:
    """The field of a run's config: sized by its preset; of the --field-options only grid_lr_scale and
    level_time_resolutions apply (unset: the preset's)."""
    overrides = {key: getattr(config, key) for key in ("grid_lr_scale", "level_time_resolutions")
                 if getattr(config, key) not in (None, ())}  # fmt: skip
    return HexPlaneField(HexPlaneConfig.preset(config.preset, **overrides))


def register() -> None:
    """The 'liquidgs.fields' entry point (liquidgs' pyproject.toml): hexplane registers as a plugin would."""
    register_field("hexplane", build, presets=PRESETS, label="HexPlane (4D-GS)", local_deformation=True)
