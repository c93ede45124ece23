"""The staged GPU acceptance (train/gpu_acceptance.py, scripts/gpu_acceptance.sh): its plan fits the
lent machine's limits, plan B's decision, records that survive a killed stage, and its bad inputs."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from argparse import Namespace
from pathlib import Path

import pytest

from liquidgs.cli import main as cli
from liquidgs.data import generate_synthetic
from liquidgs.train import gpu_acceptance as acc
from tiny_runs import one_line_error

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return Path(generate_synthetic("spinner", tmp_path_factory.mktemp("gpu") / "s", size=16, frames=8)) / "dnerf"


def test_the_plan_fits_15_minutes_with_a_3_minute_start_and_no_stage_over_9_minutes():
    acc.check_plan()
    plan = acc.stage_plan()
    assert [name for name, *_ in plan] == [stage.name for stage in acc.STAGES]
    assert all(end - start <= acc.STAGE_LIMIT_S for _, start, end, _ in plan)
    assert plan[-1][2] == acc.COMMAND_BUDGET_S < acc.COMMAND_LIMIT_S
    assert acc.MACHINE_START_S >= 180 and acc.MACHINE_START_S + acc.TRANSFER_S + acc.COMMAND_BUDGET_S <= 900
    assert plan[-1][2] - plan[-1][1] >= acc.SCENE_MIN_S
    for budget in (300, 590):  # too short for the scene stage's minimum; too close to the 600 s kill
        with pytest.raises(acc.ConfigError):
            acc.check_plan(budget)


def test_script_dry_run_prints_the_stage_plan_with_times(scene):
    env = {**os.environ, "PYTHON": sys.executable}
    done = subprocess.run(["bash", "scripts/gpu_acceptance.sh", "--dry-run", "out", str(scene)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 2 and "images are 16x16, the acceptance needs 800x800" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    code, out = _cli(["bench", "acceptance", "--out", "o", "--scene", str(scene), "--size", "16", "--dry-run"])
    assert code == 0
    assert "setup            0-60   s" in out and "scene          450-570  s" in out
    assert "= 780 s of the 900 s lent (120 s spare)" in out and "no stage over 540 s" in out


def _cli(args):
    import contextlib
    import io

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        code = cli(args)
    return code, buffer.getvalue()


def test_plan_b_decision():
    assert acc.scene_backend(acc.BuildOutcome("built", 171.4)) == ("gsplat", "gsplat (kernels built in 171 s)")
    backend, label = acc.scene_backend(acc.BuildOutcome("failed", 12.0, "nvcc fatal: unsupported gpu"))
    assert backend == "torch" and "plan B: gsplat did not build: nvcc fatal" in label
    backend, label = acc.scene_backend(acc.BuildOutcome("cut", 300.0))
    assert backend == "torch" and "stopped after 300 s" in label
    with pytest.raises(ValueError):
        acc.scene_backend(acc.BuildOutcome("running"))
    # Once the fields are done, the build may take what leaves the backends stage and the scene's minimum.
    assert acc.build_wait_s(270) == 270 - acc.STAGE["backends"].limit_s - acc.SCENE_MIN_S
    assert acc.build_wait_s(150) == 0.0


def test_field_verdict_fails_beyond_the_margin_or_on_a_missing_run():
    ok = acc.field_verdict("cfc", {"psnr": 30.2, "seconds": 9.0}, {"psnr": 30.9, "seconds": 40.0})
    assert ok["passed"] and ok["line"].startswith("cfc: pass - GPU 30.20 dB in 9 s, CPU 30.90 dB, difference -0.70")
    far = acc.field_verdict("sde", {"psnr": 28.0, "seconds": 9.0}, {"psnr": 30.9, "seconds": 40.0})
    assert not far["passed"] and "FAIL" in far["line"]
    missing = acc.field_verdict("hexplane", {"psnr": 28.0, "seconds": 9.0}, None)
    assert not missing["passed"] and missing["line"] == "hexplane: FAIL - the CPU run did not finish"


@pytest.mark.slow
def test_a_stage_killed_at_its_limit_keeps_the_records_before_it_and_the_summary_names_it(tmp_path):
    args = Namespace(out=tmp_path, budget_s=60, scene=Path("s"), work=tmp_path / "w", size=800, build_dir=tmp_path)
    run = acc.Acceptance(args)
    assert run.run_stage("setup", [sys.executable, "-c", "pass"], 30)
    child = "import subprocess, sys, time; subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)']); " \
            "time.sleep(60)"  # a stage with a child of its own, as `fields` has its CPU twins
    began = time.monotonic()
    assert not run.run_stage("fields", [sys.executable, "-c", child], 2)
    assert time.monotonic() - began < 20  # killed with its own children, not waited for
    acc.append_record(tmp_path, {"stage": "backends", "event": "start"})
    with (tmp_path / acc.RECORDS).open("a") as file:
        file.write('{"stage": "backends", "event": "res')  # a line cut by the command's kill
    lines = acc.summary_lines(acc.read_records(tmp_path))
    assert lines[0].startswith("setup: passed in")
    assert lines[2] == "fields: killed at its 2 s limit in 2 s"
    assert lines[3].startswith("backends: DID NOT FINISH") and lines[4] == "scene: not started"
    assert lines[-1] == "did not finish: fields, backends"
    code, out = _cli(["bench", "acceptance", "--out", str(tmp_path), "--summary"])
    assert code == 0 and out.splitlines()[-1] == "did not finish: fields, backends"


def test_no_gpu_is_one_line_and_exit_2(scene, tmp_path, capsys):
    if __import__("torch").cuda.is_available():
        pytest.skip("this machine has CUDA")
    assert cli(["bench", "acceptance", "--out", str(tmp_path / "o"), "--scene", str(scene), "--size", "16"]) == 2
    assert "no CUDA GPU" in one_line_error(capsys) and not (tmp_path / "o").exists()


def test_a_missing_scene_is_one_line(tmp_path, capsys):
    assert cli(["bench", "acceptance", "--out", str(tmp_path), "--scene", str(tmp_path / "nope"), "--dry-run"]) == 2
    assert "no D-NeRF scene there" in one_line_error(capsys)


def test_every_field_run_is_the_same_command_on_both_devices(tmp_path):
    gpu = acc.field_train_args(Path("scene"), "sde", "cuda", tmp_path / "a")
    cpu = acc.field_train_args(Path("scene"), "sde", "cpu", tmp_path / "a")
    assert [a for a in gpu if a != "cuda"] == [a for a in cpu if a != "cpu"]
    assert "--iterations=300" in gpu and "--backend" in gpu and gpu[gpu.index("--backend") + 1] == "torch"
