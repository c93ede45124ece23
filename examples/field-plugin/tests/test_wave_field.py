"""The plugin's own tests: liquidgs' contract check, and what its options and noise do."""

import pytest
import torch
from wave_field import WaveField, register

from liquidgs.errors import ConfigError
from liquidgs.fields import FieldConfig, build_field
from liquidgs.fields.testing import check_field, plugin_registry


@pytest.fixture(autouse=True)
def wave_registered():
    with plugin_registry(register, package="liquidgs-wave-field"):
        yield


def test_the_wave_field_keeps_the_field_contract():
    check_field("wave", options=[{"width": 8, "frequencies": 1}], lambda_=0.05)


def test_its_options_size_it():
    field = build_field(FieldConfig(name="wave", preset="tiny", options={"width": 8}))
    assert isinstance(field, WaveField) and field.hidden.out_features == 8
    assert build_field(FieldConfig(name="wave", preset="dnerf")).hidden.out_features == 64
    with pytest.raises(ConfigError, match="frequencies must be between 1 and 16, got 0"):
        FieldConfig(name="wave", preset="tiny", options={"frequencies": 0})


def test_lambda_is_the_training_noise():
    field = build_field(FieldConfig(name="wave", preset="tiny", lambda_=0.5))
    torch.nn.init.normal_(field.head.weight)
    xyz, t = torch.rand(16, 3), torch.full((1, 1), 0.25)
    assert field.noise_std == 0.5
    field.train()
    assert not torch.equal(field(xyz, t)[0], field(xyz, t)[0])
    assert FieldConfig(name="wave", preset="tiny").base_lambda == 0.01
