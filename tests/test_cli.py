"""The `liquidgs` dispatcher and the raster benchmark command."""

import json

from liquidgs.cli import COMMANDS
from liquidgs.cli import main as cli


def test_help_lists_every_command(capsys):
    assert cli(["--help"]) == 0
    out = capsys.readouterr().out
    for name in COMMANDS:
        assert f"  {name}" in out


def test_unknown_command_and_no_command_exit_2(capsys):
    assert cli(["fly"]) == 2
    assert "unknown command 'fly'" in capsys.readouterr().err
    assert cli([]) == 2
    assert cli(["bench"]) == 2
    assert "liquidgs bench {raster,fields}" in capsys.readouterr().err


def test_every_command_module_imports_and_has_main():
    import importlib

    for module_name, _ in COMMANDS.values():
        assert callable(importlib.import_module(module_name).main)


def test_bench_raster_prints_one_json_object_per_case(capsys):
    assert cli(["bench", "raster", "--json", "--cases", "32x32/300,48x40/500", "--repeats", "1"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.strip()]
    assert [(r["width"], r["height"], r["n_gaussians"]) for r in rows] == [(32, 32, 300), (48, 40, 500)]
    for row in rows:
        assert row["backend"] == "torch" and row["device"] == "cpu"
        assert row["forward_ms"] > 0 and row["backward_ms"] > 0 and row["peak_memory_mb"] >= 0
