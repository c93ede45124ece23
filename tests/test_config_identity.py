"""Config identity 3 (2, normalised), and run folders named by identities 2 and 1 still found.

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
    folder_names,
    from_dict,
    identity,
    identity_v2,
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
    assert d["identity"] == 2 and IDENTITY_VERSION == 3  # version 3 normalises, the dict keeps its marker
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


# ----------------------------------------------------------------------------- identity 3
@pytest.fixture
def dnerf_scene(tmp_path) -> Path:
    (tmp_path / "scene").mkdir()
    (tmp_path / "scene" / "transforms_train.json").write_text("{}")
    return tmp_path / "scene"


@pytest.mark.parametrize(
    ("args", "same"),
    [(["--field", "sde"], ["--field", "sde", "--lambda", "0.05"]),
     ([], ["--downscale", "1"]), (["--data-format", "dnerf"], ["--data-format", "dnerf", "--downscale", "1"]),
     ([], ["--eval.lpips-weights", "weights"]),
     (["--eval.lpips-weights", "/abs/weights"], ["--eval.lpips-weights", "w"]),
     (["--field", "cfc"], ["--field", "cfc", "--lambda", "0"])],
    ids=["sde lambda", "downscale", "downscale dnerf", "lpips weights", "lpips weights paths", "cfc lambda 0"],
)  # fmt: skip
def test_equal_settings_hash_equal(dnerf_scene, args, same):
    """Before: each pair hashed apart, so equal runs were trained twice and not shared."""
    a, _ = resolve_config(["--data", str(dnerf_scene), "--preset", "tiny", *args])
    b, _ = resolve_config(["--data", str(dnerf_scene), "--preset", "tiny", *same])
    assert config_hash(a) == config_hash(b) and differing_settings(a, b) == []


def test_settings_that_differ_still_hash_apart(dnerf_scene, tmp_path):
    base = ["--data", str(dnerf_scene), "--preset", "tiny"]
    sde, _ = resolve_config([*base, "--field", "sde"])
    assert config_hash(sde) != config_hash(resolve_config([*base, "--field", "sde", "--lambda", "0.1"])[0])
    assert config_hash(resolve_config(base)[0]) != config_hash(resolve_config([*base, "--downscale", "2"])[0])
    # a Nerfies split's default downscale is its own (vrig 4, interp 2): None and 1 stay apart there
    nerfies = tmp_path / "nerfies"
    nerfies.mkdir()
    (nerfies / "dataset.json").write_text("{}")
    one, _ = resolve_config(["--data", str(nerfies), "--downscale", "1"])
    assert config_hash(one) != config_hash(resolve_config(["--data", str(nerfies)])[0])


def test_identity_3_keeps_the_hash_of_every_config_already_normal(dnerf_scene):
    """Built-in and experiment runs (lambda given, no weights path) keep their folders."""
    for args in (["--field", "sde", "--lambda", "0.05"], ["--field", "mlp"], ["--downscale", "8", "--field", "cfc"]):
        cfg, _ = resolve_config(["--data", str(dnerf_scene), "--preset", "tiny", *args])
        assert config_hash(cfg) == _v2_hash(cfg)


def _v2_hash(cfg) -> str:
    import hashlib

    return hashlib.sha256(json.dumps(identity_v2(cfg), sort_keys=True).encode()).hexdigest()[:10]


def test_a_run_named_by_identity_2_is_found_by_train_and_experiments(tmp_path, monkeypatch, capsys):
    """A finished run of a config that was not normal (here: a weights path) made under identity 2 is
    found by the same config."""
    monkeypatch.chdir(tmp_path)
    text = (V1_RUN / "config.yml").read_text().replace("out: /tmp/legacy/runs/0de6fcb36b", "out: null")
    config = tmp_path / "config.yml"
    config.write_text(text.replace("lpips_weights: null", "lpips_weights: weights/alex.pth"))
    old = load_yaml(config)
    assert config_hash(old) != _v2_hash(old) and folder_names(old)[1] == _v2_hash(old)
    parent = tmp_path / "outputs" / "dnerf" / "mlp"
    folder = _copy_v1_run(parent).rename(parent / _v2_hash(old))
    (folder / "config.yml").write_text(config.read_text())
    assert cli(["train", "--config", str(config)]) == 0
    assert f"{Path('outputs/dnerf/mlp') / folder.name}: already finished" in capsys.readouterr().err
    assert run_folder(old, parent) == folder


def test_an_sde_run_without_lambda_made_under_identity_2_keeps_its_folder(dnerf_scene, tmp_path):
    """`train --field sde` stored lambda None: its hash changed (to the experiments' lambda 0.05 one)."""
    cfg, _ = resolve_config(["--data", str(dnerf_scene), "--preset", "tiny", "--field", "sde"])
    assert config_hash(cfg) != _v2_hash(cfg)
    assert run_folder(cfg, tmp_path / "runs") == tmp_path / "runs" / config_hash(cfg)
    (tmp_path / "runs" / _v2_hash(cfg)).mkdir(parents=True)
    assert run_folder(cfg, tmp_path / "runs") == tmp_path / "runs" / _v2_hash(cfg)


def test_a_time_resolution_per_level_is_in_a_hexplane_runs_identity_only_when_set():
    """Unset (every run made before it), no field's identity holds it, so their run folders keep their names."""
    args = ["--data", "scene", "--preset", "tiny", "--field", "hexplane"]
    default, _ = resolve_config(args)
    levels, _ = resolve_config([*args, "--field-options.level-time-resolutions", "20", "40"])
    assert "level_time_resolutions" not in identity(default)["field_options"]
    assert identity(levels)["field_options"]["level_time_resolutions"] == [20, 40]
    assert config_hash(levels) != config_hash(default)
    for field in ("mlp", "cfc", "static"):
        cfg, _ = resolve_config(["--data", "scene", "--preset", "tiny", "--field", field])
        assert "level_time_resolutions" not in identity(cfg)["field_options"]
