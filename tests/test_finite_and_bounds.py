"""Numbers a writer would save broken, sizes that multiply cost, inputs of the wrong shape: each is
refused in one line (exit 2) naming the run, file or setting, with nothing written.

Driven through the CLI in-process (liquidgs.cli.main); the runs are copies of the tiny MLP run,
damaged the way a diverged or broken training would leave them.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest
import torch

from liquidgs.cli import main as cli
from liquidgs.train.run_folder import CHECKPOINT, read_checkpoint, write_checkpoint
from tiny_runs import snapshot


def one_error_line(capsys, code: int, argv: list[str]) -> str:
    """Runs `liquidgs ARGV`; its exit code must be `code` and stderr one line, which is returned."""
    assert cli(argv) == code, argv
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


def refused(capsys, argv: list[str], *watched: Path) -> str:
    """`liquidgs ARGV` exits 2 with one line and leaves every watched folder as it was."""
    before = snapshot(*watched)
    line = one_error_line(capsys, 2, argv)
    assert snapshot(*watched) == before, "nothing may be written"
    return line


def copy_run(run: Path, to: Path) -> Path:
    shutil.copytree(run, to, ignore=shutil.ignore_patterns("baked", "export", "renders"))
    return to


def damage_checkpoint(run: Path, change) -> Path:
    """The run's checkpoint with `change(payload)` applied, written as training writes it."""
    payload = read_checkpoint(run / CHECKPOINT)
    change(payload)
    payload.pop("format")
    write_checkpoint(run, payload)
    return run


def nan_field(payload: dict) -> None:
    """A diverged field: one weight of its last layer NaN, so every Gaussian's deltas are."""
    last_weight = [key for key in payload["field"] if key.endswith("weight")][-1]
    payload["field"][last_weight].view(-1)[0] = float("nan")


def inf_scale(payload: dict) -> None:
    payload["params"]["scales"].view(-1)[0] = float("inf")


@pytest.fixture(scope="module")
def broken_runs(tiny_mlp_run, tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("broken_runs")
    return {
        "nan field": damage_checkpoint(copy_run(tiny_mlp_run, root / "nan_field"), nan_field),
        "inf scale": damage_checkpoint(copy_run(tiny_mlp_run, root / "inf_scale"), inf_scale),
    }


WRITERS = {
    "bake": ["bake"],
    "export ply": ["export", "--sequence", "3"],
    "export plyseq": ["export", "--format", "plyseq", "--sequence", "3"],
    "export splatv": ["export", "--format", "splatv"],
    "export web": ["export", "--format", "web"],
}


@pytest.mark.parametrize("damage", ["nan field", "inf scale"])
@pytest.mark.parametrize("writer", list(WRITERS))
def test_a_non_finite_run_is_refused_by_every_writer(broken_runs, writer, damage, capsys):
    run = broken_runs[damage]
    line = refused(capsys, [*WRITERS[writer], "--run", str(run)], run)
    counted = re.search(rf"{re.escape(str(run))}: ([\d,]+) of ([\d,]+) values of .* are NaN or infinite; nothing written", line)
    assert counted and 0 < int(counted[1].replace(",", "")) <= int(counted[2].replace(",", "")), line
