"""One run folder = one configuration, whatever the door (issue 28): `train --config` of a
run's own config.yml, `--resume --config`, spec grids whose runs share a name, overrides of a
grid's axes, scenes given by relative paths or changed since training, and equal settings that
must hash equal."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml

from liquidgs.cli import main as cli
from liquidgs.commands.train import default_run_dir, resolve_config
from liquidgs.errors import ConfigError
from liquidgs.experiments import expand, spec_from_dict
from liquidgs.train.config import load_yaml
from tiny_runs import one_line_error, run_train, snapshot, tiny_flags


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


# ----------------------------------------------------------------------------- liquidgs train
# 10 iterations, the evaluation at the end only and no LPIPS: a finished run in about a second.
SHORT = [*tiny_flags({"iterations": 10, "eval.start": 10}), "--eval.lpips-weights", "/nonexistent-lpips-weights"]


@pytest.fixture(scope="module")
def resumed_run(tmp_path_factory, puppet_scene) -> Path:
    """A finished run that was resumed once: its config.yml holds `resume: true` and `out:`."""
    root = tmp_path_factory.mktemp("doors")
    scene = root / "puppet"
    shutil.copytree(puppet_scene, scene)
    run = root / "run"
    run_train(["--data", str(scene), "--field", "mlp", "--out", str(run), *SHORT, "--iterations", "8"])
    run_train(["--out", str(run), "--resume", "--iterations", "10"])
    stored = yaml.safe_load((run / "config.yml").read_text())
    assert stored["resume"] is True and stored["out"] == str(run)
    return run


def test_config_of_a_resumed_run_with_another_seed_is_a_new_run(resumed_run, tmp_path, monkeypatch, capsys):
    """Before: it resumed the seed-0 run under seed 1, removed its results.json, rewrote config.yml."""
    monkeypatch.chdir(tmp_path)
    before = snapshot(resumed_run)
    cfg, run_dir = resolve_config(["--config", str(resumed_run / "config.yml"), "--seed", "1"])
    assert not cfg.resume and cfg.seed == 1 and run_dir == default_run_dir(cfg) != resumed_run
    assert cli(["train", "--config", str(resumed_run / "config.yml"), "--seed", "1"]) == 0
    assert (tmp_path / run_dir / "results.json").is_file() and load_yaml(tmp_path / run_dir / "config.yml").seed == 1
    assert snapshot(resumed_run) == before


def test_config_into_its_own_folder_with_another_seed_is_refused_naming_it(resumed_run, capsys):
    """Before: the same resume under seed 1 ("already finished" without --iterations)."""
    before = snapshot(resumed_run)
    argv = ["train", "--config", str(resumed_run / "config.yml"), "--out", str(resumed_run), "--seed", "1"]
    assert cli(argv) == 2
    assert "output folder holds a different run (settings differ: seed); choose another --out" in one_line_error(
        capsys
    )
    assert snapshot(resumed_run) == before


def test_resume_with_a_config_is_refused(resumed_run, tmp_path, capsys):
    """Before: --config OTHER was silently ignored."""
    other = tmp_path / "other.yml"
    other.write_text((resumed_run / "config.yml").read_text().replace("seed: 0", "seed: 7"))
    before = snapshot(resumed_run)
    assert cli(["train", "--out", str(resumed_run), "--resume", "--config", str(other)]) == 2
    assert one_line_error(capsys) == (
        f"liquidgs train: error: {other}: --resume continues the run in --out as its own config.yml says; --config "
        "cannot change it (to train this config, leave out --resume)"
    )
    assert snapshot(resumed_run) == before


def test_config_yml_holds_the_scene_as_an_absolute_path(puppet_scene, tmp_path, monkeypatch):
    """Before: `data.path` as typed, so another working directory read another scene."""
    monkeypatch.chdir(puppet_scene.parent)
    cfg, _ = resolve_config(["--data", puppet_scene.name, "--out", str(tmp_path / "run"), *SHORT])
    assert cfg.data.path == puppet_scene and cfg.data.path.is_absolute()


def _changed_copy(scene: Path, where: Path) -> Path:
    """The scene with one test camera moved: same file names and sizes but the cameras' file."""
    copy = shutil.copytree(scene, where)
    transforms = copy / "transforms_test.json"
    raw = json.loads(transforms.read_text())
    raw["frames"][0]["transform_matrix"][0][3] += 0.5
    transforms.write_text(json.dumps(raw))
    return copy


def test_a_scene_that_changed_since_training_is_refused_by_eval_resume_and_train(resumed_run, tmp_path, capsys):
    """Before: `eval --run` and `--resume` scored or trained on whatever lay at the path."""
    scene = load_yaml(resumed_run / "config.yml").data.path
    assert json.loads((resumed_run / "scene.json").read_text())["files"]["transforms_test.json"] > 0
    run = shutil.copytree(resumed_run, tmp_path / "run")
    saved = shutil.copytree(scene, tmp_path / "saved")
    try:
        shutil.rmtree(scene)
        _changed_copy(saved, scene)
        before = snapshot(run)
        for argv in (["eval", "--run", str(run)], ["train", "--out", str(run), "--resume", "--iterations", "12"],
                     ["train", "--config", str(run / "config.yml"), "--out", str(run)]):  # fmt: skip
            assert cli(argv) == 2
            assert one_line_error(capsys).endswith(
                f"{scene}: not the scene the run in {run} was trained on "
                "(1 file(s) changed, e.g. transforms_test.json); nothing was written"
            )
        assert snapshot(run) == before
    finally:
        shutil.rmtree(scene)
        shutil.copytree(saved, scene)
    assert cli(["eval", "--run", str(run)]) == 0  # the scene as trained


def test_a_run_folder_without_a_scene_print_is_read_as_before(resumed_run, tmp_path, capsys):
    run = shutil.copytree(resumed_run, tmp_path / "run")
    (run / "scene.json").unlink()
    assert cli(["eval", "--run", str(run)]) == 0
    assert cli(["train", "--out", str(run), "--resume", "--iterations", "12"]) == 0
    assert (run / "scene.json").is_file()  # recorded from now on
