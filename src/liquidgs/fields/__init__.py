"""Deformation fields: (canonical xyz, t) -> (d_xyz, d_rotation, d_scaling).

  static  zero deltas, no parameters
  mlp     the D-3DGS MLP
  cfc     a stack of liquid CfC cells (deterministic)
  sde     the same stack with stochastic noise in training: the paper's time-gate noise, or
          (beyond the paper) an exact OU or a torchsde-integrated hidden-state diffusion,
          with annealed and/or input-dependent noise levels
  hexplane  4DGaussians' HexPlane field, registered through an entry point like any plugin

Which fields exist is the registry's (fields/registry.py: `register`, the contract a field
satisfies, and the "liquidgs.fields" entry points of other packages).
The fields know nothing of rendering or training.
"""

from liquidgs.fields.base import DeformationField, Deltas, FieldContractError, StaticField, linear_flops
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
from liquidgs.fields.registry import FieldType, field_label, field_names, field_type, register

__all__ = [
    "ACTIVATIONS",
    "NOISE_SITES",
    "PRESET_NAMES",
    "PRESETS",
    "SCHEDULES",
    "CfCCell",
    "Deltas",
    "DeformationField",
    "FieldConfig",
    "FieldContractError",
    "FieldType",
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
    "field_label",
    "field_names",
    "field_type",
    "linear_flops",
    "ou_std",
    "ou_transition",
    "register",
    "schedule_factor",
    "solve_ltc_sde",
]
