"""Deformation fields: (canonical xyz, t) -> (d_xyz, d_rotation, d_scaling).

  static  zero deltas, no parameters
  mlp     the D-3DGS MLP
  cfc     a stack of liquid CfC cells (deterministic)
  sde     the same stack with stochastic noise in training: the paper's time-gate noise, or
          (beyond the paper) an exact OU or a torchsde-integrated hidden-state diffusion,
          with annealed and/or input-dependent noise levels

The fields know nothing of rendering or training.
"""

from liquidgs.fields.base import DeformationField, Deltas, StaticField, linear_flops
from liquidgs.fields.build import build_field
from liquidgs.fields.cells import (
    CfCCell,
    LiquidCell,
    OUCell,
    SolverCell,
    ou_std,
    ou_transition,
    solve_ltc_sde,
)
from liquidgs.fields.config import (
    ACTIVATIONS,
    FIELD_NAMES,
    NOISE_SITES,
    PRESET_NAMES,
    PRESETS,
    SCHEDULES,
    FieldConfig,
    FieldOptions,
)
from liquidgs.fields.encoding import PositionalEncoding, TimeFeatures
from liquidgs.fields.liquid import LiquidField, schedule_factor
from liquidgs.fields.mlp import MLPField

__all__ = [
    "ACTIVATIONS",
    "FIELD_NAMES",
    "NOISE_SITES",
    "PRESET_NAMES",
    "PRESETS",
    "SCHEDULES",
    "CfCCell",
    "Deltas",
    "DeformationField",
    "FieldConfig",
    "FieldOptions",
    "LiquidCell",
    "LiquidField",
    "MLPField",
    "OUCell",
    "PositionalEncoding",
    "SolverCell",
    "StaticField",
    "TimeFeatures",
    "build_field",
    "linear_flops",
    "ou_std",
    "ou_transition",
    "schedule_factor",
    "solve_ltc_sde",
]
