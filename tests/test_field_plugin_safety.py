"""Plugins cannot break liquidgs (issue 28): a plugin taking a built-in name, failing or exiting
at registration, or with a factory that fails is one line naming its package while every other
field keeps working (bench fields included); a plugin's own options are --field-options.* and
part of its runs' identity; a stochastic plugin takes --lambda; the field's package is recorded
in config.yml and named when it is missing; liquidgs.fields.testing checks the contract.

Plugins are modules written into a temporary folder and listed in a mocked entry-point table
(field_plugins.use_registry), not installed packages.
"""

from __future__ import annotations

import json

import pytest
import yaml

from field_plugins import plugin, use_registry, write_plugin
from liquidgs.cli import main as cli
from liquidgs.commands.train import resolve_config
from liquidgs.errors import ConfigError
from liquidgs.fields import FieldConfig, MLPField, build_field, field_names, field_type
from liquidgs.fields.testing import check_field
from liquidgs.train.config import config_hash, differing_settings, identity, load_yaml, save_yaml
from test_field_registry import LOPSIDED_PLUGIN, TOY_PLUGIN
from tiny_runs import one_line_error

BUILTIN_FIELDS = ("static", "mlp", "cfc", "sde", "hexplane")
TOY_FIELDS = (*BUILTIN_FIELDS, "toy")

TAKES_MLP = """
    from liquidgs.fields import StaticField, register as register_field

    def register():
        register_field("mlp", StaticField, presets=["tiny"], label="Not the MLP")
        register_field("hexplane", StaticField, presets=["tiny"])
        register_field("still", StaticField, presets=["tiny"])
"""

BAD_FACTORIES = """
    from liquidgs.fields import register as register_field

    def no_arguments():
        raise AssertionError("never called")

    def raises(config):
        raise RuntimeError("the grid does not fit")

    def register():
        register_field("nullary", no_arguments, presets=["tiny"])
        register_field("raising", raises, presets=["tiny"])
"""

OWN_OPTIONS = """
    from dataclasses import dataclass
    from typing import Literal

    from liquidgs.fields import StaticField, register as register_field

    SEEN = []

    @dataclass
    class WavyOptions:
        width: int = 8
        scale: float = 1.0
        kind: Literal["sin", "cos"] = "sin"

        def __post_init__(self):
            if self.width < 1:
                raise ValueError(f"width must be >= 1, got {self.width}")

    class Wavy(StaticField):
        def __init__(self, config):
            super().__init__(config)
            SEEN.append((config.options, config.base_lambda))

    def register():
        register_field("wavy", Wavy, presets=["tiny"], options=WavyOptions, default_lambda=0.1)
        register_field("plain", StaticField, presets=["tiny"])
"""


@pytest.fixture
def toy_registry(tmp_path, monkeypatch):
    return use_registry(
        monkeypatch, [plugin("toy-fields", write_plugin(tmp_path, "toy_fields", TOY_PLUGIN, monkeypatch))]
    )


def test_a_plugin_cannot_take_a_builtin_name(tmp_path, monkeypatch, capsys):
    """It used to disable the built-in MLP (every MLP command exited 2, inviting to uninstall liquidgs)."""
    taker = write_plugin(tmp_path, "taker", TAKES_MLP, monkeypatch)
    use_registry(monkeypatch, [plugin("greedy-fields", taker)])
    assert field_names() == (*BUILTIN_FIELDS, "still")  # its other field still registers
    assert capsys.readouterr().err.splitlines() == [
        f"liquidgs: warning: field plugin package 'greedy-fields' cannot register '{name}': it is a built-in field "
        "(the built-in is kept)"
        for name in ("mlp", "hexplane")
    ]
    assert field_type("mlp").package == "liquidgs" and field_type("mlp").label == "D-3DGS (MLP)"
    assert isinstance(build_field(FieldConfig(name="mlp", preset="tiny")), MLPField)
    cfg, _ = resolve_config(["--data", "scene", "--preset", "tiny", "--field", "mlp"])
    assert cfg.field_config().name == "mlp"


@pytest.mark.parametrize(
    ("source", "error"),
    [
        ("import sys\n\ndef register():\n    sys.exit(3)\n", "exited (quitter = quitter:register): SystemExit: 3"),
        ("raise RuntimeError('half installed')\n", "failed to load (quitter = quitter:register): RuntimeError: "),
        ("register = 3\n", "failed to load (quitter = quitter:register): TypeError: 'int' object is not callable"),
    ],
    ids=["sys.exit", "raises at import", "not callable"],
)
def test_a_plugin_that_exits_or_fails_at_registration_is_one_line(tmp_path, monkeypatch, capsys, source, error):
    """sys.exit(3) at registration used to end every liquidgs command silently."""
    quitter = write_plugin(tmp_path, "quitter", source, monkeypatch)
    toy = write_plugin(tmp_path, "toy_fields", TOY_PLUGIN, monkeypatch)
    use_registry(monkeypatch, [plugin("quitting-fields", quitter), plugin("toy-fields", toy)])
    assert field_names() == TOY_FIELDS
    [line] = capsys.readouterr().err.splitlines()
    assert line.startswith(f"liquidgs: warning: field plugin package 'quitting-fields' {error}")


def test_one_packages_two_entry_points_for_one_function_register_it_once(tmp_path, monkeypatch, capsys):
    """They used to be "registered by two packages, 'x' and 'x'"."""
    entry = write_plugin(tmp_path, "toy_fields", TOY_PLUGIN, monkeypatch)
    twin = entry.__class__("toy_again", entry.value, entry.group)
    use_registry(monkeypatch, [plugin("toy-fields", entry), plugin("toy-fields", twin)])
    assert field_names() == TOY_FIELDS and field_type("toy").package == "toy-fields"
    assert capsys.readouterr().err == ""


def test_one_package_registering_a_name_twice_names_the_package_once(tmp_path, monkeypatch, capsys):
    source = (
        TOY_PLUGIN
        + '\n    def register_again():\n        register_field("toy", lambda config: None, presets=["tiny"])\n'
    )
    entry = write_plugin(tmp_path, "toy_fields", source, monkeypatch)
    again = entry.__class__("toy_again", "toy_fields:register_again", entry.group)
    use_registry(monkeypatch, [plugin("toy-fields", entry), plugin("toy-fields", again)])
    assert "toy" not in field_names()
    line = "field 'toy' is registered twice by package 'toy-fields': fix the package"
    assert capsys.readouterr().err == f"liquidgs: warning: {line}\n"


@pytest.fixture
def bad_factories(tmp_path, monkeypatch):
    entry = write_plugin(tmp_path, "bad_factories", BAD_FACTORIES, monkeypatch)
    return use_registry(monkeypatch, [plugin("bad-factories", entry)])


def test_a_factory_that_fails_is_one_line_naming_its_package(bad_factories, puppet_scene, tmp_path, capsys):
    """It used to be a 19-line traceback."""
    with pytest.raises(ConfigError) as err:
        build_field(FieldConfig(name="nullary", preset="tiny"))
    assert str(err.value) == (
        "field 'nullary' (package bad-factories 0.2): its factory failed: "
        "TypeError: no_arguments() takes 0 positional arguments but 1 was given"
    )
    out = tmp_path / "run"
    args = ["train", "--data", str(puppet_scene), "--preset", "tiny", "--field", "raising", "--out", str(out)]
    assert cli(args) == 2
    assert one_line_error(capsys) == (
        "liquidgs train: error: field 'raising' (package bad-factories 0.2): its factory failed: "
        "RuntimeError: the grid does not fit"
    )
    assert not out.exists()


def test_bench_fields_measures_every_good_field_and_names_the_bad_ones(bad_factories, capsys):
    """Without --fields it used to stop at the first bad field and measure none after it."""
    flags = ["--json", "--presets", "tiny", "--sizes", "8", "--repeats", "1", "--warmup", "0"]
    assert cli(["bench", "fields", *flags]) == 0
    out, err = capsys.readouterr()
    assert [json.loads(line)["field"] for line in out.splitlines()] == list(BUILTIN_FIELDS)
    assert err.splitlines() == [
        "liquidgs bench fields: warning: skipped field 'nullary' (package bad-factories 0.2): its factory failed: "
        "TypeError: no_arguments() takes 0 positional arguments but 1 was given",
        "liquidgs bench fields: warning: skipped field 'raising' (package bad-factories 0.2): its factory failed: "
        "RuntimeError: the grid does not fit",
    ]
    # Named, a bad field is the command's error.
    assert cli(["bench", "fields", *flags, "--fields", "raising"]) == 2
    assert one_line_error(capsys).endswith("RuntimeError: the grid does not fit")


@pytest.fixture
def own_options(tmp_path, monkeypatch):
    entry = write_plugin(tmp_path, "wavy_fields", OWN_OPTIONS, monkeypatch)
    return use_registry(monkeypatch, [plugin("wavy-fields", entry)])


WAVY = ["--data", "scene", "--preset", "tiny", "--field", "wavy"]


def test_a_plugins_own_options_are_field_options_and_part_of_its_runs_identity(own_options, tmp_path):
    default, _ = resolve_config(WAVY)
    wide, _ = resolve_config([*WAVY, "--field-options.width", "32", "--field-options.kind", "cos"])
    assert (wide.field_options.width, wide.field_options.kind, wide.field_options.scale) == (32, "cos", 1.0)
    options = wide.field_config().options
    assert (type(options).__name__, options.width, options.kind) == ("WavyOptions", 32, "cos")
    build_field(wide.field_config())
    import wavy_fields

    assert wavy_fields.SEEN[-1] == (options, 0.1)  # the factory reads them, and the registered lambda
    assert identity(default)["field_options"]["width"] == 8
    assert differing_settings(default, wide) == ["field_options.kind", "field_options.width"]
    assert config_hash(default) != config_hash(wide)
    # Stored in config.yml with the field's package, and read back.
    save_yaml(wide, tmp_path / "config.yml")
    stored = yaml.safe_load((tmp_path / "config.yml").read_text())
    assert stored["field_options"]["width"] == 32
    assert stored["field_package"] == {"name": "wavy-fields", "version": "0.2"}
    assert config_hash(load_yaml(tmp_path / "config.yml")) == config_hash(wide)
    # Other fields' configs and identities do not hold them.
    mlp, _ = resolve_config(["--data", "scene", "--preset", "tiny", "--field", "mlp"])
    assert "width" not in identity(mlp)["field_options"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            [*WAVY, "--field-options.width", "0"],
            "field 'wavy' (package wavy-fields 0.2): bad --field-options: ValueError: width must be >= 1, got 0",
        ),
        ([*WAVY, "--field-options.width", "wide"], "--field-options.width: expected an integer, got 'wide'"),
        ([*WAVY, "--field-options.kind", "tan"], "--field-options.kind: unknown kind 'tan' (choose from sin, cos)"),
        (
            ["--data", "scene", "--preset", "tiny", "--field", "plain", "--field-options.width", "4"],
            "liquidgs train: unknown setting 'field_options.width'",
        ),
        (
            ["--data", "scene", "--preset", "tiny", "--field", "plain", "--lambda", "0.1"],
            "field 'plain' is deterministic",
        ),
    ],
    ids=["its own rules", "type", "choice", "another field", "deterministic plugin"],
)
def test_bad_plugin_options_are_one_line(own_options, args, message):
    with pytest.raises(ConfigError) as err:
        resolve_config(args)
    assert message in str(err.value)


def test_a_stochastic_plugin_takes_lambda(own_options):
    """--lambda on any plugin used to be refused as "deterministic"."""
    cfg, _ = resolve_config([*WAVY, "--lambda", "0.3"])
    assert cfg.resolved_lambda() == 0.3 and cfg.field_config().resolved().lambda_ == 0.3
    default, _ = resolve_config(WAVY)
    assert default.resolved_lambda() == 0.1  # the level it registered
    assert field_type("wavy").default_lambda == 0.1 and field_type("sde").default_lambda == 0.05


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ("3", "field 'odd': options must be a dataclass, got 3"),
        ("make_dataclass('O', [('width', int)])", "field 'odd': option 'width' needs a default"),
        ("make_dataclass('O', [('hidden', int, 4)])", "option 'hidden' is a setting of every field (FieldOptions)"),
        ("make_dataclass('O', [('table', dict, None)])", "option 'table': type <class 'dict'> is not one settings"),
        ("make_dataclass('O', [('width', int, 'x')])", "option 'width': default 'x' is not an integer"),
    ],
)
def test_bad_options_classes_are_refused_at_registration(tmp_path, monkeypatch, capsys, options, message):
    source = f"""
    from dataclasses import make_dataclass

    from liquidgs.fields import StaticField, register as register_field

    def register():
        register_field("odd", StaticField, presets=["tiny"], options={options})
    """
    use_registry(monkeypatch, [plugin("odd-fields", write_plugin(tmp_path, "odd_fields", source, monkeypatch))])
    assert field_names() == BUILTIN_FIELDS
    assert message in capsys.readouterr().err


def test_a_run_whose_plugin_is_not_installed_names_its_package(toy_registry, tmp_path, monkeypatch, capsys):
    """It used to say only "unknown field"."""
    run = tmp_path / "run"
    run.mkdir()
    cfg, _ = resolve_config(["--data", "scene", "--preset", "tiny", "--field", "toy"])
    save_yaml(cfg, run / "config.yml")
    (run / "checkpoint.pt").write_bytes(b"")
    use_registry(monkeypatch)  # the plugin uninstalled
    assert cli(["eval", "--run", str(run)]) == 2
    assert one_line_error(capsys) == (
        f"liquidgs eval: error: {run / 'config.yml'}: field 'toy' comes from package toy-fields 0.2, "
        "which is not installed"
    )


def test_builtin_runs_record_liquidgs_and_its_version(tmp_path):
    from liquidgs import __version__

    cfg, _ = resolve_config(["--data", "scene", "--preset", "tiny", "--field", "mlp"])
    save_yaml(cfg, tmp_path / "config.yml")
    assert yaml.safe_load((tmp_path / "config.yml").read_text())["field_package"] == {
        "name": "liquidgs",
        "version": __version__,
    }


def test_the_contract_check_passes_every_builtin_and_fails_a_broken_field(toy_registry, tmp_path, monkeypatch):
    for name in field_names():
        check_field(name)
    check_field("sde", lambda_=0.2)
    lopsided = write_plugin(tmp_path, "lopsided_fields", LOPSIDED_PLUGIN, monkeypatch)
    use_registry(monkeypatch, [plugin("lopsided-fields", lopsided)])
    with pytest.raises(Exception, match="field 'lopsided' returned"):
        check_field("lopsided")


NOISY_IN_EVAL = """
    import torch
    from torch import nn

    from liquidgs.fields import DeformationField, linear_flops, register as register_field

    class Noisy(DeformationField):
        def __init__(self, config):
            super().__init__(config)
            self.layer = nn.Linear(3, 10)

        def deltas(self, xyz, t):
            d = self.layer(xyz) + torch.randn(xyz.shape[0], 10)
            return d[:, :3], d[:, 3:7], d[:, 7:]

        def flops_per_gaussian(self):
            return linear_flops(self)

    def register():
        register_field("noisy", Noisy, presets=["tiny"])
"""


def test_the_contract_check_fails_a_field_that_is_random_in_eval_mode(tmp_path, monkeypatch):
    use_registry(
        monkeypatch, [plugin("noisy-fields", write_plugin(tmp_path, "noisy_fields", NOISY_IN_EVAL, monkeypatch))]
    )
    with pytest.raises(AssertionError, match=r"field 'noisy' \(preset tiny\): eval mode is not deterministic"):
        check_field("noisy")
