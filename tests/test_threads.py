"""The thread count of a training (issue 28 item 5): one rule for `liquidgs train` and every run of
`experiment run`, and recorded in results.json, since results depend on it."""

from __future__ import annotations

import json

import pytest
import torch

from liquidgs.cli import main as cli
from liquidgs.errors import ConfigError
from liquidgs.experiments import runner
from liquidgs.train.run import DEFAULT_THREADS, training_threads
from shared_data import use_optional_lpips
from tiny_runs import tiny_flags


@pytest.fixture(autouse=True)
def keep_torch_threads(monkeypatch):
    use_optional_lpips(monkeypatch)
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


def test_the_thread_count_is_omp_num_threads_else_one(monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    assert training_threads() == DEFAULT_THREADS == 1
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert training_threads() == 3
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv("OMP_NUM_THREADS", bad)
        with pytest.raises(ConfigError, match=f"OMP_NUM_THREADS='{bad}': the thread count must be a positive"):
            training_threads()


@pytest.mark.parametrize("parallel", [1, 2, 4])
def test_experiment_runs_take_the_threads_train_takes(parallel, monkeypatch):
    """Before, `--parallel 1` left torch its default (every core) and more slots split the cores:
    a spec's run and the same run trained by hand in the same shell differed."""
    monkeypatch.setattr(runner, "_gpu_count", lambda: 0)
    assert runner._slot_environments(parallel) == [{}] * parallel  # each run's environment: the shell's


def test_results_record_the_thread_count_and_a_static_run_does_not_depend_on_it(puppet_scene, tmp_path, monkeypatch):
    """The compiled kernels give the same bits for any thread count (before, the rasteriser's
    backward did not, and a static run trained with 1 and 2 threads drifted apart). A field's own
    torch matrix products still depend on it, so only the static model is held to this."""
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    torch.set_num_threads(2)  # what torch starts with on a 2-core machine: train sets its own
    args = ["train", "--data", str(puppet_scene), "--field", "static", *tiny_flags({"iterations": 20})]
    assert cli([*args, "--out", str(tmp_path / "one")]) == 0
    assert json.loads((tmp_path / "one" / "results.json").read_text())["threads"] == 1
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    assert cli([*args, "--out", str(tmp_path / "two")]) == 0
    assert json.loads((tmp_path / "two" / "results.json").read_text())["threads"] == 2
    one, two = (torch.load(tmp_path / run / "checkpoint.pt", weights_only=True)["params"] for run in ("one", "two"))
    for key, value in one.items():
        assert torch.equal(value, two[key]), key
