"""build_field: a FieldConfig -> the deformation field module it describes."""

from __future__ import annotations

from liquidgs.errors import ConfigError
from liquidgs.fields.base import DeformationField
from liquidgs.fields.config import FieldConfig
from liquidgs.fields.registry import field_type


def build_field(config: FieldConfig) -> DeformationField:
    """The registered field config.name, sized by its preset and overrides (float32, CPU)."""
    field = field_type(config.name).factory(config)
    if not isinstance(field, DeformationField):
        raise ConfigError(f"field '{config.name}': its factory returned {type(field).__name__}, not a DeformationField")
    field.name = config.name
    return field
