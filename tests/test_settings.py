"""liquidgs.settings: one typed loader for YAML, overrides and flags; flags named as tyro names them."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import pytest
import tyro

from liquidgs.commands.data import CheckArgs, ImagesArgs, SynthArgs, UndistortArgs, VideoArgs
from liquidgs.commands.demo import DemoArgs
from liquidgs.commands.evaluate import EvalArgs
from liquidgs.commands.experiment import ReportArgs, RunArgs
from liquidgs.commands.export import ExportArgs
from liquidgs.commands.render import RenderArgs
from liquidgs.commands.view import ViewArgs
from liquidgs.errors import ConfigError
from liquidgs.settings import (
    flags_of,
    from_dict,
    option_strings,
    parse_flag_settings,
    parse_flags,
    setting_keys,
    to_dict,
    to_flags,
    with_settings,
)
from liquidgs.train.config import TrainConfig, preset_config

COMMAND_CONFIGS = [TrainConfig, RenderArgs, ExportArgs, DemoArgs, EvalArgs, ViewArgs, RunArgs, ReportArgs,
                   SynthArgs, CheckArgs, VideoArgs, ImagesArgs, UndistortArgs]  # fmt: skip


def tyro_flags(cls) -> tuple[set[str], int]:
    """The option strings and the number of positional arguments of tyro's own parser."""
    default = preset_config("dnerf", Path(".")) if cls is TrainConfig else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # get_parser: tyro's public parser, deprecated in 1.0
        parser = tyro.extras.get_parser(cls, default=default)
    actions = parser._actions
    flags = {s for a in actions for s in a.option_strings} - {"-h", "--help"}
    return flags, sum(1 for a in actions if not a.option_strings)


@pytest.mark.parametrize("cls", COMMAND_CONFIGS, ids=lambda c: c.__name__)
def test_our_flags_are_tyros(cls):
    """--help is tyro's; the parser is ours: a tyro release that renamed a flag fails here."""
    ours = {s for flag in flags_of(cls) for s in option_strings(flag)}
    theirs, positional = tyro_flags(cls)
    assert ours == theirs
    assert sum(1 for flag in flags_of(cls) if flag.positional) == positional


def test_train_flags_keep_their_names_with_the_data_settings_grouped():
    keys = {flag.flag: flag.key for flag in flags_of(TrainConfig)}
    assert keys["data"] == "data.path" and keys["data-format"] == "data.format"
    assert keys["downscale"] == "data.downscale" and keys["val-as-test"] == "data.val_as_test"
    assert keys["lambda"] == "lambda_" and keys["eval.lpips-normalize"] == "eval.lpips_normalize"


def test_flags_give_typed_settings():
    argv = ["--data", "scene", "--iterations", "300", "--lambda", "None", "--eval.no-lpips-normalize",
            "--eval.also", "5", "6", "--downscale", "2", "--field-options.activation", "tanh", "--resume"]  # fmt: skip
    assert parse_flag_settings(TrainConfig, argv, "t") == {
        "data.path": Path("scene"), "iterations": 300, "lambda_": None, "eval.lpips_normalize": False,
        "eval.also": (5, 6), "data.downscale": 2, "field_options.activation": "tanh", "resume": True,
    }  # fmt: skip


def test_a_switch_that_may_be_unset_takes_a_value_as_tyro_shows_it():
    """split.apply (bool or None, None: decided from the scene): --split.apply {None,True,False}."""
    for text, value in (("True", True), ("false", False), ("None", None), ("null", None)):
        assert parse_flag_settings(TrainConfig, ["--split.apply", text], "t") == {"split.apply": value}


def test_a_number_that_may_be_unset_takes_none_as_its_reference_writes_it():
    """The reference and the errors call an unset value null (YAML's word): the flag takes it too."""
    for text, value in (("0.3", 0.3), ("null", None), ("None", None)):
        assert parse_flag_settings(TrainConfig, ["--split.occlusion", text], "t") == {"split.occlusion": value}


def test_flags_round_trip_through_to_flags():
    settings = {"field": "sde", "lambda_": 0.1, "eval.also": (5, 6), "eval.quantize_8bit": False, "downscale": 4,
                "perturb.keep_frames": None, "densify.max_per_pixel": 1.5, "split.apply": False}  # fmt: skip
    argv = to_flags(TrainConfig, settings)
    assert "--eval.no-quantize-8bit" in argv and "--downscale" in argv
    assert parse_flag_settings(TrainConfig, argv, "t") == setting_keys(TrainConfig, settings)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--iterations", "lots"], "--iterations: expected an integer, got 'lots'"),
        (["--bogus", "1"], "unrecognized arguments: --bogus 1"),
        (["--iterations"], "argument --iterations: expected one argument"),
        (["--iter", "3"], "unrecognized arguments: --iter 3"),  # no abbreviations: a typo never lands elsewhere
        (["--split.apply", "yes"], "--split.apply: expected true or false or null, got 'yes'"),  # may be unset
    ],
)
def test_usage_errors_are_one_line(argv, message):
    with pytest.raises(ConfigError) as err:
        parse_flag_settings(TrainConfig, ["--data", "x", *argv], "t")
    assert str(err.value) == message


def test_the_field_is_checked_against_the_registry_when_the_config_is_built():
    # A plugin's field is a name no type annotation can list: flags take any name, the config refuses.
    assert parse_flag_settings(TrainConfig, ["--data", "x", "--field", "nerf"], "t")["field"] == "nerf"
    with pytest.raises(ConfigError) as err:
        dataclasses.replace(preset_config("tiny", Path("scene")), field="nerf")
    assert str(err.value) == "unknown field 'nerf' (choose from static, mlp, cfc, sde, hexplane)"


def test_a_positional_argument_and_a_missing_required_one():
    args = parse_flags(RunArgs, ["paper-dnerf", "--data-root", "d", "--parallel", "2"], "run")
    assert (args.spec, args.data_root, args.parallel) == ("paper-dnerf", Path("d"), 2)
    with pytest.raises(ConfigError, match="required: --data-root"):
        parse_flags(RunArgs, ["paper-dnerf"], "run")


def test_yaml_values_are_checked_and_named():
    cfg = preset_config("tiny", Path("scene"))
    raw = to_dict(cfg)
    assert from_dict(TrainConfig, raw) == cfg
    raw["eval"]["every"] = "often"
    with pytest.raises(ConfigError, match="setting 'eval.every' must be an integer, got 'often'"):
        from_dict(TrainConfig, raw, "f.yml")
    with pytest.raises(ConfigError, match="f.yml: unknown setting 'eval.bogus'"):
        from_dict(TrainConfig, {**to_dict(cfg), "eval": {"bogus": 1}}, "f.yml")


def test_with_settings_checks_the_result_as_a_whole():
    cfg = preset_config("tiny", Path("scene"))
    changed = with_settings(cfg, {"eval.every": 7, "data.downscale": 2})
    assert (changed.eval.every, changed.data.downscale, cfg.eval.every) == (7, 2, 500)
    with pytest.raises(ConfigError, match="iterations must be an integer between 1"):
        with_settings(cfg, {"iterations": 0})
    with pytest.raises(ConfigError, match="lambda must be 0"):
        with_settings(cfg, {"field": "cfc", "lambda_": 0.1})
    with pytest.raises(ConfigError, match="unknown setting 'eval'"):
        with_settings(cfg, {"eval": 3})


def test_lists_and_fixed_length_tuples():
    assert parse_flag_settings(ExportArgs, ["--time", "0.1", "0.5"], "export")["time"] == [0.1, 0.5]
    view = parse_flag_settings(ViewArgs, ["--run", "a", "--background", "1", "0", "0.5", "--run", "b"], "view")
    assert view == {"run": [Path("a"), Path("b")], "background": (1.0, 0.0, 0.5)}
    with pytest.raises(ConfigError, match="argument --background: expected 3 arguments"):
        parse_flag_settings(ViewArgs, ["--background", "1", "0"], "view")
