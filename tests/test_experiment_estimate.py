"""`experiment run --dry-run`'s GPU-time estimate: measured it/s where the GPU acceptance left one,
else FLOPs under the assumptions it prints."""

from __future__ import annotations

import json

import pytest

from liquidgs.experiments import BUILTIN_SPECS, expand
from liquidgs.experiments import estimate as est
from liquidgs.experiments.spec import DNERF_SCENES, NERFDS_SCENES
from liquidgs.fields import build_field
from tiny_runs import run_cli


@pytest.fixture(scope="module")
def data_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("roots")
    for dataset, scenes in (("dnerf", DNERF_SCENES), ("nerfds", NERFDS_SCENES)):
        for scene in scenes:
            (root / dataset / scene).mkdir(parents=True)
    return root


def test_flops_estimate_is_the_fields_forward_and_backward_at_the_stated_assumptions(data_root, tmp_path):
    runs = list(expand(BUILTIN_SPECS["paper-dnerf"], data_root / "dnerf", tmp_path / "e").runs)
    got = est.estimate(runs, rates={})
    expected = 0.0
    for run in runs:
        cfg = run.train_config()
        flops = build_field(cfg.field_config()).flops_per_gaussian()
        expected += 3 * flops * est.ASSUMED_GAUSSIANS * cfg.iterations / est.ASSUMED_FLOPS_PER_S
    assert got.seconds == pytest.approx(expected) and got.measured_runs == 0
    assert "24 runs from FLOPs, a lower bound" in got.line(24) and "no GPU figure measured yet" in got.line(24)


def test_a_measured_rate_replaces_the_flops_estimate_for_its_preset_and_field(data_root, tmp_path):
    records = tmp_path / "gpu.jsonl"
    record = {"benchmark": "gpu-acceptance", "preset": "dnerf", "field": "mlp", "iterations_per_second": 20.0,
              "device_name": "NVIDIA H200"}  # fmt: skip
    records.write_text(json.dumps(record) + "\n" + '{"cut off')
    rates = est.measured_rates(records)
    assert rates == {("dnerf", "mlp"): (20.0, "NVIDIA H200")}
    runs = list(expand(BUILTIN_SPECS["paper-dnerf"], data_root / "dnerf", tmp_path / "e").runs)
    mlp = [r for r in runs if r.field == "mlp"]
    assert est.estimate(mlp, rates).seconds == pytest.approx(8 * 40_000 / 20.0)
    assert "8 runs from measured it/s on NVIDIA H200" in est.estimate(runs, rates).line(24)


@pytest.mark.parametrize(("spec", "root", "runs"), [("paper-dnerf", "dnerf", 24), ("noise-study", "", 60)])
def test_dry_run_prints_the_run_count_and_the_estimate(data_root, tmp_path, spec, root, runs):
    args = ["experiment", "run", spec, "--data-root", str(data_root / root), "--out", str(tmp_path / spec)]
    code, out, err = run_cli([*args, "--dry-run"])
    assert code == 0, err
    assert f"{runs} runs (0 done)" in out and f"GPU-time estimate for the {runs} runs to train" in out
