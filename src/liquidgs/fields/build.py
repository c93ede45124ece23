"""build_field: a FieldConfig -> the deformation field module it describes."""

from __future__ import annotations

from liquidgs.errors import ConfigError
from liquidgs.fields.base import DeformationField
from liquidgs.fields.config import FieldConfig
from liquidgs.fields.registry import field_type


def build_field(config: FieldConfig) -> DeformationField:
    """The registered field config.name, sized by its preset and overrides (float32, CPU)."""
    kind = field_type(config.name)
    if kind.plugin:
        # Another package's code: whatever it raises is one line naming the field and the package
        # (a bad setting it refuses with ConfigError keeps its own words).
        try:
            field = kind.factory(config)
        except ConfigError:
            raise
        except Exception as error:
            raise ConfigError(
                f"field '{config.name}' (package {kind.origin}): its factory failed: {type(error).__name__}: {error}"
            ) from None
    else:
        field = kind.factory(config)
    if not isinstance(field, DeformationField):
        raise ConfigError(f"field '{config.name}': its factory returned {type(field).__name__}, not a DeformationField")
    field.name = config.name
    return field
