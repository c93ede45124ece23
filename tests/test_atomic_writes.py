"""One writer for every file liquidgs writes (liquidgs.atomic): a full disk, a read-only file system
or a missing permission is exit 2 and one line naming the file, with nothing half-written; a PLY
sequence is a folder that is complete or absent; what a killed writer left is removed by the next.
"""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from liquidgs.cli import main as cli
from tiny_runs import one_line_error, snapshot, tiny_flags


@pytest.fixture(autouse=True)
def _one_thread(one_torch_thread):
    yield


def torch_save_on_a_full_disk(obj, file):
    """torch.save when the disk fills: into a Python file object the file's OSError(ENOSPC) is the
    context of the RuntimeError torch raises; into a path, its C++ writer raises the RuntimeError
    alone (measured on a full tmpfs)."""
    if isinstance(file, (str, os.PathLike)):
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 704 vs 598")
    try:
        file.write(b"partial")
        raise OSError(errno.ENOSPC, "No space left on device")
    except OSError:
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 704 vs 598") from None


def refuse_replace(monkeypatch, name: str, code: int) -> None:
    """os.replace onto a file called `name` fails with `code`, as the file system would."""
    real = os.replace

    def replace(src, dst, *args, **kwargs):
        if Path(dst).name == name:
            raise OSError(code, os.strerror(code), str(src), None, str(dst))
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", replace)


def hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob(".*"))


def export(run: Path, out: Path, *flags: str) -> int:
    return cli(["export", "--run", str(run), "--out", str(out), "--device", "cpu", *flags])


# ----------------------------------------------------------------- a full disk, each writer
def test_bake_on_a_full_disk_is_one_line_naming_scene_pt(tiny_mlp_run, tmp_path, capsys, monkeypatch):
    before = snapshot(tiny_mlp_run)
    monkeypatch.setattr(torch, "save", torch_save_on_a_full_disk)
    few = ["--min-keyframes", "3", "--max-keyframes", "3", "--device", "cpu"]
    assert cli(["bake", "--run", str(tiny_mlp_run), "--out", str(tmp_path / "baked"), *few]) == 2
    line = one_line_error(capsys)
    assert (
        line == f"liquidgs bake: error: no space left on {tmp_path} while writing baked/scene.pt; nothing was written"
    )
    assert list(tmp_path.iterdir()) == [] and snapshot(tiny_mlp_run) == before


def test_export_on_a_full_disk_keeps_the_older_field_pt(tiny_mlp_run, tmp_path, capsys, monkeypatch):
    out = tmp_path / "export"
    assert export(tiny_mlp_run, out) == 0
    before = snapshot(out)
    monkeypatch.setattr(torch, "save", torch_save_on_a_full_disk)
    assert export(tiny_mlp_run, out) == 2
    line = one_line_error(capsys)
    assert line == f"liquidgs export: error: no space left on {out} while writing field.pt; the previous file is kept"
    assert sorted(p.name for p in out.iterdir()) == ["canonical.ply", "field.pt"]
    assert snapshot(out)[str(out / "field.pt")] == before[str(out / "field.pt")]


def test_a_full_disk_mid_sequence_keeps_the_older_sequence_whole(tiny_mlp_run, tmp_path, capsys, monkeypatch):
    out = tmp_path / "export"
    assert export(tiny_mlp_run, out, "--sequence", "4") == 0
    capsys.readouterr()
    before = snapshot(out / "sequence")
    refuse_replace(monkeypatch, "frame_0002.ply", errno.ENOSPC)
    assert export(tiny_mlp_run, out, "--sequence", "3", "--time", "0.5") == 2
    line = one_line_error(capsys)
    assert line == (
        f"liquidgs export: error: no space left on {out} while writing sequence/frame_0002.ply; "
        "the previous sequence is kept"
    )
    assert snapshot(out / "sequence") == before and hidden(out) == []


def test_a_full_disk_in_the_web_export_leaves_no_folder(tiny_mlp_run, tmp_path, capsys, monkeypatch):
    real = Path.write_bytes

    def write_bytes(self, data):
        if self.suffix == ".bin":  # scene.bin, or its temporary
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", write_bytes)
    out = tmp_path / "export"
    assert export(tiny_mlp_run, out, "--format", "web") == 2
    line = one_line_error(capsys)
    assert line == f"liquidgs export: error: no space left on {out} while writing web/scene.bin; nothing was written"
    assert [p for p in tmp_path.rglob("*") if not p.is_dir()] == [] and hidden(tmp_path) == []


@pytest.mark.slow
@pytest.mark.parametrize(
    "code, reason", [(errno.EROFS, "read-only file system at"), (errno.EACCES, "no permission to write in")]
)
def test_splatv_on_a_refusing_file_system_keeps_the_older_file(
    tiny_mlp_run, tmp_path, capsys, monkeypatch, code, reason
):
    out = tmp_path / "export"
    fixed = ("--splatv-tolerance", "0.5")  # one fit, not the budget search: the write is what is tested
    assert export(tiny_mlp_run, out, "--format", "splatv", *fixed) == 0
    before = snapshot(out)
    refuse_replace(monkeypatch, "scene.splatv", code)
    assert export(tiny_mlp_run, out, "--format", "splatv", *fixed) == 2
    line = one_line_error(capsys)
    assert line == f"liquidgs export: error: {reason} {out} while writing scene.splatv; the previous file is kept"
    assert snapshot(out) == before


def test_a_read_only_checkpoint_keeps_the_last_one(puppet_scene, tmp_path, capsys, monkeypatch):
    import liquidgs.atomic as atomic

    real = os.replace
    checkpoints = []

    def replace(src, dst):
        if Path(dst).name == "checkpoint.pt":
            checkpoints.append(dst)
            if len(checkpoints) == 2:
                raise OSError(errno.EROFS, "Read-only file system", str(src), None, str(dst))
        return real(src, dst)

    monkeypatch.setattr(atomic.os, "replace", replace)
    out = tmp_path / "run"
    flags = tiny_flags({"iterations": 20, "eval.start": 20})
    assert cli(["train", "--data", str(puppet_scene), "--field", "mlp", "--out", str(out), *flags]) == 2
    line = one_line_error(capsys)
    assert (
        line == f"liquidgs train: error: read-only file system at {out} while writing checkpoint.pt; "
        "the previous file is kept"
    )
    assert torch.load(out / "checkpoint.pt", weights_only=True)["state"]["iteration"] == 10
    assert hidden(out) == [], hidden(out)


# ----------------------------------------------------------------- a PLY sequence is whole or absent
def test_a_shorter_sequence_replaces_the_longer_one_whole(tiny_mlp_run, tmp_path):
    out = tmp_path / "export"
    assert export(tiny_mlp_run, out, "--sequence", "5") == 0
    assert export(tiny_mlp_run, out, "--sequence", "3") == 0
    assert sorted(p.name for p in (out / "sequence").iterdir()) == [f"frame_{i:04d}.ply" for i in range(3)]
    assert hidden(out) == []


SLOW_SEQUENCE = """
import sys, time
from pathlib import Path
import liquidgs.commands.export as export
from liquidgs.cli import main

real, progress = export.write_ply, Path(sys.argv[1])

def slow(path, params, comments=()):
    written = real(path, params, comments)
    progress.write_text(str(int(progress.read_text() or 0) + 1) if progress.exists() else "1")
    time.sleep(0.5)
    return written

export.write_ply = slow
main(sys.argv[2:])
"""


@pytest.mark.slow  # a process killed mid-export
def test_a_killed_sequence_export_leaves_no_sequence_and_the_next_export_cleans_up(tiny_mlp_run, tmp_path):
    out, progress = tmp_path / "export", tmp_path / "frames-written"
    child = subprocess.Popen(
        [sys.executable, "-c", SLOW_SEQUENCE, str(progress), "export", "--run", str(tiny_mlp_run),
         "--out", str(out), "--device", "cpu", "--sequence", "50"],
        stderr=subprocess.PIPE,
    )  # fmt: skip
    deadline = time.monotonic() + 120
    while not (progress.exists() and progress.read_text() == "3") and child.poll() is None:
        assert time.monotonic() < deadline, "the child never wrote 3 frames"
        time.sleep(0.05)
    assert child.poll() is None, child.stderr.read().decode()
    child.send_signal(signal.SIGKILL)
    child.wait()
    child.stderr.close()
    assert not (out / "sequence").exists()
    assert [p.name.startswith(".sequence.partial-") for p in out.iterdir() if p.is_dir()] == [True]

    assert export(tiny_mlp_run, out, "--sequence", "2") == 0
    assert sorted(p.name for p in (out / "sequence").iterdir()) == ["frame_0000.ply", "frame_0001.ply"]
    assert hidden(out) == []


# ----------------------------------------------------------------- what a killed writer left
KILLED_WRITER = """
import os, signal, sys
from pathlib import Path
from liquidgs.atomic import build_atomically, write_atomic

def die(tmp):
    tmp.write_text("half")
    os.kill(os.getpid(), signal.SIGKILL)

def build(building):
    (building / "frame_0000.ply").write_text("whole")
    write_atomic(folder / "canonical.ply", die)

folder = Path(sys.argv[1])
build_atomically(folder / "sequence", build)
"""


def test_the_next_write_removes_dead_writers_leftovers_only(tiny_mlp_run, tmp_path):
    out = tmp_path / "export"
    out.mkdir()
    killed = subprocess.run([sys.executable, "-c", KILLED_WRITER, str(out)], check=False)
    assert killed.returncode == -signal.SIGKILL
    dead = hidden(out)
    assert len(dead) == 2 and not (out / "canonical.ply").exists() and not (out / "sequence").exists()
    # The same names as a live writer's (this process) and a writer's on another host: kept.
    temporary = next(name for name in dead if name.startswith(".canonical."))
    host, pid = temporary.split(".")[2].split("-")[:2]
    live = out / temporary.replace(f"{host}-{pid}-", f"{host}-{os.getpid()}-")
    foreign = out / temporary.replace(f"{host}-", f"{'0' if host[0] != '0' else '1'}{host[1:]}-")
    for kept in (live, foreign):
        kept.write_text("being written")

    assert export(tiny_mlp_run, out) == 0
    assert hidden(out) == sorted([live.name, foreign.name])
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == ["canonical.ply", "field.pt"]


# ----------------------------------------------------------------- paths and counts
@pytest.mark.parametrize(
    "command",
    [
        ["export", "--run", "{run}"],
        ["bake", "--run", "{run}"],
        ["render", "--run", "{run}"],
    ],
)
def test_an_empty_out_is_refused(tiny_mlp_run, tmp_path, capsys, monkeypatch, command):
    monkeypatch.chdir(tmp_path)
    before = snapshot(tiny_mlp_run)
    argv = [arg.format(run=tiny_mlp_run) for arg in command]
    assert cli([*argv, "--out", ""]) == 2
    assert one_line_error(capsys).endswith("--out: an empty path; name the file or folder ('.' for the current folder)")
    assert list(tmp_path.iterdir()) == [] and snapshot(tiny_mlp_run) == before


def test_times_naming_one_file_write_and_count_it_once(tiny_mlp_run, tmp_path, capsys):
    out = tmp_path / "export"
    assert export(tiny_mlp_run, out, "--time", "-0.0", "0.0", "0.5", "0.5") == 0
    assert sorted(p.name for p in out.iterdir()) == ["canonical.ply", "field.pt", "time_0.0000.ply", "time_0.5000.ply"]
    assert f"wrote 4 files under {out}" in " ".join(capsys.readouterr().err.split())  # rich wraps lines


def test_the_viewer_says_why_a_camera_path_was_not_saved(tiny_mlp_run, tmp_path, monkeypatch):
    import numpy as np

    from liquidgs.render.camera_path import PathCamera
    from liquidgs.viewer.scenes import load_runs
    from liquidgs.viewer.server import Viewer

    path = tmp_path / "path.json"
    viewer = Viewer(load_runs([tiny_mlp_run]), port=0, camera_path_file=path)
    try:
        viewer.keyframes += [PathCamera(np.eye(4), 50.0, 0.0), PathCamera(np.eye(4), 50.0, 1.0)]
        refuse_replace(monkeypatch, "path.json", errno.EROFS)
        assert viewer.save_camera_path(None) is None
    finally:
        viewer.stop()
    assert (
        viewer.path_text.content == f"read-only file system at {tmp_path} while writing path.json; nothing was written"
    )
    assert list(tmp_path.iterdir()) == []
