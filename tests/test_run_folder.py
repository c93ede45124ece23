"""What a run folder guarantees: one writer, safe checkpoint loading, honest resume, labels."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch
import yaml

from liquidgs.cli import main as cli
from liquidgs.commands.train import resolve_config
from liquidgs.errors import LiquidGSError
from liquidgs.train.run_folder import (
    CHECKPOINT_FORMAT,
    LOCK_NAME,
    RESULTS_FORMAT,
    read_results,
    run_directory_state,
    run_folder_lock,
    write_results,
    writer_pid,
)
from liquidgs.train.strategy import D3DGSStrategy, DensifyConfig
from liquidgs.train.trainer import Trainer
from tiny_runs import interrupt_at, one_line_error, run_train, snapshot, tiny_flags

SRC = Path(__file__).resolve().parents[1] / "src"

FLAGS = [
    "--field", "mlp", *tiny_flags({"iterations": 30, "eval.start": 10, "eval.every": 10}),
    "--eval.lpips-backbone", "squeeze", "--eval.lpips-weights", "/nonexistent-lpips-weights",
]  # fmt: skip


@pytest.fixture(scope="session")
def scene(puppet_scene) -> Path:
    return puppet_scene


@pytest.fixture(autouse=True)
def _one_thread(one_torch_thread):
    yield


# ----------------------------------------------------------------- 1. one writer
@pytest.mark.slow
def test_a_second_writer_is_refused_with_the_folder_and_the_pid(scene, tmp_path, capsys):
    out = tmp_path / "run"
    holder = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(f"""
            import sys, time
            from liquidgs.train.run_folder import run_folder_lock
            with run_folder_lock({str(out)!r}):
                print("held", flush=True)
                time.sleep(60)
        """)],
        env={**os.environ, "PYTHONPATH": str(SRC)}, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        assert writer_pid(out) == holder.pid
        assert cli(["train", "--data", str(scene), "--out", str(out), *FLAGS]) == 2
        err = one_line_error(capsys)
        assert str(out) in err and f"PID {holder.pid}" in err
        assert not (out / "config.yml").exists()
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    # The operating system released the dead writer's lock: no stale lock.
    assert writer_pid(out) is None
    with run_folder_lock(out):
        assert writer_pid(out) == os.getpid()
    assert list(out.iterdir()) == [], "the lock file goes with its writer"
    fresh = tmp_path / "fresh"
    with run_folder_lock(fresh / "deeper"):
        assert (fresh / "deeper").is_dir()
    assert not fresh.exists(), "folders the lock created and nothing was written to are removed again"


# ----------------------------------------------------------------- 2. resume never goes back
def test_resume_that_would_go_back_is_refused_before_anything_is_written(scene, tmp_path, capsys):
    out = tmp_path / "run"
    run_train(["--data", str(scene), "--out", str(out), *FLAGS])
    before = snapshot(out)
    capsys.readouterr()
    for fewer in ("20", "15"):
        assert cli(["train", "--out", str(out), "--resume", "--iterations", fewer]) == 2
        assert "would go back" in one_line_error(capsys)
        assert snapshot(out) == before
    assert cli(["train", "--out", str(out), "--resume"]) == 0  # a plain resume still works
    assert snapshot(out) == before
    # Extending a finished run: results.json is rewritten for the new last iteration.
    assert cli(["train", "--out", str(out), "--resume", "--iterations", "35"]) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["final"]["iteration"] == 35 and results["iterations"] == 35
    assert yaml.safe_load((out / "config.yml").read_text())["iterations"] == 35


# ----------------------------------------------------------------- 3. checkpoints cannot run code
class _Payload:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def test_a_crafted_checkpoint_does_not_execute(scene, tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    interrupt_at(15, ["--data", str(scene), "--out", str(out), *FLAGS], monkeypatch)
    marker = tmp_path / "pwned"
    torch.save({"format": CHECKPOINT_FORMAT, "params": _Payload(marker)}, out / "checkpoint.pt")
    capsys.readouterr()
    for command in (["eval", "--run", str(out)], ["train", "--out", str(out), "--resume"]):
        assert cli(command) == 2
        err = one_line_error(capsys)
        assert "checkpoint.pt" in err and "corrupt or unreadable" in err
        assert not marker.exists(), f"{command[0]} executed code from a checkpoint"


# ----------------------------------------------------------------- 4. degenerate camera extent
def test_a_fixed_camera_is_reported_and_training_uses_the_points_extent(scene, tmp_path, capsys):
    import shutil

    fixed = tmp_path / "fixed"
    shutil.copytree(scene, fixed)
    meta = json.loads((fixed / "transforms_train.json").read_text())
    for frame in meta["frames"]:
        frame["transform_matrix"] = meta["frames"][0]["transform_matrix"]
    (fixed / "transforms_train.json").write_text(json.dumps(meta))
    assert cli(["data", "check", str(fixed)]) == 0
    report = capsys.readouterr().out
    assert "extent:     0.0000" in report and "DEGENERATE" in report and "all OK" not in report
    assert "all sit at one position" in report

    cfg, run_dir = resolve_config(["--data", str(fixed), "--out", str(tmp_path / "run"), *FLAGS])
    with pytest.warns(UserWarning, match="one position"):
        trainer = Trainer(cfg, run_dir)
    assert trainer.strategy.scene_extent > 1.0  # the random box of initial points, [-1.3, 1.3]^3
    assert any("densification uses" in note for note in trainer.notes)


def test_densification_never_prunes_everything_silently():
    strategy = D3DGSStrategy(DensifyConfig(start=0, interval=1, opacity_reset_interval=1), scene_extent=1e-9)
    params = torch.nn.ParameterDict(
        {
            "means": torch.nn.Parameter(torch.zeros(4, 3)),
            "scales": torch.nn.Parameter(torch.zeros(4, 3)),
            "quats": torch.nn.Parameter(torch.tensor([[1.0, 0, 0, 0]]).repeat(4, 1)),
            "opacities": torch.nn.Parameter(torch.zeros(4)),
            "sh0": torch.nn.Parameter(torch.zeros(4, 1, 3)),
            "shN": torch.nn.Parameter(torch.zeros(4, 0, 3)),
        }
    )
    optimizers = {k: torch.optim.Adam([params[k]]) for k in params}
    state = strategy.initial_state(4, torch.device("cpu"))
    means2d = torch.zeros(4, 2, requires_grad=True)
    means2d.absgrad = torch.zeros(4, 2)
    info = {"means2d": means2d, "radii": torch.ones(4), "width": 8, "height": 8}
    report = strategy.step_post_backward(params, optimizers, state, 2, info)
    assert report["pruned_all"] == 1 and params["means"].shape[0] == 1


# ----------------------------------------------------------------- 5. disk full, read-only, Ctrl-C
def test_a_full_disk_during_a_checkpoint_says_so_and_keeps_the_last_one(scene, tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    real_save = torch.save
    saves = []

    def save_until_full(obj, file):
        saves.append(1)
        if len(saves) == 2:
            file.write(b"partial")
            raise OSError(errno.ENOSPC, "No space left on device")
        real_save(obj, file)

    monkeypatch.setattr(torch, "save", save_until_full)
    assert cli(["train", "--data", str(scene), "--out", str(out), *FLAGS]) == 2
    err = one_line_error(capsys)
    assert f"no space left on {out}" in err and "checkpoint.pt" in err and "previous file is kept" in err
    monkeypatch.setattr(torch, "save", real_save)
    kept = torch.load(out / "checkpoint.pt", weights_only=True)
    assert kept["state"]["iteration"] == 10
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint.pt", "config.yml", "scene.json", "tensorboard"]


def test_read_only_file_system_is_one_line(scene, tmp_path, capsys, monkeypatch):
    import liquidgs.train.run_folder.lock as lock

    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system", str(tmp_path / "run" / LOCK_NAME))

    monkeypatch.setattr(lock.os, "open", read_only)
    assert cli(["train", "--data", str(scene), "--out", str(tmp_path / "run"), *FLAGS]) == 2
    assert "Read-only file system" in one_line_error(capsys)
    assert not (tmp_path / "run").exists()


def test_ctrl_c_names_the_kept_checkpoint_and_the_resume_command(scene, tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    original = Trainer.train_step

    def stop(self, step):
        if step == 15:
            raise KeyboardInterrupt
        return original(self, step)

    monkeypatch.setattr(Trainer, "train_step", stop)
    assert cli(["train", "--data", str(scene), "--out", str(out), *FLAGS]) == 130
    err = one_line_error(capsys)
    assert "interrupted" in err and "checkpoint at iteration 10 is kept" in err
    assert f"liquidgs train --out {out} --resume" in err

    def interrupted_import(name, *args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("importlib.import_module", interrupted_import)
    assert cli(["eval", "--run", str(out)]) == 130  # Ctrl-C while the command starts


# ----------------------------------------------------------------- 6. leftovers
def test_stale_temporaries_are_removed_on_the_next_start(scene, tmp_path, monkeypatch):
    out = tmp_path / "run"
    interrupt_at(15, ["--data", str(scene), "--out", str(out), *FLAGS], monkeypatch)
    stale = [out / ".checkpoint.abc123.tmp.pt", out / ".results.x9y8.tmp.json", out / ".config.q1.tmp.yml"]
    for path in stale:
        path.write_bytes(b"half-written")
    foreign = out / "notes.tmp.txt"  # not ours: left alone
    foreign.write_text("keep")
    run_train(["--data", str(scene), "--out", str(out), "--resume", *FLAGS])
    assert not any(path.exists() for path in stale) and foreign.exists()


def test_a_folder_with_only_a_lock_and_temporaries_counts_as_empty(scene, tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / ".liquidgs.lock").write_text("12345\n")  # a writer killed before it wrote anything
    (out / ".config.abcd.tmp.yml").write_text("data: x")
    results = run_train(["--data", str(scene), "--out", str(out), *FLAGS])
    assert results.final["iteration"] == 30 and not (out / ".config.abcd.tmp.yml").exists()


# ----------------------------------------------------------------- 7. unfinished runs are labelled
def test_readers_accept_an_unfinished_run_and_label_it(scene, tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    interrupt_at(15, ["--data", str(scene), "--out", str(out), *FLAGS], monkeypatch)
    assert cli(["eval", "--run", str(out)]) == 0
    record = json.loads((out / "eval.json").read_text())
    assert record["finished"] is False and record["iteration"] == 10 and record["iterations"] == 30
    assert "unfinished run" in record["kind"] and "final" not in record["kind"]
    assert "unfinished run" in " ".join(capsys.readouterr().out.split())
    export = tmp_path / "export"
    assert cli(["export", "--run", str(out), "--out", str(export), "--time", "-0.0"]) == 0
    assert "unfinished run: checkpoint at iteration 10 of 30" in " ".join(capsys.readouterr().err.split())
    assert (export / "time_0.0000.ply").is_file() and not (export / "time_-0.0000.ply").exists()


# ----------------------------------------------------------------- 8. TensorBoard after a resume
def scalar_steps(folder: Path, tag: str) -> list[int]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(folder / "tensorboard"))
    events.Reload()
    return [event.step for event in events.Scalars(tag)]


def test_tensorboard_shows_each_step_once_after_a_resume(scene, tmp_path, monkeypatch):
    whole, resumed = tmp_path / "whole", tmp_path / "resumed"
    run_train(["--data", str(scene), "--out", str(whole), *FLAGS])
    # Checkpoints at 15 and 30, stopped at 25: step 20 was logged, then replayed after the resume.
    interrupt_at(25, ["--data", str(scene), "--out", str(resumed), *FLAGS, "--checkpoint-every", "15"], monkeypatch)
    run_train(["--data", str(scene), "--out", str(resumed), "--resume", *FLAGS, "--checkpoint-every", "15"])
    for tag in ("train/loss", "test/psnr"):
        assert scalar_steps(resumed, tag) == scalar_steps(whole, tag), tag


# ----------------------------------------------------------------- 9. the records' formats
RESULTS_BEFORE_FORMAT = Path(__file__).parent / "data" / "results_before_format.json"
"""results.json of a 10-iteration sde run with a time jitter, written by the code before results.json
recorded its format (commit 52e35db)."""


def test_results_written_before_the_format_was_recorded_still_read(tmp_path):
    raw = json.loads(RESULTS_BEFORE_FORMAT.read_text())
    assert "format" not in raw
    (tmp_path / "results.json").write_text(RESULTS_BEFORE_FORMAT.read_text())
    results = read_results(tmp_path)
    assert results.format == RESULTS_FORMAT and results.lambda_ == 0.05 and results.perturb == {"time_jitter": 0.03}
    assert results.final["iteration"] == 10 and results.views == {"train": 6, "test": 1}
    # Written again, it holds exactly the same keys, in the same order, plus the format first.
    assert list(results.to_json().items()) == [("format", RESULTS_FORMAT), *raw.items()]
    write_results(tmp_path, results)
    assert read_results(tmp_path) == results


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda raw: [raw], "corrupt results (not a JSON object)"),
        (lambda raw: {**raw, "format": "liquidgs-results-9"}, "results format 'liquidgs-results-9' is not one"),
        (lambda raw: {k: v for k, v in raw.items() if k != "views"}, "field 'views' is missing"),
        (lambda raw: {**raw, "seed": "0"}, "field 'seed' is not an integer"),
        (lambda raw: {**raw, "lpips_normalize": 1}, "field 'lpips_normalize' is not true or false"),
        (lambda raw: {**raw, "num_gaussians": True}, "field 'num_gaussians' is not an integer"),
        (lambda raw: {**raw, "fps": 60}, None),  # a whole number is a float
        (lambda raw: {**raw, "psnr": 30.0}, "field 'psnr' is not part of liquidgs-results-1"),
    ],
)
def test_a_results_file_that_does_not_fit_its_format_is_one_error_naming_it(tmp_path, change, message):
    path = tmp_path / "results.json"
    path.write_text(json.dumps(change(json.loads(RESULTS_BEFORE_FORMAT.read_text()))))
    if message is None:
        assert read_results(tmp_path).fps == 60
        return
    with pytest.raises(LiquidGSError) as caught:
        read_results(tmp_path)
    assert str(caught.value).startswith(f"{path}: ") and message in str(caught.value)
    path.write_bytes(b"\xff")
    with pytest.raises(LiquidGSError, match="results.json: unreadable"):
        read_results(tmp_path)


@pytest.mark.slow
def test_readers_do_not_import_the_training_loop():
    readers = [
        "liquidgs.commands.evaluate", "liquidgs.commands.render", "liquidgs.commands.export",
        "liquidgs.commands.view", "liquidgs.commands.experiment", "liquidgs.viewer.scenes",
        "liquidgs.experiments.report", "liquidgs.experiments.runner", "liquidgs.train.run",
    ]  # fmt: skip
    code = f"import sys; [__import__(m) for m in {readers!r}]; print('liquidgs.train.trainer' in sys.modules)"
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    assert result.stdout.strip() == "False"


def test_a_folder_is_in_one_of_five_states(tmp_path):
    folder = tmp_path / "run"
    assert run_directory_state(folder) == "empty"
    folder.mkdir()
    (folder / LOCK_NAME).write_text("12345\n")
    (folder / ".checkpoint.ab12.tmp.pt").write_bytes(b"half")
    assert run_directory_state(folder) == "empty"  # a writer killed before it wrote a run file
    (folder / "notes.txt").write_text("mine")
    assert run_directory_state(folder) == "foreign"
    (folder / "notes.txt").unlink()
    (folder / "config.yml").write_text("field: mlp\n")
    assert run_directory_state(folder) == "configured"
    (folder / "checkpoint.pt").write_bytes(b"weights")
    assert run_directory_state(folder) == "unfinished"
    (folder / "results.json").write_text("{}")
    assert run_directory_state(folder) == "finished"
    assert run_directory_state(folder / "config.yml") == "foreign"  # a file where the folder should be
