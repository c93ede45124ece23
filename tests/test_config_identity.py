"""Config identity 2, and run folders named by identity 1 (made before it) still found.

tests/data/config_v1 was made by liquidgs 52e35db, the last code with identity 1: hashes.json
holds four configurations resolved from `liquidgs train` arguments with their hashes, and
run-0de6fcb36b the config.yml / results.json / per_view.json of a finished 20-iteration run
(its checkpoint left out). tests/data/config_v2_before_grid_lr.json holds identity-2 hashes made
by liquidgs 9e28a81, before HexPlane's grid_lr_scale.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from liquidgs.cli import main as cli
from liquidgs.commands.train import resolve_config
from liquidgs.experiments import expand, spec_from_dict
from liquidgs.experiments.runner import finished_elsewhere
from liquidgs.train.config import (
    IDENTITY_VERSION,
    config_hash,
    differing_settings,
    from_dict,
    identity,
    legacy_config_hash,
    load_yaml,
    preset_config,
    run_folder,
)

V1 = Path(__file__).parent / "data" / "config_v1"
V1_CASES = json.loads((V1 / "hashes.json").read_text())["cases"]
V1_RUN = V1 / "run-0de6fcb36b"
BEFORE_GRID_LR = json.loads((Path(__file__).parent / "data" / "config_v2_before_grid_lr.json").read_text())


@pytest.mark.parametrize("name", sorted(V1_CASES))
def test_version_1_hashes_are_reproduced(name):
    """From the stored config and from the same command line parsed by this code."""
    case = V1_CASES[name]
    assert legacy_config_hash(from_dict(case["config"])) == case["hash"]
    cfg, _ = resolve_config(["--data", case["config"]["data"], *case["args"]])
    assert legacy_config_hash(cfg) == case["hash"]
    assert config_hash(cfg) != case["hash"]


def test_identity_2_holds_every_setting_that_changes_a_run():
    cfg = preset_config("tiny", Path("scene"))
    d = identity(cfg)
    assert d["identity"] == IDENTITY_VERSION == 2
    assert d["data"]["path"] == str(Path("scene").resolve()) and "cache_images" not in d["data"]
    assert not {"out", "resume", "device", "backend", "checkpoint_every"} & set(d)
    assert d["eval"]["also"] == [] and d["densify"]["max_per_pixel"] == 0 and "time_jitter" in d["perturb"]
    assert "name" not in d["field_options"]  # no placeholder of version 1


@pytest.mark.parametrize("name", sorted(BEFORE_GRID_LR["cases"]))
def test_grid_lr_scale_changed_the_identity_of_hexplane_runs_only(name):
    """The built-in fields' hashes are those of before the setting; HexPlane's are new, so its runs
    made then (the grid at the decoder's learning rate) are not taken for runs of this code."""
    case = BEFORE_GRID_LR["cases"][name]
    cfg, _ = resolve_config(["--data", BEFORE_GRID_LR["data"], *case["args"]])
    assert (config_hash(cfg) == case["hash"]) == (cfg.field != "hexplane")
    assert ("grid_lr_scale" in identity(cfg)["field_options"]) == (cfg.field == "hexplane")


def test_grid_lr_scale_is_part_of_a_hexplane_runs_identity():
    args = ["--data", "scene", "--preset", "tiny", "--field", "hexplane"]
    default, _ = resolve_config(args)
    scaled, _ = resolve_config([*args, "--field-options.grid-lr-scale", "4"])
    assert identity(default)["field_options"]["grid_lr_scale"] is None  # the preset's, 10
    assert differing_settings(default, scaled) == ["field_options.grid_lr_scale"]
    assert config_hash(scaled) != config_hash(default)


def test_a_version_1_config_yml_loads_and_keeps_its_hash():
    cfg = load_yaml(V1_RUN / "config.yml")
    assert cfg.data.path == Path("/tmp/legacy/scene/dnerf") and cfg.iterations == 20
    assert legacy_config_hash(cfg) == "0de6fcb36b"


def _copy_v1_run(parent: Path) -> Path:
    folder = parent / "0de6fcb36b"
    shutil.copytree(V1_RUN, folder)
    return folder


def test_liquidgs_train_finds_a_run_made_before_identity_2(tmp_path, monkeypatch, capsys):
    """Same settings, default folder: the version-1 folder is the run, finished, not trained again."""
    monkeypatch.chdir(tmp_path)
    folder = _copy_v1_run(tmp_path / "outputs" / "dnerf" / "mlp")
    cfg = load_yaml(V1_RUN / "config.yml")
    assert run_folder(cfg, folder.parent) == folder
    config = tmp_path / "config.yml"  # the stored config without its run folder
    config.write_text((V1_RUN / "config.yml").read_text().replace("out: /tmp/legacy/runs/0de6fcb36b", "out: null"))
    assert cli(["train", "--config", str(config)]) == 0
    assert f"{Path('outputs/dnerf/mlp/0de6fcb36b')}: already finished" in capsys.readouterr().err
    assert sorted(p.name for p in folder.iterdir()) == ["config.yml", "per_view.json", "results.json"]


def test_an_experiment_finds_its_runs_made_before_identity_2(tmp_path):
    spec = spec_from_dict({"name": "e", "preset": "tiny", "scenes": ["synthetic:puppet:16"], "fields": ["mlp"],
                           "seeds": [0, 1], "overrides": {"iterations": 20}}, "test")  # fmt: skip
    directory = tmp_path / "exp"
    first = expand(spec, tmp_path, directory).runs[0]
    parent = directory / Path(first.run_dir).parent
    legacy = _copy_v1_run(parent).rename(parent / legacy_config_hash(first.train_config()))
    again = expand(spec, tmp_path, directory)
    assert again.runs[0].folder(directory) == legacy and again.runs[0].is_done(directory)
    assert not again.runs[1].is_done(directory)
    # and in a sibling experiment, whose runs this one shares
    sibling = tmp_path / "other"
    shutil.move(directory, sibling)
    assert finished_elsewhere(first, directory) == sibling / Path(first.run_dir).parent / legacy.name
