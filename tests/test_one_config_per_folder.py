"""One run folder = one configuration, whatever the door (issue 28): `train --config` of a
run's own config.yml, `--resume --config`, spec grids whose runs share a name, overrides of a
grid's axes, scenes given by relative paths or changed since training, and equal settings that
must hash equal."""

from __future__ import annotations

from pathlib import Path

import pytest

from liquidgs.errors import ConfigError
from liquidgs.experiments import expand, spec_from_dict


def _spec(**grid) -> dict:
    return {"name": "e", "preset": "tiny", "scenes": ["a"], "fields": ["mlp"], **grid}


@pytest.fixture
def data_root(tmp_path) -> Path:
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    return tmp_path


# ----------------------------------------------------------------------------- experiment specs
def test_two_grids_whose_runs_share_a_name_are_refused_naming_both(data_root, tmp_path):
    """Before: both runs wrote logs/tiny-a-mlp-s0.config.yml, each folder trained the other's run."""
    raw = {"name": "e", "preset": "tiny", "scenes": ["a"], "fields": ["mlp"],
           "grids": [{"overrides": {"iterations": 20}}, {"overrides": {"iterations": 30}}]}  # fmt: skip
    with pytest.raises(ConfigError) as err:
        expand(spec_from_dict(raw, "s.yml"), data_root, tmp_path / "exp")
    assert str(err.value) == (
        "spec 'e' grids[0] and grids[1]: two runs are named tiny-a-mlp-s0 but differ in iterations; give the grids "
        "different 'dataset' labels, or name the field configurations as variants"
    )
    assert not (tmp_path / "exp").exists()
    raw["grids"][1]["dataset"] = "longer"  # distinct labels: distinct names, logs and report rows
    names = [run.name for run in expand(spec_from_dict(raw, "s.yml"), data_root, tmp_path / "exp").runs]
    assert names == ["tiny-a-mlp-s0", "longer-a-mlp-s0"]


def test_lambdas_that_print_alike_are_refused(data_root, tmp_path):
    """sde-l0.05 would name both rows."""
    raw = _spec(fields=["sde"], lambdas=[0.05, 0.05000001])
    with pytest.raises(ConfigError, match="two runs are named tiny-a-sde-l0.05-s0 but differ in lambda_"):
        expand(spec_from_dict(raw, "s.yml"), data_root, tmp_path / "exp")


@pytest.mark.parametrize(
    ("where", "key", "owner"),
    [("overrides", "data", "'scenes'"), ("overrides", "data.path", "'scenes'"),
     ("overrides", "field", "'fields'"), ("overrides", "lambda", "'lambdas'"), ("overrides", "lambda_", "'lambdas'"),
     ("overrides", "seed", "'seeds'"), ("overrides", "preset", "'preset'"), ("overrides", "out", "--out"),
     ("overrides", "resume", "runs resume"), ("overrides", "perturb.time_jitter", "'perturb.time_jitter'"),
     ("variants.v.overrides", "field", "'fields' or a variant's 'field'")],
)  # fmt: skip
def test_overrides_of_a_grid_axis_are_refused_naming_grid_and_key(data_root, tmp_path, where, key, owner):
    """Before: a row labelled mlp trained a cfc, a 'spin' row trained another scene."""
    values = {"data": str(data_root / "b"), "data.path": str(data_root / "b"), "field": "cfc", "lambda": 0.3,
              "lambda_": 0.3, "seed": 5, "preset": "dnerf", "out": "/tmp/x", "resume": True,
              "perturb.time_jitter": 0.5}  # fmt: skip
    raw = {"name": "e", "preset": "tiny", "scenes": ["a"], "perturb": {"time_jitter": [0, 0.1]}}
    if where == "overrides":
        raw.update(fields=["mlp"], overrides={key: values[key]})
    else:
        raw["variants"] = {"v": {"field": "mlp", "overrides": {key: values[key]}}}
    with pytest.raises(ConfigError) as err:
        expand(spec_from_dict(raw, "s.yml"), data_root, tmp_path / "exp")
    message = str(err.value)
    assert message.startswith(f"spec 'e': {where}.{key} sets what the grid's ") and owner in message
