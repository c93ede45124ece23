"""What an experiment may not do to the files around it, and YAML it may not be fed (issue 28):
alias bombs in configs and specs, spec paths outside --out, another experiment's folder, Ctrl-C."""

from __future__ import annotations

import time

import pytest

from liquidgs.cli import main as cli
from liquidgs.errors import ConfigError
from liquidgs.experiments import spec_from_dict
from tiny_runs import one_line_error

# Nine levels of nine aliases: 9^9 (387 million) values once expanded, from 470 bytes of YAML.
ALIAS_BOMB = "\n".join(
    ["a0: &a0 [x, x, x, x, x, x, x, x, x]"]
    + [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, 9)]
)
ALIASES = {"bomb": ALIAS_BOMB, "self-reference": "a: &a {x: *a}"}


def _refused_quickly(argv, capsys) -> str:
    started = time.perf_counter()
    assert cli(argv) == 2
    assert time.perf_counter() - started < 5
    return one_line_error(capsys)


@pytest.mark.parametrize("aliases", sorted(ALIASES))
def test_yaml_aliases_in_a_run_config_are_one_line(tmp_path, capsys, aliases):
    config = tmp_path / "config.yml"
    config.write_text(f"data: scene\nextra:\n  {ALIASES[aliases].replace(chr(10), chr(10) + '  ')}\n")
    error = _refused_quickly(["train", "--config", str(config), "--out", str(tmp_path / "run")], capsys)
    assert f"{config}: run config holds more than 100,000 values" in error
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("aliases", sorted(ALIASES))
def test_yaml_aliases_in_a_spec_are_one_line(tmp_path, capsys, aliases):
    spec = tmp_path / "spec.yml"
    spec.write_text(f"name: e\npreset: tiny\nscenes: [s]\nfields: [mlp]\n{ALIASES[aliases]}\n")
    argv = ["experiment", "run", str(spec), "--data-root", str(tmp_path), "--out", str(tmp_path / "e")]
    assert f"{spec}: spec holds more than 100,000 values" in _refused_quickly(argv, capsys)
    assert not (tmp_path / "e").exists()


# ----------------------------------------------------------------------------- spec paths
@pytest.mark.parametrize(
    ("key", "value"),
    [("dataset", "../.."), ("dataset", "/tmp/elsewhere"), ("dataset", "a/b"), ("scenes", ["../../x"]),
     ("scenes", ["/abs/scene"]), ("scenes", [".."])],
)  # fmt: skip
def test_spec_paths_that_leave_the_experiment_folder_are_refused(key, value):
    raw = {"name": "e", "preset": "tiny", "scenes": ["a"], "fields": ["mlp"], key: value}
    with pytest.raises(ConfigError) as err:
        spec_from_dict(raw, "s.yml")
    named = value if key == "dataset" else value[0]
    assert str(err.value).startswith(f"s.yml: '{key}' must") and repr(named) in str(err.value)
