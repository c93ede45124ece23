"""The GPU acceptance (scripts/gpu_acceptance.sh and `liquidgs bench gpu`): what a CPU can check."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from liquidgs.cli import main as cli
from liquidgs.data import generate_synthetic
from liquidgs.train.acceptance import (
    SCENE_MIN_GAIN_DB,
    SCENE_MIN_ITERATIONS,
    build_parser,
    scene_verdict,
    summary_lines,
)

ROOT = Path(__file__).resolve().parents[1]
RECORD = {
    "device_name": "NVIDIA H200", "torch_version": "2.11.0+cu130", "gsplat_version": "1.5.3",
    "scene": "hellwarrior", "resolution": [800, 800], "field": "mlp", "iterations": 12345,
    "train_seconds": 600.4, "iterations_per_second": 20.56, "n_gaussians": 81234, "render_fps": 143.2,
    "initial_psnr": 11.87, "psnr": 38.123, "ssim": 0.98765, "lpips": None, "lpips_metric": None,
    "evaluation": "test views at iteration 12345 of the 40000 planned (cut short by the budget)",
}  # fmt: skip


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    return Path(generate_synthetic("spinner", tmp_path_factory.mktemp("gpu") / "s", size=24, frames=8)) / "dnerf"


def test_parser_defaults_are_the_acceptance_run():
    args = build_parser().parse_args(["--data", "scene"])
    assert (args.preset, args.field, args.downscale, args.budget_s) == ("dnerf", "mlp", 1, 420.0)
    assert args.output == Path("benchmarks/gpu.jsonl") and not args.dry_run


def test_summary_names_the_gpu_and_labels_the_cut_short_evaluation():
    lines = summary_lines(RECORD)
    assert lines[0] == "GPU: NVIDIA H200 (torch 2.11.0+cu130, gsplat 1.5.3), rasteriser: gsplat"
    assert "12345 iterations in 600 s = 20.6 it/s (81,234 Gaussians at the end)" in lines[1]
    assert lines[2] == "render with the field: 143.2 FPS at 800x800"
    assert lines[3].startswith("test PSNR 38.12 dB, SSIM 0.9877, LPIPS unavailable - test views at iteration 12345")
    with_lpips = summary_lines({**RECORD, "lpips": 0.0312, "lpips_metric": "LPIPS-Alex"})
    assert "LPIPS-Alex 0.0312" in with_lpips[3]


def test_the_scene_bar_passes_a_run_that_learned_and_fails_one_that_did_not():
    passed, line = scene_verdict(RECORD)
    assert passed and line.startswith("scene bar: pass - test PSNR 38.12 dB at iteration 12345, +26.25 dB over")
    assert summary_lines(RECORD)[-1] == line
    at_the_bar = {**RECORD, "iterations": SCENE_MIN_ITERATIONS, "psnr": RECORD["initial_psnr"] + SCENE_MIN_GAIN_DB}
    assert scene_verdict(at_the_bar)[0]
    flat = {**RECORD, "psnr": RECORD["initial_psnr"] + SCENE_MIN_GAIN_DB - 0.01}  # e.g. gradients that do nothing
    assert scene_verdict(flat) == (False, scene_verdict(flat)[1])
    assert scene_verdict(flat)[1].startswith(f"scene bar: FAIL (PSNR gain under {SCENE_MIN_GAIN_DB:g} dB)")
    slow = {**RECORD, "iterations": SCENE_MIN_ITERATIONS - 1}
    assert scene_verdict(slow)[1].startswith(f"scene bar: FAIL ({SCENE_MIN_ITERATIONS - 1} iterations, under")
    assert not scene_verdict({**RECORD, "psnr": float("nan")})[0]  # a diverged run


def test_dry_run_prints_the_plan_and_writes_nothing(scene, tmp_path, capsys):
    output = tmp_path / "gpu.jsonl"
    args = ["bench", "gpu", "--data", str(scene), "--budget-s", "300", "--output", str(output), "--dry-run"]
    assert cli(args) == 0
    plan = capsys.readouterr().out
    assert "(24x24, 1 test views), field mlp, preset dnerf (40000 iterations planned)" in plan
    assert "train for 300 s" in plan and f"append one JSON line to {output}" in plan
    assert not output.exists()


@pytest.mark.parametrize(
    ("flags", "words"),
    [(["--budget-s", "2"], "--budget-s must be at least 10"), (["--fps-frames", "0"], "--fps-frames must be >= 1")],
)
def test_bad_arguments_are_one_line(scene, flags, words, capsys):
    assert cli(["bench", "gpu", "--data", str(scene), "--dry-run", *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err


def test_a_machine_without_cuda_is_told_so_and_nothing_is_written(scene, tmp_path, capsys):
    if __import__("torch").cuda.is_available():
        pytest.skip("this machine has CUDA")
    output = tmp_path / "gpu.jsonl"
    assert cli(["bench", "gpu", "--data", str(scene), "--output", str(output)]) == 2
    assert "needs a CUDA device" in capsys.readouterr().err
    assert not output.exists()


BAD_SCRIPT_ARGS = [[], ["--dry-run", "out", "missing-scene"], ["--dry-run", "out", "tests"], ["a", "b", "c"]]


@pytest.mark.parametrize("args", BAD_SCRIPT_ARGS)
def test_script_refuses_bad_arguments(args):
    env = {**os.environ, "PYTHON": sys.executable}
    done = subprocess.run(["bash", "scripts/gpu_acceptance.sh", *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    assert done.returncode == 2 and len(done.stderr.strip().splitlines()) == 1
