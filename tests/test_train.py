"""Trainer smoke tests, bit-exact resume, divergence guard, and bad input handling."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from liquidgs.cli import main as cli
from liquidgs.commands.train import resolve_config, train
from liquidgs.data import generate_synthetic
from liquidgs.train.trainer import Trainer, TrainingDiverged

LPIPS_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "lpips"

SMOKE_FLAGS = [
    "--preset",
    "tiny",
    "--iterations",
    "40",
    "--warmup",
    "10",
    "--init-points",
    "800",
    "--sh-interval",
    "15",
    "--densify.start",
    "10",
    "--densify.interval",
    "10",
    "--densify.opacity-reset-interval",
    "25",
    "--eval.start",
    "20",
    "--eval.every",
    "20",
    "--eval.fps-frames",
    "3",
    "--checkpoint-every",
    "20",
]


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory) -> Path:
    root = generate_synthetic("puppet", tmp_path_factory.mktemp("scene") / "puppet", size=40, frames=24, seed=1)
    return Path(root) / "dnerf"


@pytest.fixture(autouse=True)
def lpips_weights(monkeypatch):
    if LPIPS_DIR.is_dir():
        monkeypatch.setenv("LIQUIDGS_LPIPS_WEIGHTS", str(LPIPS_DIR))


def run_train(args: list[str]) -> dict:
    cfg, run_dir = resolve_config(args)
    return train(cfg, run_dir)


def train_until_interrupted(args: list[str], monkeypatch) -> None:
    """Start a run and stop it like Ctrl-C at iteration 21, just after its checkpoint at 20."""
    original_step = Trainer.train_step

    def stop_after_checkpoint(self, step):
        if step == 21:
            raise KeyboardInterrupt
        return original_step(self, step)

    monkeypatch.setattr(Trainer, "train_step", stop_after_checkpoint)
    with pytest.raises(KeyboardInterrupt):
        run_train(args)
    monkeypatch.setattr(Trainer, "train_step", original_step)


@pytest.mark.parametrize("field", ["static", "mlp", "cfc", "sde"])
def test_each_field_trains_and_writes_a_complete_run(small_scene, tmp_path, field):
    out = tmp_path / field
    results = run_train(["--data", str(small_scene), "--field", field, "--out", str(out), *SMOKE_FLAGS])
    for name in ("config.yml", "checkpoint.pt", "results.json", "per_view.json"):
        assert (out / name).is_file(), name
    assert list((out / "tensorboard").iterdir()), "TensorBoard events expected"
    on_disk = json.loads((out / "results.json").read_text())
    assert on_disk == json.loads(json.dumps(results))
    assert on_disk["final"]["iteration"] == 40 and on_disk["evaluated_at"] == [20, 40]
    assert on_disk["best_of"]["iteration"] in (20, 40) and "model selection" in on_disk["best_of"]["note"]
    assert on_disk["final"]["psnr"] > 8.0 and on_disk["fps"] > 0
    assert on_disk["lpips_backbone"] == "alex"
    if LPIPS_DIR.is_dir():
        assert on_disk["final"]["lpips"] is not None
    assert (on_disk["field_parameters"] == 0) == (field == "static")
    assert on_disk["lambda"] == (0.05 if field == "sde" else 0.0)
    per_view = json.loads((out / "per_view.json").read_text())
    assert len(per_view["views"]) == len(list((small_scene / "test").iterdir()))


def test_resume_matches_an_uninterrupted_run(small_scene, tmp_path, monkeypatch):
    flags = ["--data", str(small_scene), "--field", "sde", "--lambda", "0.1", *SMOKE_FLAGS]
    whole = tmp_path / "whole"
    run_train([*flags, "--out", str(whole)])

    interrupted = tmp_path / "interrupted"
    train_until_interrupted([*flags, "--out", str(interrupted)], monkeypatch)
    assert not (interrupted / "results.json").exists()
    # Restarting without --resume is refused rather than silently starting over.
    assert cli(["train", *flags, "--out", str(interrupted)]) == 2
    run_train([*flags, "--out", str(interrupted), "--resume"])

    a = torch.load(whole / "checkpoint.pt", weights_only=False)
    b = torch.load(interrupted / "checkpoint.pt", weights_only=False)
    for key, value in a["params"].items():
        assert torch.equal(value, b["params"][key]), key
    for key, value in a["field"].items():
        assert torch.equal(value, b["field"][key]), key
    ra = json.loads((whole / "results.json").read_text())
    rb = json.loads((interrupted / "results.json").read_text())
    assert ra["final"]["psnr"] == rb["final"]["psnr"]


def test_divergence_guard_stops_and_keeps_the_last_good_checkpoint(small_scene, tmp_path, monkeypatch):
    out = tmp_path / "diverge"
    original_step = Trainer.train_step

    def poison(self, step):
        if step == 25:
            with torch.no_grad():
                self.params["means"][0] = float("nan")
        return original_step(self, step)

    monkeypatch.setattr(Trainer, "train_step", poison)
    with pytest.raises(TrainingDiverged, match="non-finite Gaussians at iteration 25"):
        run_train(["--data", str(small_scene), "--field", "mlp", "--out", str(out), *SMOKE_FLAGS])
    kept = torch.load(out / "checkpoint.pt", weights_only=False)
    assert kept["state"]["iteration"] == 20
    assert torch.isfinite(kept["params"]["means"]).all()
    assert not (out / "results.json").exists()


def test_psnr_collapse_is_detected(small_scene, tmp_path):
    cfg, run_dir = resolve_config(["--data", str(small_scene), "--out", str(tmp_path / "r"), *SMOKE_FLAGS])
    trainer = Trainer(cfg, run_dir)
    for step in range(1, 200):
        trainer._guard_divergence(step, 25.0)
    with pytest.raises(TrainingDiverged, match="training PSNR collapsed"):
        for step in range(200, 400):
            trainer._guard_divergence(step, 5.0)


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    assert len(err.splitlines()) == 1, err
    return err


def test_unknown_field_and_preset_are_one_line_errors(small_scene, tmp_path, capsys):
    assert cli(["train", "--data", str(small_scene), "--preset", "huge", "--out", str(tmp_path / "a")]) == 2
    assert "unknown preset 'huge'" in one_line_error(capsys)
    assert cli(["train", "--data", str(small_scene), "--field", "transformer", "--out", str(tmp_path / "b")]) == 2
    assert "invalid choice 'transformer'" in one_line_error(capsys)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_bad_data_fails_before_anything_is_written(small_scene, tmp_path, capsys):
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(small_scene, broken)
    meta = json.loads((broken / "transforms_train.json").read_text())
    del meta["frames"][0]["time"]
    (broken / "transforms_train.json").write_text(json.dumps(meta))
    out = tmp_path / "run"
    assert cli(["train", "--data", str(broken), "--field", "mlp", "--out", str(out), *SMOKE_FLAGS]) == 2
    err = one_line_error(capsys)
    assert "transforms_train.json" in err and "time" in err
    assert not out.exists()


def test_output_folder_with_another_run_is_not_touched(small_scene, tmp_path, capsys):
    out = tmp_path / "run"
    run_train(["--data", str(small_scene), "--field", "static", "--out", str(out), *SMOKE_FLAGS])
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    capsys.readouterr()
    assert cli(["train", "--data", str(small_scene), "--field", "mlp", "--out", str(out), *SMOKE_FLAGS]) == 2
    assert "holds a different run" in one_line_error(capsys)
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before

    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("precious")
    assert cli(["train", "--data", str(small_scene), "--field", "mlp", "--out", str(foreign), *SMOKE_FLAGS]) == 2
    assert "holds no liquidgs run" in one_line_error(capsys)
    assert [p.name for p in foreign.iterdir()] == ["notes.txt"]


def test_corrupt_checkpoint_on_resume_is_a_clear_error(small_scene, tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    train_until_interrupted(
        ["--data", str(small_scene), "--field", "mlp", "--out", str(out), *SMOKE_FLAGS], monkeypatch
    )
    checkpoint = out / "checkpoint.pt"
    checkpoint.write_bytes(checkpoint.read_bytes()[:1000])
    corrupt = checkpoint.read_bytes()
    capsys.readouterr()
    assert (
        cli(
            [
                "train",
                "--data",
                str(small_scene),
                "--field",
                "mlp",
                "--out",
                str(out),
                "--resume",
                *SMOKE_FLAGS,
            ]
        )
        == 2
    )
    err = one_line_error(capsys)
    assert "checkpoint.pt" in err and "corrupt" in err
    assert checkpoint.read_bytes() == corrupt and not (out / "results.json").exists()


def test_resume_refuses_changed_settings(small_scene, tmp_path, capsys):
    out = tmp_path / "run"
    run_train(["--data", str(small_scene), "--field", "static", "--out", str(out), *SMOKE_FLAGS])
    capsys.readouterr()
    assert cli(["train", "--out", str(out), "--resume", "--seed", "7"]) == 2
    assert "seed" in one_line_error(capsys)


def test_real_data_path_trains_from_the_point_cloud_with_smooth_time(small_scene, tmp_path):
    """The Nerfies layout: Gaussians start from points.npy, annealed smooth training is on."""
    import numpy as np

    nerfies = small_scene.parent / "nerfies"
    out = tmp_path / "real"
    flags = [f for f in SMOKE_FLAGS if f not in ("--init-points", "800")]
    cfg, run_dir = resolve_config(
        ["--data", str(nerfies), "--field", "cfc", "--smooth-time", "--out", str(out), *flags]
    )
    trainer = Trainer(cfg, run_dir)
    points = np.load(nerfies / "points.npy")
    assert trainer.params["means"].shape[0] == points.shape[0]
    assert trainer.dataset.kind == "real"
    noises = {trainer.time_noise(step) for step in range(cfg.warmup, cfg.warmup + 5)}
    assert len(noises) == 5 and all(abs(n) < 0.1 for n in noises)
    assert trainer.time_noise(cfg.warmup - 1) == 0.0  # no smoothing during warm-up
    results = train(cfg, run_dir)
    assert results["final"]["psnr"] > 8.0 and (out / "results.json").is_file()


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the messages of a machine without CUDA")
@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--backend", "gsplat"], "--backend gsplat needs a CUDA device"),
        (["--device", "cuda"], "sees no CUDA device"),
        (["--device", "tpu9"], "unknown device 'tpu9'"),
    ],
)
def test_unusable_device_or_backend_is_a_one_line_error(small_scene, tmp_path, capsys, flags, message):
    out = tmp_path / "run"
    assert cli(["train", "--data", str(small_scene), "--out", str(out), *SMOKE_FLAGS, *flags]) == 2
    assert message in one_line_error(capsys)
    assert not out.exists(), "nothing may be written"
