"""kill -9 at random moments, and inside checkpoint and results writes: resume reaches the
uninterrupted result bit for bit (CPU, one thread)."""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from tiny_runs import tiny_flags

SRC = Path(__file__).resolve().parents[1] / "src"

# A checkpoint every 5 steps: the kills land between many of them.
FLAGS = [
    "--field", "mlp", *tiny_flags({"checkpoint_every": 5}),
    "--eval.lpips-weights", "/nonexistent-lpips-weights", "--device", "cpu",
]  # fmt: skip

# Runs the CLI; with a target, SIGKILLs itself just before the n-th os.replace onto that file,
# i.e. with the temporary fully written and the old file still in place.
LAUNCHER = """
import os, signal, sys
target, nth = sys.argv[1], int(sys.argv[2])
real_replace, calls = os.replace, []
def replace(src, dst):
    if os.path.basename(str(dst)) == target:
        calls.append(dst)
        if len(calls) == nth:
            os.kill(os.getpid(), signal.SIGKILL)
    return real_replace(src, dst)
os.replace = replace
from liquidgs.cli import main
sys.exit(main(sys.argv[3:]))
"""


def launch(args: list[str], target: str = "-", nth: int = 0) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(SRC), "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    return subprocess.Popen(
        [sys.executable, "-c", LAUNCHER, target, str(nth), *args],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


def restart_args(out: Path, scene: Path) -> list[str]:
    resume = ["--resume"] if (out / "checkpoint.pt").exists() else []
    return ["train", "--data", str(scene), "--out", str(out), *FLAGS, *resume]


@pytest.mark.slow
def test_kill_9_at_random_moments_then_resume_is_bit_exact(puppet_scene, tmp_path):
    scene = puppet_scene
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    reference = launch(["train", "--data", str(scene), "--out", str(whole), *FLAGS])
    assert reference.wait(timeout=120) == 0, reference.stderr.read()

    rng = random.Random(9)
    kills = [("checkpoint.pt", 3), ("random", 0), ("results.json", 1), ("random", 0)]
    for target, nth in kills:
        if (killed / "results.json").exists():
            break
        if target == "random":
            process = launch(restart_args(killed, scene))
            try:  # a run that ends before its kill moment is not waited for
                process.wait(timeout=rng.uniform(2.0, 6.0))
            except subprocess.TimeoutExpired:
                process.send_signal(signal.SIGKILL)
        else:
            process = launch(restart_args(killed, scene), target, nth)
        code = process.wait(timeout=120)
        assert code in (0, -signal.SIGKILL), process.stderr.read()
        if target != "random":
            assert code == -signal.SIGKILL, f"the kill inside the {target} write did not happen"
            assert not (killed / "results.json").exists()
    final = launch(restart_args(killed, scene))
    assert final.wait(timeout=120) == 0, final.stderr.read()

    a = torch.load(whole / "checkpoint.pt", weights_only=True)
    b = torch.load(killed / "checkpoint.pt", weights_only=True)
    for group in ("params", "field"):
        for key, value in a[group].items():
            assert torch.equal(value, b[group][key]), f"{group}.{key}"
    ra = json.loads((whole / "results.json").read_text())
    rb = json.loads((killed / "results.json").read_text())
    assert ra["final"] == rb["final"] and ra["num_gaussians"] == rb["num_gaussians"]
    # Nothing half-written is left: no temporaries, no lock.
    assert not [p.name for p in killed.iterdir() if p.name.startswith(".")]
