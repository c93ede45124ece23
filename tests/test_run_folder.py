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
from liquidgs.train.runlock import run_folder_lock, writer_pid
from liquidgs.train.strategy import D3DGSStrategy, DensifyConfig
from liquidgs.train.trainer import Trainer
from tiny_runs import one_line_error, run_train, snapshot, tiny_flags

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


def interrupt_at(step_to_stop: int, args: list[str], monkeypatch) -> None:
    original = Trainer.train_step

    def stop(self, step):
        if step == step_to_stop:
            raise KeyboardInterrupt
        return original(self, step)

    monkeypatch.setattr(Trainer, "train_step", stop)
    with pytest.raises(KeyboardInterrupt):
        run_train(args)
    monkeypatch.setattr(Trainer, "train_step", original)


# ----------------------------------------------------------------- 1. one writer
def test_a_second_writer_is_refused_with_the_folder_and_the_pid(scene, tmp_path, capsys):
    out = tmp_path / "run"
    holder = subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(f"""
            import sys, time
            from liquidgs.train.runlock import run_folder_lock
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
    torch.save({"format": "liquidgs-checkpoint-1", "params": _Payload(marker)}, out / "checkpoint.pt")
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
    assert sorted(p.name for p in out.iterdir()) == ["checkpoint.pt", "config.yml", "tensorboard"]


def test_read_only_file_system_is_one_line(scene, tmp_path, capsys, monkeypatch):
    import liquidgs.train.runlock as runlock

    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system", str(tmp_path / "run" / runlock.LOCK_NAME))

    monkeypatch.setattr(runlock.os, "open", read_only)
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
    assert results["final"]["iteration"] == 30 and not (out / ".config.abcd.tmp.yml").exists()


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
