"""The built-in fields' registrations, through the public API as a plugin's are."""

from __future__ import annotations

from liquidgs.fields.base import StaticField
from liquidgs.fields.config import PAPER_LAMBDA
from liquidgs.fields.liquid import LiquidField
from liquidgs.fields.mlp import MLPField
from liquidgs.fields.presets import PRESET_NAMES
from liquidgs.fields.registry import register


def register_builtin_fields() -> None:
    """The built-in fields, in the order tables list them (the registry loads this first)."""
    register("static", StaticField, presets=PRESET_NAMES, label="Static", family="static")
    register("mlp", MLPField, presets=PRESET_NAMES, label="D-3DGS (MLP)", family="mlp")
    register("cfc", LiquidField, presets=PRESET_NAMES, label="Liquid CfC", family="liquid")
    register("sde", LiquidField, presets=PRESET_NAMES, label="SDE-LNN", family="liquid", default_lambda=PAPER_LAMBDA)
