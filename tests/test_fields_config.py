"""FieldConfig: presets, parameter counts of the paper's cost table, FLOPs, and bad settings."""

import dataclasses

import pytest

from liquidgs.errors import ConfigError
from liquidgs.fields import FieldConfig, build_field, field_names

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.mark.parametrize(
    ("name", "preset", "params"),
    [
        ("static", "dnerf", 0),
        ("mlp", "dnerf", 522_280),
        ("mlp", "nerfds", 506_378),
        ("cfc", "dnerf", 1_553_706),
        ("cfc", "nerfds", 318_602),
        ("sde", "dnerf", 1_553_706),
        ("sde", "nerfds", 318_602),
    ],
)
def test_parameter_counts_match_the_paper(name, preset, params):
    assert build_field(FieldConfig(name=name, preset=preset)).num_parameters() == params


@pytest.mark.parametrize(("hidden", "units", "layers"), [(128, 256, 2), (32, 64, 1), (16, 48, 3)])
def test_liquid_count_follows_the_per_cell_formula(hidden, units, layers):
    cfg = FieldConfig(name="cfc", preset="nerfds", hidden=hidden, backbone_units=units, backbone_layers=layers, cells=4)
    inputs = 63 + 21
    backbone = (inputs + hidden) * units + units + (layers - 1) * (units**2 + units)
    cell = backbone + 4 * (units * hidden + hidden)
    expected = 4 * cell + (inputs * hidden + hidden) + (hidden * 10 + 10)
    assert build_field(cfg).num_parameters() == expected


def test_flops_count_twice_the_linear_multiply_adds():
    # D-3DGS dnerf MLP: timenet 13x256 + 256x30, layers 93x256, 6 x 256x256, 349x256, heads 256x10.
    mlp = 13 * 256 + 256 * 30 + 93 * 256 + 6 * 256 * 256 + 349 * 256 + 256 * 10
    assert build_field(FieldConfig(name="mlp", preset="dnerf")).flops_per_gaussian() == 2 * mlp
    # Liquid dnerf: timenet, 6 cells of (223x256 + 256x256 + 4 x 256x128), skip 95x128, read-out 128x10.
    liquid = 13 * 256 + 256 * 32 + 6 * (223 * 256 + 256 * 256 + 4 * 256 * 128) + 95 * 128 + 128 * 10
    assert build_field(FieldConfig(name="cfc", preset="dnerf")).flops_per_gaussian() == 2 * liquid
    assert build_field(FieldConfig(name="static")).flops_per_gaussian() == 0


def test_tiny_preset_fields_are_of_similar_size():
    mlp = build_field(FieldConfig(name="mlp", preset="tiny"))
    cfc = build_field(FieldConfig(name="cfc", preset="tiny"))
    assert 40_000 < mlp.num_parameters() < 80_000
    assert 0.8 < cfc.num_parameters() / mlp.num_parameters() < 1.25
    assert 0.8 < cfc.flops_per_gaussian() / mlp.flops_per_gaussian() < 1.25


def test_resolution_fills_the_preset_and_keeps_overrides():
    cfg = FieldConfig(name="sde", preset="nerfds", hidden=64).resolved()
    sizes = (cfg.hidden, cfg.backbone_units, cfg.cells, cfg.activation, cfg.timenet_width)
    assert sizes == (64, 64, 6, "gelu", 0)
    assert cfg.lambda_ == 0.05  # the paper's calibrated value when unset
    assert FieldConfig(name="cfc").resolved().lambda_ == 0.0
    assert FieldConfig(name="mlp", preset="dnerf").resolved().timenet_out == 30


def test_replacing_the_name_revalidates():
    # The trainer builds FieldConfig(name="mlp") and swaps name/preset/lambda in.
    cfg = dataclasses.replace(FieldConfig(name="mlp", noise="gate"), name="sde", lambda_=0.1)
    assert build_field(cfg).config.lambda_ == 0.1
    with pytest.raises(ConfigError, match="lambda"):
        dataclasses.replace(FieldConfig(name="sde"), name="cfc", lambda_=0.05)


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        (dict(name="sde", lambda_=-0.1), "lambda must be"),
        (dict(name="sde", lambda_=float("nan")), "lambda must be"),
        (dict(name="liquid"), "unknown field 'liquid'"),
        (dict(name="cfc", preset="hypernerf"), "unknown preset 'hypernerf'"),
        (dict(name="cfc", activation="swish"), "unknown activation 'swish'"),
        (dict(name="sde", lambda_schedule="exp", lambda_decay_steps=10), "unknown lambda schedule 'exp'"),
        (dict(name="sde", noise="state"), "unknown noise site 'state'"),
        (dict(name="sde", lambda_schedule="cosine"), "lambda_decay_steps"),
        (dict(name="mlp", mlp_depth=0), "mlp_depth must be an integer >= 1"),
        (dict(name="cfc", cells=0), "cells must be an integer >= 1"),
        (dict(name="cfc", backbone_layers=0), "backbone_layers must be an integer >= 1"),
        (dict(name="cfc", hidden=0), "hidden must be an integer >= 1"),
        (dict(name="cfc", lambda_=0.05), "deterministic"),
        (dict(name="mlp", noise="ou"), "'sde' field only"),
        (dict(name="sde", lambda_floor=0.0), "lambda_floor"),
        (dict(name="sde", solver_dt=0.0), "solver_dt"),
        (dict(name="sde", ltc_leak=-1.0), "ltc_leak"),
        (dict(name="sde", ltc_leak=1.0), "hidden-state"),
        (dict(name="cfc", backbone_dropout=1.0), "backbone_dropout"),
        (dict(name="mlp", preset="nerfds", timenet_width=64), "timenet"),
        (dict(name="mlp", xyz_freqs=-1), "xyz_freqs"),
    ],
)
def test_bad_settings_raise_a_clear_config_error(settings, message):
    with pytest.raises(ConfigError, match=message) as info:
        FieldConfig(**settings)
    assert isinstance(info.value, ValueError)


def test_every_field_name_builds():
    for name in field_names():
        assert build_field(FieldConfig(name=name, preset="tiny")).name == name
