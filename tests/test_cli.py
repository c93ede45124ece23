"""The `liquidgs` dispatcher and the raster benchmark command."""

import json
import subprocess
import sys
import textwrap

import pytest

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
    assert "liquidgs bench {raster,fields,train,gpu,acceptance,bake}" in capsys.readouterr().err


_CHILD = textwrap.dedent("""
    import sys, types
    from liquidgs import cli

    def flood(argv):
        for _ in range(100_000):
            print("x" * 100)

    def pipe_elsewhere(argv):
        print("a line")
        raise BrokenPipeError(32, "Broken pipe")

    def progress(argv):  # lines through a rich progress bar's console on stdout, as `eval` prints
        from rich.console import Console
        from rich.progress import Progress

        with Progress(console=Console()) as bar:
            for _ in range(100_000):
                bar.console.print("x" * 50, highlight=False)

    for name, main in (("flood", flood), ("pipe-elsewhere", pipe_elsewhere), ("progress", progress)):
        sys.modules[name] = types.SimpleNamespace(main=main)
        cli.COMMANDS[name] = (name, "")
    sys.exit(cli.main(sys.argv[1:]))
""")


@pytest.mark.parametrize(
    ("command", "first_line"),
    [
        # `liquidgs experiment run SPEC --dry-run | head`: the reader goes, the command stops without a word.
        ("flood", b"x" * 100 + b"\n"),
        # rich meets the gone reader by exiting 1 itself: `liquidgs experiment run SPEC | head` ends as `head` expects.
        ("progress", b"x" * 50 + b"\n"),
    ],
    ids=["plain output", "progress bar"],
)
def test_a_reader_that_stops_early_ends_the_command_quietly(command, first_line):
    child = subprocess.Popen([sys.executable, "-c", _CHILD, command], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert child.stdout.readline() == first_line
    child.stdout.close()
    assert child.wait(timeout=60) == 141
    assert child.stderr.read() == b""


@pytest.mark.slow  # a training process of its own
def test_training_into_a_pipe_closed_at_once_exits_141(tmp_path):
    """`liquidgs train ... 2>&1 | true`: the progress bar's stderr is the pipe whose reader has gone."""
    from liquidgs.data import generate_synthetic

    scene = generate_synthetic("spinner", tmp_path / "s", size=16, frames=8) / "dnerf"
    args = ["--data", str(scene), "--out", str(tmp_path / "run"), "--preset", "tiny", "--iterations", "10",
            "--warmup", "2", "--init-points", "100", "--eval.start", "10", "--eval.fps-frames", "1"]  # fmt: skip
    child = subprocess.Popen([sys.executable, "-m", "liquidgs.cli", "train", *args], stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT)  # fmt: skip
    child.stdout.close()
    assert child.wait(timeout=300) == 141


def test_a_broken_pipe_that_is_not_standard_output_is_still_an_error():
    done = subprocess.run([sys.executable, "-c", _CHILD, "pipe-elsewhere"], capture_output=True, timeout=60)
    assert done.returncode == 2
    assert done.stdout == b"a line\n"
    assert done.stderr.decode().strip() == "liquidgs pipe-elsewhere: error: a file: Broken pipe"


def test_every_command_module_imports_and_has_main():
    import importlib

    for module_name, _ in COMMANDS.values():
        assert callable(importlib.import_module(module_name).main)


@pytest.mark.parametrize("backend", ["torch", "cpu"])
def test_bench_raster_prints_one_json_object_per_case(capsys, backend):
    args = ["bench", "raster", "--json", "--cases", "32x32/300,48x40/500", "--repeats", "1", "--backend", backend]
    assert cli(args) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.strip()]
    assert [(r["width"], r["height"], r["n_gaussians"]) for r in rows] == [(32, 32, 300), (48, 40, 500)]
    for row in rows:
        assert row["backend"] == backend and row["device"] == "cpu" and row["tile_size"] == 4
        assert row["forward_ms"] > 0 and row["backward_ms"] > 0 and row["peak_memory_mb"] >= 0


@pytest.mark.slow
def test_bench_train_times_every_phase_of_real_steps(capsys, tmp_path):
    output = tmp_path / "bench.jsonl"
    args = ["bench", "train", "--json", "--size", "32", "--from-step", "120", "--steps", "4", "--output", str(output)]
    assert cli(args) == 0
    record = json.loads(capsys.readouterr().out)
    assert json.loads(output.read_text()) == record
    assert record["scene"] == "puppet" and record["resolution"] == [32, 32] and record["field"] == "mlp"
    assert record["timed_steps"] == [121, 124] and record["n_gaussians"]["min"] > 0
    assert "dynamic_gaussians" not in record  # no split on a synthetic scene
    phases = record["phases_ms"]
    assert set(phases) == {
        "data", "field_forward", "raster_forward", "loss_forward", "loss_backward", "raster_backward", "field_backward",
        "densification", "optimizer_step", "other",
    }  # fmt: skip
    # After the tiny preset's 100-step warm-up the field runs, so both of its passes take time.
    assert all(phases[name] > 0 for name in ("field_forward", "field_backward", "raster_forward", "raster_backward"))
    assert sum(phases.values()) == pytest.approx(record["ms_per_iteration"], rel=0.5)
    assert record["torch_threads"] >= 1 and record["machine"] and record["clock"] == "wall"


def test_bench_train_on_the_cpu_clock_counts_the_process_own_work(capsys, monkeypatch):
    """--clock cpu: the steps' and phases' times are the process's CPU seconds, whatever else runs."""
    import time

    ticks = iter(range(10**6))
    monkeypatch.setattr(time, "process_time", lambda: 0.001 * next(ticks))  # 1 ms a reading, no wall time
    assert cli(["bench", "train", "--json", "--size", "32", "--from-step", "2", "--steps", "3", "--clock", "cpu"]) == 0
    record = json.loads(capsys.readouterr().out)
    times = [record["ms_per_iteration"], *record["phases_ms"].values()]
    assert record["clock"] == "cpu" and all(ms == pytest.approx(round(ms)) for ms in times)  # whole readings only


def test_bench_train_takes_train_settings_for_the_timed_run(capsys):
    """A setting's cost is two bench runs on one commit: train's flags reach the trainer and the record."""
    args = ["bench", "train", "--json", "--size", "32", "--from-step", "3", "--steps", "2",
            "--init-points", "150", "--densify.start", "50", "--cameras.refine", "on"]  # fmt: skip
    assert cli(args) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["settings"] == {"init_points": 150, "densify.start": 50, "cameras.refine": "on"}
    assert record["n_gaussians"] == {"min": 150, "median": 150, "max": 150}  # nothing densified before step 50


@pytest.mark.parametrize("flag, message", [
    (["--iterations", "9"], "--iterations is the benchmark's to set"),
    (["--eval.start", "9"], "--eval.start is the benchmark's to set"),
    (["--cameras.refine", "maybe"], "--cameras.refine: unknown refine 'maybe'"),
    (["--no-such-setting", "1"], "unrecognized arguments: --no-such-setting"),
])  # fmt: skip
def test_bench_train_refuses_settings_it_owns_or_does_not_know(capsys, flag, message):
    assert cli(["bench", "train", "--size", "32", *flag]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
