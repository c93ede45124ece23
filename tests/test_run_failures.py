"""Runs that fail are recorded as failed, never as finished, and lose nothing (issue 28):
collapsed renders (the guard during training, the check of the final evaluation), a field whose
evaluation-mode output is non-finite, and a full disk under the checkpoint, the lock and a
generated scene."""

from __future__ import annotations

import errno
import json

import numpy as np
import pytest
import torch

from field_plugins import plugin, use_registry, write_plugin
from liquidgs.cli import main as cli
from liquidgs.commands.train import resolve_config
from liquidgs.data import generate_synthetic
from liquidgs.errors import LiquidGSError
from liquidgs.eval.collapse import collapse_reason
from liquidgs.train.run import load_run
from liquidgs.train.run_folder import LOCK_NAME, run_folder_lock, write_checkpoint
from liquidgs.train.trainer import RunCollapsed, Trainer
from shared_data import use_optional_lpips
from tiny_runs import one_line_error, tiny_flags

# Fields that train like a static scene and misbehave only in evaluation mode, as a buggy field's
# eval branch does: one gives NaN, one moves every Gaussian out of view (a black, flat render).
EVAL_MODE_FIELDS = """
    import torch
    from torch import nn

    from liquidgs.fields import DeformationField, register as register_field

    class EvalOnly(DeformationField):
        SHIFT = 0.0

        def __init__(self, config):
            super().__init__(config)
            self.offset = nn.Parameter(torch.zeros(3))

        def deltas(self, xyz, t):
            d_xyz = xyz * 0 + self.offset
            if not self.training:
                d_xyz = d_xyz + self.SHIFT
            return d_xyz, xyz.new_zeros(xyz.shape[0], 4), xyz.new_zeros(xyz.shape[0], 3)

        def flops_per_gaussian(self):
            return 3

    class EvalNaN(EvalOnly):
        SHIFT = float("nan")

    class EvalGone(EvalOnly):
        SHIFT = 1.0e4

    def register():
        register_field("evalnan", EvalNaN, presets=["tiny"])
        register_field("evalgone", EvalGone, presets=["tiny"])
"""


@pytest.fixture(autouse=True)
def optional_lpips(monkeypatch):
    use_optional_lpips(monkeypatch)


@pytest.fixture
def eval_mode_fields(tmp_path, monkeypatch):
    entry_point = write_plugin(tmp_path, "eval_mode_fields", EVAL_MODE_FIELDS, monkeypatch)
    use_registry(monkeypatch, [plugin("eval-mode-fields", entry_point)])


# ----------------------------------------------------------------- collapse
def summary(psnr: float, background: float, flat: int, views: int = 4) -> dict:
    return {"psnr": psnr, "background_psnr": background, "flat_views": flat, "n_views": views}


def test_the_collapse_check_of_an_evaluation():
    # The run: every test render black on a black-background scene, 20.798 vs 20.799 dB.
    assert "every test render is one flat colour" in collapse_reason(summary(20.798, 20.799, flat=4), learned=True)
    assert "no better than the background alone" in collapse_reason(summary(20.85, 20.8, flat=1), learned=True)
    assert collapse_reason(summary(23.7, 20.99, flat=0), learned=True) is None  # 600 steps at the preset's rate
    # A run of a few steps that never got above the background did not collapse: it is too short to say.
    assert collapse_reason(summary(18.7, 19.7, flat=0), learned=False) is None


def test_a_run_too_short_to_beat_the_background_finishes_with_a_note(puppet_scene, tmp_path, capsys):
    """8 steps leave the puppet worse than an empty render (18.7 vs 19.7 dB): not a collapse (it never
    learned), but the user is told."""
    flags = tiny_flags({"iterations": 8, "eval.start": 8})
    assert cli(["train", "--data", str(puppet_scene), "--field", "static", "--out", str(tmp_path / "r"), *flags]) == 0
    assert "is no better than the background alone" in " ".join(capsys.readouterr().err.split())  # rich wraps
    assert (tmp_path / "r" / "results.json").is_file()


def test_the_guard_stops_training_that_falls_back_to_the_background(puppet_scene, tmp_path):
    args = ["--data", str(puppet_scene), "--field", "mlp", "--out", str(tmp_path), *tiny_flags()]
    cfg, run_dir = resolve_config(args)
    trainer = Trainer(cfg, run_dir)
    for step in range(1, 200):  # 25 dB where the background alone scores 20: it learned
        trainer._guard_divergence(step, 25.0, 20.0)
    with pytest.raises(RunCollapsed, match=r"no better than the background alone at iteration 2\d\d \(20.\d dB, back"):
        for step in range(200, 400):  # 19 dB: less than the 10 dB the drop guard needs, worse than empty
            trainer._guard_divergence(step, 19.0, 20.0)


def test_a_field_learning_rate_that_blacks_out_the_scene_is_a_failed_run(puppet_scene, tmp_path, capsys):
    """The issue's case, shortened: a field learning rate 10,000x the preset's turns every render of
    the puppet (black background) black; exit 2, no results.json, a record of why, resumable."""
    out = tmp_path / "run"
    flags = tiny_flags({"optim.field_lr_init": 50.0, "optim.field_lr_final": 50.0})
    assert cli(["train", "--data", str(puppet_scene), "--field", "mlp", "--out", str(out), *flags]) == 2
    err = one_line_error(capsys)
    assert "the run collapsed: every test render is one flat colour (2 views) at iteration 40" in err
    assert "try a lower field learning rate" in err and not (out / "results.json").exists()
    record = {"reason": err.split("error: ")[1], "checkpoint_iteration": 40}
    assert json.loads((out / "failure.json").read_text()) == record
    assert cli(["train", "--out", str(out), "--resume"]) == 2  # resumed: evaluated again, failed again
    assert "every test render is one flat colour" in one_line_error(capsys)
    assert load_run(out).progress_label == f"failed run (why: {out / 'failure.json'}): checkpoint at iteration 40"


def test_final_renders_that_are_all_background_are_never_a_finished_run(
    puppet_scene, tmp_path, capsys, eval_mode_fields
):
    out = tmp_path / "run"
    assert cli(["train", "--data", str(puppet_scene), "--field", "evalgone", "--out", str(out), *tiny_flags()]) == 2
    err = one_line_error(capsys)
    assert "the run collapsed: every test render is one flat colour" in err and "not recorded as finished" in err
    assert not (out / "results.json").exists()
    assert json.loads((out / "failure.json").read_text())["checkpoint_iteration"] == 40
    assert torch.load(out / "checkpoint.pt", weights_only=True)["state"]["iteration"] == 40


# ----------------------------------------------------------------- nothing lost
def test_a_field_non_finite_in_evaluation_mode_is_one_line_and_keeps_the_training(
    puppet_scene, tmp_path, capsys, eval_mode_fields
):
    out = tmp_path / "run"
    flags = tiny_flags({"eval.start": 40})  # the only evaluation is the final one
    assert cli(["train", "--data", str(puppet_scene), "--field", "evalnan", "--out", str(out), *flags]) == 2
    err = one_line_error(capsys)
    assert "field 'evalnan' gives non-finite Gaussians in evaluation mode at iteration 40" in err
    assert f"last good checkpoint in {out} is kept (iteration 40)" in err
    assert torch.load(out / "checkpoint.pt", weights_only=True)["state"]["iteration"] == 40
    assert not (out / "results.json").exists() and (out / "failure.json").is_file()


# ----------------------------------------------------------------- a full disk
def torch_save_on_a_full_disk(obj, file):
    """What torch.save does when the disk fills: its zip writer turns the file's OSError(ENOSPC)
    into a RuntimeError raised while handling it (measured on a 256 KB tmpfs, torch 2.13)."""
    try:
        file.write(b"partial")
        raise OSError(errno.ENOSPC, "No space left on device")
    except OSError:
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 704 vs 598") from None


def test_a_full_disk_under_torch_save_is_one_line_naming_the_file(tmp_path, monkeypatch):
    contents = {"params": {"means": torch.zeros(2, 3)}}
    path = write_checkpoint(tmp_path, contents)
    before = path.read_bytes()
    monkeypatch.setattr(torch, "save", torch_save_on_a_full_disk)
    with pytest.raises(LiquidGSError) as err:
        write_checkpoint(tmp_path, contents)
    assert str(err.value) == f"no space left on {tmp_path} while writing checkpoint.pt; the previous file is kept"
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["checkpoint.pt"]


def test_a_full_disk_leaves_no_lock_behind(tmp_path, monkeypatch):
    import liquidgs.train.run_folder.lock as lock

    def full(*args):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(lock.os, "pwrite", full)
    run_dir = tmp_path / "new" / "run"
    message = f"no space left on {run_dir} while writing {LOCK_NAME}; nothing was written"
    with pytest.raises(LiquidGSError, match=message), run_folder_lock(run_dir):
        pass
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_leaves_no_partial_synthetic_scene(tmp_path, monkeypatch):
    def full(*args, **kwargs):  # the scene's last file
        raise OSError(errno.ENOSPC, "No space left on device")

    out = tmp_path / "scene"
    with monkeypatch.context() as patch:
        patch.setattr(np, "save", full)
        with pytest.raises(LiquidGSError, match=f"no space left on {tmp_path} .* scene {out}; nothing was written"):
            generate_synthetic("puppet", out, size=8, frames=8)
    assert list(tmp_path.iterdir()) == []
    generate_synthetic("puppet", out, size=8, frames=8)
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    monkeypatch.setattr(np, "save", full)
    with pytest.raises(LiquidGSError, match="the previous scene is kept"):
        generate_synthetic("puppet", out, size=8, frames=8, seed=1)
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before
    assert [p.name for p in tmp_path.iterdir()] == ["scene"]
