"""build_field: a FieldConfig -> the deformation field module it describes; the built-in fields'
registrations."""

from __future__ import annotations

from liquidgs.errors import ConfigError
from liquidgs.fields.base import DeformationField, StaticField
from liquidgs.fields.config import PRESET_NAMES, FieldConfig
from liquidgs.fields.liquid import LiquidField
from liquidgs.fields.mlp import MLPField
from liquidgs.fields.registry import field_type, register


def register_builtin_fields() -> None:
    """The built-in fields, in the order tables list them (the registry calls this first)."""
    register("static", StaticField, presets=PRESET_NAMES, label="Static", family="static")
    register("mlp", MLPField, presets=PRESET_NAMES, label="D-3DGS (MLP)", family="mlp")
    register("cfc", LiquidField, presets=PRESET_NAMES, label="Liquid CfC", family="liquid")
    register("sde", LiquidField, presets=PRESET_NAMES, label="SDE-LNN", family="liquid")


def build_field(config: FieldConfig) -> DeformationField:
    """The registered field config.name, sized by its preset and overrides (float32, CPU)."""
    field = field_type(config.name).factory(config)
    if not isinstance(field, DeformationField):
        raise ConfigError(f"field '{config.name}': its factory returned {type(field).__name__}, not a DeformationField")
    field.name = config.name
    return field
