"""The public field registry: the built-in fields and plugins register through one API; a field
from another package trains, evaluates, renders, exports, is benchmarked, named in experiment
specs and labelled in reports; hexplane through its entry point; and every bad plugin gives one line.

Plugins here are modules written into a temporary folder and listed in a mocked entry-point table
(field_plugins.use_registry), not installed packages.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import torch

from field_plugins import plugin, use_registry, write_plugin
from liquidgs.cli import main as cli
from liquidgs.data import generate_synthetic
from liquidgs.errors import ConfigError
from liquidgs.experiments import expand, spec_from_dict
from liquidgs.experiments.report.collect import Method
from liquidgs.fields import FieldConfig, build_field, field_label, field_names, field_type, register
from liquidgs.fields.benchmark import main as bench_fields
from liquidgs.fields.hexplane import DEFAULT_BOUNDS, HexPlaneField
from liquidgs.train.run import load_run
from liquidgs.viewer.scenes import load_runs
from test_train import SMOKE_FLAGS

TOY_PLUGIN = """
    import torch
    from torch import nn

    from liquidgs.fields import DeformationField, linear_flops, register as register_field

    WIDTHS = {"tiny": 8, "dnerf": 16}
    REGULARISED_AT = []

    class ToyField(DeformationField):
        def __init__(self, config):
            super().__init__(config)
            width = WIDTHS[config.preset]
            self.hidden = nn.Linear(4, width)
            self.head = nn.Linear(width, 10)
            self.register_buffer("centre", torch.zeros(3))

        def setup(self, xyz):
            self.centre.copy_(xyz.mean(0))

        def deltas(self, xyz, t):
            h = torch.tanh(self.hidden(torch.cat([xyz - self.centre, t.expand(xyz.shape[0], 1)], 1)))
            d = 0.01 * self.head(h)
            return d[:, :3], d[:, 3:7], d[:, 7:]

        def regulariser_loss(self):
            REGULARISED_AT.append(self.progress_step)
            return 1e-4 * self.head.weight.square().sum()

        def flops_per_gaussian(self):
            return linear_flops(self)

    def register():
        register_field("toy", ToyField, presets=WIDTHS, label="Toy field")
"""

LOPSIDED_PLUGIN = """
    from liquidgs.fields import DeformationField, register as register_field

    class Lopsided(DeformationField):
        def deltas(self, xyz, t):
            zero = xyz.new_zeros(xyz.shape[0], 3)
            return zero, zero, zero  # d_rotation must have 4 columns

        def flops_per_gaussian(self):
            return 0

    def register():
        register_field("lopsided", Lopsided, presets=["tiny"])
"""


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory) -> Path:
    root = generate_synthetic("puppet", tmp_path_factory.mktemp("scene") / "puppet", size=40, frames=24, seed=1)
    return Path(root) / "dnerf"


@pytest.fixture
def toy_registry(tmp_path, monkeypatch):
    entry = write_plugin(tmp_path, "toy_fields", TOY_PLUGIN, monkeypatch)
    return use_registry(monkeypatch, [plugin("toy-fields", entry)])


def test_builtin_fields_and_hexplane_register_through_the_public_api(monkeypatch):
    use_registry(monkeypatch)
    assert field_names() == ("static", "mlp", "cfc", "sde", "hexplane")
    assert [field_label(n) for n in field_names()] == [
        "Static",
        "D-3DGS (MLP)",
        "Liquid CfC",
        "SDE-LNN",
        "HexPlane (4D-GS)",
    ]
    assert {field_type(n).package for n in field_names()} == {"liquidgs"}
    assert [field_type(n).family for n in field_names()] == ["static", "mlp", "liquid", "liquid", None]
    assert field_type("hexplane").presets == ("dnerf", "nerfds", "tiny")
    # The grid is the one built-in field whose deformation is local (motion_reg's default weights).
    assert [n for n in field_names() if field_type(n).local_deformation] == ["hexplane"]
    with pytest.raises(ConfigError, match="field 'hexplane' takes its sizes from its preset.*mlp_depth"):
        FieldConfig(name="hexplane", preset="tiny", mlp_depth=3)
    with pytest.raises(ConfigError, match="hexplane.*lambda must be 0"):
        FieldConfig(name="hexplane", preset="tiny", lambda_=0.1)


def test_a_plugin_field_is_a_field_everywhere(toy_registry, small_scene, tmp_path, capsys):
    assert field_names()[-1] == "toy" and field_type("toy").package == "toy-fields"
    out = tmp_path / "run"
    args = ["train", "--data", str(small_scene), "--field", "toy", "--out", str(out), *SMOKE_FLAGS]
    assert cli(args) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["field"] == "toy" and results["final"]["iteration"] == 40
    assert results["field_parameters"] == (4 * 8 + 8) + (8 * 10 + 10)
    assert results["field_flops_per_gaussian"] == 2 * (4 * 8 + 8 * 10)
    # The hooks: set-up from the initial means (checkpointed), the regulariser from the warm-up's end.
    regularised_at = sys.modules["toy_fields"].REGULARISED_AT
    assert min(regularised_at) == 10 and max(regularised_at) == 40
    run = load_run(out, "cpu")
    assert run.field.name == "toy" and run.field.centre.abs().sum() > 0
    assert cli(["eval", "--run", str(out)]) == 0
    renders = tmp_path / "renders"
    assert cli(["render", "--run", str(out), "--out", str(renders), "--sweep-frames", "2", "--orbit-frames", "2"]) == 0
    assert any((renders / "test" / "render").iterdir())
    exported = tmp_path / "exported"
    assert cli(["export", "--run", str(out), "--out", str(exported), "--time", "0.5"]) == 0
    [viewer_scene] = load_runs([out], "cpu")
    assert "toy" in viewer_scene.label
    capsys.readouterr()
    assert bench_fields(["--json", "--fields", "toy", "--presets", "tiny", "--sizes", "16", "--repeats", "1"]) == 0
    [row] = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert (row["field"], row["params"]) == ("toy", results["field_parameters"])
    # Experiment specs name it, their runs are TrainConfigs of it, reports label it by its registration.
    spec = spec_from_dict({"name": "e", "preset": "tiny", "scenes": ["synthetic:puppet:16"], "fields": ["toy"]}, "t")
    [entry] = expand(spec, tmp_path, tmp_path / "exp").runs
    assert entry.train_config().field == "toy"
    assert Method.of("toy", 0.0).label == "Toy field" and Method.of("toy", 0.0) > Method.of("hexplane", 0.0)
    with pytest.raises(ConfigError, match="field 'toy' has no preset 'nerfds' \\(it has tiny, dnerf\\)"):
        FieldConfig(name="toy", preset="nerfds")


def test_hexplane_trains_evaluates_and_renders_with_its_hooks(small_scene, tmp_path):
    out = tmp_path / "hexplane"
    assert cli(["train", "--data", str(small_scene), "--field", "hexplane", "--out", str(out), *SMOKE_FLAGS]) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["field"] == "hexplane" and results["final"]["psnr"] > 8.0
    assert results["field_parameters"] == 219_082  # the tiny preset (hexplane.py)
    run = load_run(out, "cpu")
    assert isinstance(run.field, HexPlaneField)
    # setup: the box is the initial points' extent, not the default cube, and the checkpoint keeps it
    assert not torch.allclose(run.field.aabb.abs(), torch.full((2, 3), DEFAULT_BOUNDS))
    assert cli(["eval", "--run", str(out)]) == 0
    renders = tmp_path / "renders"
    assert cli(["render", "--run", str(out), "--out", str(renders), "--sweep-frames", "2", "--orbit-frames", "2"]) == 0


def test_the_regulariser_is_added_to_the_loss_after_the_warm_up_only(small_scene, tmp_path, monkeypatch):
    calls = []
    original = HexPlaneField.regulariser_loss

    def counted(self):
        calls.append(self.progress_step)
        return original(self)

    monkeypatch.setattr(HexPlaneField, "regulariser_loss", counted)
    flags = [*SMOKE_FLAGS, "--iterations", "14", "--eval.start", "14", "--checkpoint-every", "14"]
    assert cli(["train", "--data", str(small_scene), "--field", "hexplane", "--out", str(tmp_path / "r"), *flags]) == 0
    assert calls == list(range(10, 15))


def test_a_plugin_that_fails_to_import_is_one_line_and_the_rest_still_works(tmp_path, monkeypatch, capsys):
    broken = write_plugin(tmp_path, "broken_fields", "import not_a_module_anywhere\n", monkeypatch)
    toy = write_plugin(tmp_path, "toy_fields", TOY_PLUGIN, monkeypatch)
    use_registry(monkeypatch, [plugin("broken-fields", broken), plugin("toy-fields", toy)])
    assert field_names() == ("static", "mlp", "cfc", "sde", "hexplane", "toy")
    line = (
        "field plugin package 'broken-fields' failed to load (broken_fields = broken_fields:register): "
        "ModuleNotFoundError: No module named 'not_a_module_anywhere'"
    )
    assert capsys.readouterr().err == f"liquidgs: warning: {line}\n"
    assert build_field(FieldConfig(name="toy", preset="tiny")).num_parameters() > 0
    with pytest.raises(ConfigError) as err:
        FieldConfig(name="broken")
    choices = ", ".join(field_names())
    assert (
        str(err.value)
        == f"unknown field 'broken' (choose from {choices}); field plugin packages that failed to load: broken-fields"
    )


def test_two_packages_registering_one_name_is_one_line_naming_both(tmp_path, monkeypatch, capsys):
    first = write_plugin(tmp_path, "twin_a", TOY_PLUGIN.replace('"toy"', '"twin"'), monkeypatch)
    second = write_plugin(tmp_path, "twin_b", TOY_PLUGIN.replace('"toy"', '"twin"'), monkeypatch)
    use_registry(monkeypatch, [plugin("pkg-a", first), plugin("pkg-b", second)])
    assert "twin" not in field_names() and "mlp" in field_names()
    line = "field 'twin' is registered by two packages, 'pkg-a' and 'pkg-b': uninstall one"
    assert capsys.readouterr().err == f"liquidgs: warning: {line}\n"
    with pytest.raises(ConfigError) as err:
        FieldConfig(name="twin", preset="tiny")
    assert str(err.value) == line
    with pytest.raises(
        ConfigError, match="package 'test_field_registry' cannot register 'mlp': it is a built-in field"
    ):
        register("mlp", lambda config: None, presets=["tiny"])
    assert field_type("mlp").package == "liquidgs"


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(name="Bad-Name"), "a field name must be a lowercase identifier, got 'Bad-Name'"),
        (
            dict(presets=["blender"]),
            "field 'new' must register presets among dnerf, nerfds, tiny, got \\('blender',\\)",
        ),
        (dict(family="unet"), "field 'new': unknown family 'unet'"),
        (dict(factory=3), "field 'new': the factory must be callable"),
        (dict(local_deformation="yes"), "field 'new': local_deformation must be True or False, got 'yes'"),
    ],
)
def test_bad_registrations_are_refused(monkeypatch, kwargs, message):
    use_registry(monkeypatch)
    settings = {"name": "new", "factory": lambda config: None, "presets": ["tiny"], **kwargs}
    with pytest.raises(ConfigError, match=message):
        register(settings.pop("name"), settings.pop("factory"), **settings)


def test_a_field_with_wrong_shapes_fails_before_the_first_step_naming_it(small_scene, tmp_path, monkeypatch, capsys):
    entry = write_plugin(tmp_path, "lopsided_fields", LOPSIDED_PLUGIN, monkeypatch)
    use_registry(monkeypatch, [plugin("lopsided-fields", entry)])
    out = tmp_path / "run"
    assert cli(["train", "--data", str(small_scene), "--field", "lopsided", "--out", str(out), *SMOKE_FLAGS]) == 2
    err = capsys.readouterr().err
    assert err == (
        "liquidgs train: error: field 'lopsided' returned [(8, 3), (8, 3), (8, 3)] for N = 8 points; "
        "a field returns (d_xyz [N, 3], d_rotation [N, 4], d_scaling [N, 3])\n"
    )
    assert not (out / "checkpoint.pt").exists()
