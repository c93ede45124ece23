"""What an experiment may not do to the files around it, and YAML it may not be fed (issue 28):
alias bombs in configs and specs, spec paths outside --out, another experiment's folder, Ctrl-C."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest

from liquidgs.cli import main as cli
from liquidgs.errors import ConfigError
from liquidgs.experiments import runner, spec_from_dict
from liquidgs.experiments.runner import RunOutcome
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


# ----------------------------------------------------------------------------- the experiment folder
def _spec_file(tmp_path, name="e", seeds=(0,)) -> Path:
    (tmp_path / "data" / "a").mkdir(parents=True, exist_ok=True)
    spec = tmp_path / f"{name}.yml"
    spec.write_text(f"name: {name}\npreset: tiny\nscenes: [a]\nfields: [mlp]\nseeds: {list(seeds)}\n")
    return spec


def _fake_training(calls: list, interrupt_at: int | None = None):
    """execute_run without a training: records the run; Ctrl-C (SIGINT to this process) at one."""

    def execute(entry, experiment_dir, env=None):
        calls.append(entry.name)
        if len(calls) == interrupt_at:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.5)  # the training a Ctrl-C interrupts, still running when it arrives
        return RunOutcome(entry.name, "failed", 0.0, "log", "exit code 1: fake")

    return execute


def test_an_experiment_folder_holding_another_experiment_is_refused(tmp_path, capsys, monkeypatch):
    """Before: experiment.json was replaced, the first experiment's runs left its report."""
    monkeypatch.setattr(runner, "execute_run", _fake_training([]))
    data, out = tmp_path / "data", tmp_path / "out"
    first = _spec_file(tmp_path, "first")
    assert cli(["experiment", "run", str(first), "--data-root", str(data), "--out", str(out)]) == 1
    capsys.readouterr()
    manifest = (out / "experiment.json").read_bytes()
    argv = ["experiment", "run", str(_spec_file(tmp_path, "second")), "--data-root", str(data), "--out", str(out)]
    for dry_run in ([], ["--dry-run"]):
        assert cli([*argv, *dry_run]) == 2
        assert one_line_error(capsys) == (
            f"liquidgs experiment: error: {out}: holds the experiment 'first', not 'second'; choose another --out"
        )
    assert (out / "experiment.json").read_bytes() == manifest


def test_the_same_spec_with_more_runs_updates_its_folder_with_a_note(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(runner, "execute_run", _fake_training([]))
    data, out = tmp_path / "data", tmp_path / "out"
    cli(["experiment", "run", str(_spec_file(tmp_path)), "--data-root", str(data), "--out", str(out)])
    assert "changed since it last ran" not in capsys.readouterr().err
    cli(["experiment", "run", str(_spec_file(tmp_path, seeds=(0, 1))), "--data-root", str(data), "--out", str(out)])
    assert f"note: spec 'e' changed since it last ran in {out}" in capsys.readouterr().err
    assert len(json.loads((out / "experiment.json").read_text())["runs"]) == 2


def test_ctrl_c_stops_an_experiment_no_new_run_starts(tmp_path, capsys, monkeypatch, request):
    """Before: the current training stopped, then every remaining run was started before exit 130."""
    calls: list = []
    monkeypatch.setattr(runner, "execute_run", _fake_training(calls, interrupt_at=1))
    # Python raises KeyboardInterrupt on SIGINT only if SIGINT was not ignored when it started, and a
    # background job of a non-interactive shell (a CI runner's, say) starts with it ignored.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    request.addfinalizer(lambda: signal.signal(signal.SIGINT, previous))
    spec = _spec_file(tmp_path, seeds=(0, 1, 2, 3))
    argv = ["experiment", "run", str(spec), "--data-root", str(tmp_path / "data"), "--out", str(tmp_path / "out")]
    assert cli([*argv, "--parallel", "1"]) == 130
    assert calls == ["tiny-a-mlp-s0"]
    assert capsys.readouterr().err.strip().endswith(
        "liquidgs experiment: interrupted: 3 of 4 runs not started; the same command resumes the experiment"
    )
