"""Per-group field learning rates: the param_groups hook and its check, the trainer's Adam groups
and their schedule, checkpoints of them (and of before them), and HexPlane's grid_lr_scale."""

from __future__ import annotations

import shutil

import pytest
import torch
from torch import nn

from liquidgs.cli import main as cli
from liquidgs.commands.train import resolve_config
from liquidgs.fields import FieldConfig, FieldContractError, StaticField, build_field
from liquidgs.fields.hexplane import HexPlaneField
from liquidgs.train.config import load_yaml, save_yaml
from liquidgs.train.schedules import log_linear_lr
from liquidgs.train.trainer import Trainer
from tiny_runs import interrupt_at, one_line_error, run_train, tiny_flags

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def field_args(scene, field: str, out, *flags: str) -> list[str]:
    return ["--data", str(scene), "--field", field, "--out", str(out), *tiny_flags(), *flags]


def groups_of(optimizer: torch.optim.Adam | dict) -> list[tuple[str, float]]:
    groups = optimizer["param_groups"] if isinstance(optimizer, dict) else optimizer.param_groups
    return [(g["name"], g["lr_scale"]) for g in groups]


@pytest.mark.parametrize("name", ["static", "mlp", "cfc", "sde"])
def test_the_built_in_fields_train_all_their_parameters_in_one_group_at_the_field_rate(name):
    field = build_field(FieldConfig(name=name, preset="tiny"))
    [(group, params, scale)] = field.checked_param_groups()
    assert (group, scale) == ("field", 1.0) and params == list(field.parameters())


class Grouped(StaticField):
    """Two layers, grouped as the test says."""

    def __init__(self, groups):
        super().__init__(FieldConfig(name="static", preset="tiny"))
        self.first, self.second = nn.Linear(2, 2), nn.Linear(2, 2)
        self.groups = groups
        self.name = "grouped"

    def param_groups(self):
        return self.groups(self)


@pytest.mark.parametrize(
    ("groups", "problem"),
    [
        (lambda f: [("a", list(f.first.parameters()), 1.0)], "missing second.weight, second.bias"),
        (lambda f: [("a", list(f.parameters()), 1.0), ("b", [f.first.weight], 2.0)], "repeated first.weight"),
        (
            lambda f: [("a", [*f.parameters(), nn.Parameter(torch.zeros(1))], 1.0)],
            "1 parameter\\(s\\) that are not the field's",
        ),
    ],
)
def test_groups_that_miss_or_repeat_a_parameter_are_refused_in_one_line(groups, problem):
    with pytest.raises(FieldContractError, match=f"^field 'grouped': param_groups\\(\\) must hold each of its "
                       f"parameters exactly once \\({problem}\\)$"):  # fmt: skip
        Grouped(groups).checked_param_groups()


@pytest.mark.parametrize("scale", [0.0, -1.0, float("nan"), float("inf")])
def test_a_group_scale_must_be_a_finite_positive_number(scale):
    with pytest.raises(FieldContractError, match="field 'grouped': param group 'a' has learning-rate scale"):
        Grouped(lambda f: [("a", list(f.parameters()), scale)]).checked_param_groups()


def test_the_grid_trains_at_its_scale_times_the_field_rate_as_the_schedule_moves(puppet_scene, tmp_path):
    cfg, run_dir = resolve_config(field_args(puppet_scene, "hexplane", tmp_path / "run"))
    trainer = Trainer(cfg, run_dir)
    grid, decoder = trainer.field_optimizer.param_groups
    assert groups_of(trainer.field_optimizer) == [("grid", 10.0), ("decoder", 1.0)]
    assert grid["params"] == list(trainer.field.levels.parameters())
    assert len(grid["params"]) + len(decoder["params"]) == len(list(trainer.field.parameters()))
    o = cfg.optim
    assert (grid["lr"], decoder["lr"]) == (10 * o.field_lr_init, o.field_lr_init)
    for step in (0, 100):  # the tiny preset's schedule: 5e-3 -> 5e-4 over 1,500 steps
        trainer._update_learning_rates(step)
        lr = log_linear_lr(step, o.field_lr_init, o.field_lr_final, o.field_lr_steps)
        assert (grid["lr"], decoder["lr"]) == (10 * lr, lr)
    assert lr < o.field_lr_init


def test_a_field_whose_groups_miss_a_parameter_stops_the_run_before_it_starts(
    puppet_scene, tmp_path, monkeypatch, capsys
):
    monkeypatch.setattr(HexPlaneField, "param_groups", lambda self: [("grid", list(self.levels.parameters()), 10.0)])
    out = tmp_path / "run"
    assert cli(["train", *field_args(puppet_scene, "hexplane", out)]) == 2
    line = one_line_error(capsys)
    assert line.startswith(
        "liquidgs train: error: field 'hexplane': param_groups() must hold each of its parameters exactly once "
        "(missing feature_out.weight, feature_out.bias,"
    )
    assert not (out / "checkpoint.pt").exists()


def test_hexplane_trains_checkpoints_and_resumes_with_its_groups(puppet_scene, tmp_path, monkeypatch, capsys):
    whole, interrupted = tmp_path / "whole", tmp_path / "interrupted"
    run_train(field_args(puppet_scene, "hexplane", whole))
    interrupt_at(21, field_args(puppet_scene, "hexplane", interrupted), monkeypatch)
    stale = tmp_path / "stale"
    shutil.copytree(interrupted, stale)
    run_train(field_args(puppet_scene, "hexplane", interrupted, "--resume"))
    a = torch.load(whole / "checkpoint.pt", weights_only=True)
    b = torch.load(interrupted / "checkpoint.pt", weights_only=True)
    assert groups_of(a["field_optimizer"]) == groups_of(b["field_optimizer"]) == [("grid", 10.0), ("decoder", 1.0)]
    for key, value in a["field"].items():
        assert torch.equal(value, b["field"][key]), key

    # A HexPlane checkpoint made before the grid had its own group (one group) is refused by name.
    checkpoint = torch.load(stale / "checkpoint.pt", weights_only=True)
    grid, decoder = checkpoint["field_optimizer"]["param_groups"]
    checkpoint["field_optimizer"]["param_groups"] = [{**decoder, "params": grid["params"] + decoder["params"]}]
    torch.save(checkpoint, stale / "checkpoint.pt")
    capsys.readouterr()
    assert cli(["train", *field_args(puppet_scene, "hexplane", stale, "--resume")]) == 2
    assert one_line_error(capsys) == (
        f"liquidgs train: error: {stale / 'checkpoint.pt'}: the checkpoint trains field 'hexplane' in 1 parameter "
        "group(s), this code in 2 (grid, decoder): it was made by another version of the field; train the run "
        "again in a new folder"
    )


def test_a_checkpoint_from_before_the_groups_resumes_for_a_field_of_one_group(puppet_scene, tmp_path, monkeypatch):
    """Written then, the field's one Adam group had neither a name nor a scale."""
    out = tmp_path / "run"
    interrupt_at(21, field_args(puppet_scene, "mlp", out), monkeypatch)
    checkpoint = torch.load(out / "checkpoint.pt", weights_only=True)
    [group] = checkpoint["field_optimizer"]["param_groups"]
    del group["name"], group["lr_scale"]
    torch.save(checkpoint, out / "checkpoint.pt")
    results = run_train(field_args(puppet_scene, "mlp", out, "--resume"))
    assert results.final["iteration"] == 40
    resumed = torch.load(out / "checkpoint.pt", weights_only=True)
    assert groups_of(resumed["field_optimizer"]) == [("field", 1.0)]


def test_grid_lr_scale_is_a_setting_of_the_command_line_and_the_run_config(puppet_scene, tmp_path):
    out = tmp_path / "run"
    cfg, _ = resolve_config(field_args(puppet_scene, "hexplane", out, "--field-options.grid-lr-scale", "4"))
    assert cfg.field_options.grid_lr_scale == 4.0
    assert [scale for _, _, scale in build_field(cfg.field_config()).param_groups()] == [4.0, 1.0]
    save_yaml(cfg, tmp_path / "config.yml")
    assert load_yaml(tmp_path / "config.yml").field_options.grid_lr_scale == 4.0
    default, _ = resolve_config(field_args(puppet_scene, "hexplane", out))
    assert [scale for _, _, scale in build_field(default.field_config()).param_groups()] == [10.0, 1.0]


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("hexplane", "0", "field: grid_lr_scale must be a finite number > 0, got 0.0"),
        ("hexplane", "nan", "field: grid_lr_scale must be a finite number > 0, got nan"),
        ("mlp", "2", "grid_lr_scale applies to the 'hexplane' field only, not to 'mlp'"),
    ],
)
def test_a_bad_grid_lr_scale_is_one_line(puppet_scene, tmp_path, capsys, field, value, message):
    out = tmp_path / "run"
    assert cli(["train", *field_args(puppet_scene, field, out, "--field-options.grid-lr-scale", value)]) == 2
    assert one_line_error(capsys) == f"liquidgs train: error: {message}"
    assert not out.exists()


def test_hexplane_takes_a_time_resolution_per_level_from_the_command_line_and_the_run_config(puppet_scene, tmp_path):
    out = tmp_path / "run"
    cfg, _ = resolve_config(field_args(puppet_scene, "hexplane", out, "--field-options.level-time-resolutions", "20",
                                       "40"))  # fmt: skip
    assert cfg.field_options.level_time_resolutions == (20, 40)
    field = build_field(cfg.field_config())
    assert [tuple(level.time.shape[2:]) for level in field.levels] == [(20, 32), (40, 64)]  # tiny: 32 x (1, 2)
    save_yaml(cfg, tmp_path / "config.yml")
    assert load_yaml(tmp_path / "config.yml").field_options.level_time_resolutions == (20, 40)
    default, _ = resolve_config(field_args(puppet_scene, "hexplane", out))
    assert [level.time.shape[2] for level in build_field(default.field_config()).levels] == [40, 40]
    # It trains, and its checkpoint holds the planes it was built with.
    results = run_train(field_args(puppet_scene, "hexplane", out, "--field-options.level-time-resolutions", "20", "40"))
    assert results.final["iteration"] > 0
    state = torch.load(out / "checkpoint.pt", weights_only=True)["field"]
    assert [tuple(state[f"levels.{i}.time"].shape[2:]) for i in (0, 1)] == [(20, 32), (40, 64)]


@pytest.mark.parametrize(
    ("field", "values", "message"),
    [
        ("hexplane", ["20"], "hexplane: level_time_resolutions needs one value per level (2), got 1"),
        ("hexplane", ["20", "2"], "hexplane: level_time_resolutions must be an integer >= 3, got 2"),
        ("mlp", ["20", "40"], "level_time_resolutions applies to the 'hexplane' field only, not to 'mlp'"),
    ],
)
def test_a_bad_time_resolution_per_level_is_one_line(puppet_scene, tmp_path, capsys, field, values, message):
    out = tmp_path / "run"
    flags = ["--field-options.level-time-resolutions", *values]
    assert cli(["train", *field_args(puppet_scene, field, out, *flags)]) == 2
    assert one_line_error(capsys) == f"liquidgs train: error: {message}"
    assert not out.exists()
