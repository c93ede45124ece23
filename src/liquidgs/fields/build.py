"""build_field: a FieldConfig -> the deformation field module it describes."""

from __future__ import annotations

from liquidgs.fields.base import DeformationField, StaticField
from liquidgs.fields.config import FieldConfig
from liquidgs.fields.liquid import LiquidField
from liquidgs.fields.mlp import MLPField

_FIELD_TYPES: dict[str, type[DeformationField]] = {
    "static": StaticField,
    "mlp": MLPField,
    "cfc": LiquidField,
    "sde": LiquidField,
}


def build_field(config: FieldConfig) -> DeformationField:
    """The field named by config.name, sized by its preset and overrides (float32, CPU)."""
    return _FIELD_TYPES[config.name](config)
