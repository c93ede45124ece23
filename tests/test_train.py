"""Trainer smoke tests, bit-exact resume, divergence guard, and bad input handling."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from liquidgs.cli import main as cli
from liquidgs.commands.train import resolve_config, train
from liquidgs.data import generate_synthetic, synthetic
from liquidgs.data.synthetic import Primitive
from liquidgs.errors import ConfigError
from liquidgs.train.config import config_hash, identity, legacy_identity, load_yaml, preset_config, save_yaml
from liquidgs.train.run_folder import RESULTS_FORMAT
from liquidgs.train.trainer import Trainer, TrainingDiverged
from shared_data import optional_lpips_dir, use_optional_lpips
from tiny_runs import interrupt_at, one_line_error, run_train, tiny_flags

# The smoke runs: 800 random points, a longer warm-up, densifying every 10 steps with a reset at 25,
# three frames timed, a checkpoint at 20 (the resume test stops at 21, just after it).
SMOKE_CHANGES = {
    "warmup": 10, "init_points": 800, "sh_interval": 15, "densify.start": 10, "densify.interval": 10,
    "densify.opacity_reset_interval": 25, "eval.fps_frames": 3, "checkpoint_every": 20,
}  # fmt: skip
SMOKE_FLAGS = tiny_flags(SMOKE_CHANGES)


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory) -> Path:
    root = generate_synthetic("puppet", tmp_path_factory.mktemp("scene") / "puppet", size=40, frames=24, seed=1)
    return Path(root) / "dnerf"


@pytest.fixture(autouse=True)
def optional_lpips(monkeypatch):
    use_optional_lpips(monkeypatch)


@pytest.mark.parametrize("field", ["static", "mlp", "cfc", "sde"])
def test_each_field_trains_and_writes_a_complete_run(small_scene, tmp_path, field):
    out = tmp_path / field
    results = run_train(["--data", str(small_scene), "--field", field, "--out", str(out), *SMOKE_FLAGS])
    for name in ("config.yml", "checkpoint.pt", "results.json", "per_view.json"):
        assert (out / name).is_file(), name
    assert list((out / "tensorboard").iterdir()), "TensorBoard events expected"
    on_disk = json.loads((out / "results.json").read_text())
    assert on_disk == json.loads(json.dumps(results.to_json())) and on_disk["format"] == RESULTS_FORMAT
    assert on_disk["final"]["iteration"] == 40 and on_disk["evaluated_at"] == [20, 40]
    assert on_disk["best_of"]["iteration"] in (20, 40) and "model selection" in on_disk["best_of"]["note"]
    assert on_disk["final"]["psnr"] > 8.0 and on_disk["fps"] > 0
    assert on_disk["lpips_backbone"] == "alex"
    if optional_lpips_dir():
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
    interrupt_at(21, [*flags, "--out", str(interrupted)], monkeypatch)
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


def globe(time: float) -> list[Primitive]:
    """A bright globe that fills most of every view (on a black background): when the
    opacity reset makes every Gaussian nearly transparent, the render goes almost black."""
    return [
        Primitive("globe", "sphere", (1.25,), ((0.9, 0.8, 0.6), (0.9, 0.8, 0.6)), "checker", 0.5,
                  np.eye(3), np.array([0.0, 0.0, 0.1 * time]))
    ]  # fmt: skip


@pytest.fixture(scope="module")
def globe_scene(tmp_path_factory) -> Path:
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(synthetic.SCENES, "globe", globe)
        root = generate_synthetic("globe", tmp_path_factory.mktemp("globe") / "globe", size=32, frames=16, seed=0)
    return Path(root) / "dnerf"


GLOBE_FLAGS = ["--field", "mlp", "--preset", "tiny", "--iterations", "260", "--init-points", "1500", "--warmup", "60",
               "--densify.start", "40", "--densify.interval", "40", "--densify.opacity-reset-interval", "150",
               "--eval.start", "260", "--eval.fps-frames", "2", "--checkpoint-every", "50"]  # fmt: skip


@pytest.mark.slow  # a long run through an opacity reset
def test_opacity_reset_that_drops_psnr_by_more_than_10_db_is_not_a_divergence(globe_scene, tmp_path, monkeypatch):
    psnrs: list[float] = []
    original_step = Trainer.train_step

    def record(self, step):
        stats = original_step(self, step)
        psnrs.append(stats["psnr"])
        return stats

    monkeypatch.setattr(Trainer, "train_step", record)
    results = run_train(["--data", str(globe_scene), "--out", str(tmp_path / "run"), *GLOBE_FLAGS])
    before = sum(psnrs[130:150]) / 20  # the 20 steps before the reset at 150
    assert min(psnrs[150:160]) < before - 10, psnrs[140:170]  # the reset drops PSNR by more than 10 dB
    assert sum(psnrs[-20:]) / 20 > before - 3, psnrs[-20:]  # ... and training recovers
    assert results.final["iteration"] == 260


@pytest.mark.slow
def test_field_learning_rate_100x_too_high_is_still_caught(globe_scene, tmp_path, capsys):
    """The field switches on at 150 (itself a scheduled disturbance) and wrecks the scene at once:
    stopped within about 100 iterations, once the recovery window of the end of warm-up is over."""
    out = tmp_path / "run"
    lr = str(100 * preset_config("tiny", globe_scene).optim.field_lr_init)
    args = ["train", "--data", str(globe_scene), "--out", str(out), *GLOBE_FLAGS, "--optim.field-lr-init", lr,
            "--warmup", "150", "--iterations", "300", "--densify.opacity-reset-interval", "1000"]  # fmt: skip
    assert cli(args) == 2
    stderr = capsys.readouterr().err
    err = stderr.strip().splitlines()[-1]  # after the progress bar
    assert "Traceback" not in stderr and err.startswith("liquidgs train: error: ")
    stopped = int(re.search(r"at iteration (\d+)", err).group(1))
    assert ("training PSNR collapsed" in err or "non-finite" in err) and f"last good checkpoint in {out}" in err
    assert 150 < stopped <= 150 + 120
    kept = torch.load(out / "checkpoint.pt", weights_only=False)
    assert kept["state"]["iteration"] == 50 * ((stopped - 1) // 50)
    assert not (out / "results.json").exists()


EMPTY_PSNR = 0.0
"""A background-only PSNR below every training PSNR of the drop guard's tests: only the drop speaks."""


def test_psnr_collapse_is_detected(small_scene, tmp_path):
    cfg, run_dir = resolve_config(["--data", str(small_scene), "--out", str(tmp_path / "r"), *SMOKE_FLAGS])
    trainer = Trainer(cfg, run_dir)
    for step in range(1, 200):
        trainer._guard_divergence(step, 25.0, EMPTY_PSNR)
    with pytest.raises(
        TrainingDiverged, match=r"training PSNR collapsed at iteration 2[0-2]\d \(\d+.\d dB, best 25.0 dB\);"
    ):
        for step in range(200, 400):
            trainer._guard_divergence(step, 5.0, EMPTY_PSNR)


def test_guard_measures_from_the_last_scheduled_disturbance(small_scene, tmp_path):
    """The reset's own drop (30 -> 12 dB, recovering) is not a collapse; a collapse after the
    recovery is, and so is a drop that has not recovered once the grace window is over."""
    cfg, run_dir = resolve_config(["--data", str(small_scene), "--out", str(tmp_path / "r"), *SMOKE_FLAGS])
    trainer = Trainer(cfg, run_dir)
    n = trainer.params["means"].shape[0]
    quiet = {"reset": 0}
    for step in range(1, 600):
        trainer._guard_divergence(step, 30.0, EMPTY_PSNR)
        assert trainer._scheduled_disturbance(step, False, n, quiet) is None or step == cfg.warmup
    assert trainer._scheduled_disturbance(600, False, n, {"reset": 1}) == "opacity reset"
    trainer._start_grace(600, "opacity reset")
    for step in range(601, 660):  # 12 dB, back to 30 dB over 40 steps
        trainer._guard_divergence(step, min(30.0, 12.0 + 18.0 * (step - 601) / 40), EMPTY_PSNR)
    with pytest.raises(
        TrainingDiverged, match=r"at iteration 6\d\d \(1\d.\d dB, best 2\d.\d dB since the opacity reset at"
    ):
        for step in range(660, 900):  # inside the window: measured against the recovered level
            trainer._guard_divergence(step, 5.0, EMPTY_PSNR)

    trainer = Trainer(cfg, run_dir)
    for step in range(1, 600):
        trainer._guard_divergence(step, 30.0, EMPTY_PSNR)
    trainer._start_grace(600, "end of warm-up")
    for step in range(601, 700):  # never recovers: at the window's end the run's best applies again
        trainer._guard_divergence(step, 12.0, EMPTY_PSNR)
    with pytest.raises(TrainingDiverged, match=r"collapsed at iteration 701 \(12.0 dB, best 30.0 dB\);"):
        trainer._guard_divergence(701, 12.0, EMPTY_PSNR)

    # The other scheduled disturbances, and a densification step that is not a burst.
    assert trainer._scheduled_disturbance(300, True, n, quiet) == "SH degree step"
    assert trainer._scheduled_disturbance(cfg.warmup, False, n, quiet) == "end of warm-up"
    assert trainer._scheduled_disturbance(cfg.warmup + 1, False, n, quiet) is None
    assert trainer._scheduled_disturbance(500, False, int(n / 1.3), quiet) == "densification burst"
    assert trainer._scheduled_disturbance(500, False, int(n / 1.1), quiet) is None


def test_unknown_field_and_preset_are_one_line_errors(small_scene, tmp_path, capsys):
    assert cli(["train", "--data", str(small_scene), "--preset", "huge", "--out", str(tmp_path / "a")]) == 2
    assert "unknown preset 'huge'" in one_line_error(capsys)
    assert cli(["train", "--data", str(small_scene), "--field", "transformer", "--out", str(tmp_path / "b")]) == 2
    assert "unknown field 'transformer' (choose from static, mlp, cfc, sde, hexplane)" in one_line_error(capsys)
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
    interrupt_at(21,
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


@pytest.mark.slow  # a real-data-path training run
def test_real_data_path_trains_from_the_point_cloud_with_smooth_time(small_scene, tmp_path):
    """The Nerfies layout: Gaussians start from points.npy, annealed smooth training is on."""
    import numpy as np

    nerfies = small_scene.parent / "nerfies"
    out = tmp_path / "real"
    flags = tiny_flags(SMOKE_CHANGES, drop=("init_points",))
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
    assert results.final["psnr"] > 8.0 and (out / "results.json").is_file()


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


def test_the_d3dgs_codes_evaluation_list_is_one_flag_away(small_scene, tmp_path):
    """--eval.start 10000 --eval.also 5000 6000 7000: 5k, 6k, 7k, then every 1k from 10k (the
    reference code's test_iterations); without --eval.also the version-1 identity is as before it existed."""
    base = ["--data", str(small_scene), "--out", str(tmp_path / "r"), "--iterations", "40000"]
    cfg, run_dir = resolve_config([*base, "--eval.start", "10000", "--eval.also", "5000", "6000", "7000"])
    trainer = Trainer(cfg, run_dir)
    steps = [step for step in range(1, 40_001) if trainer.is_eval_step(step)]
    assert steps == [5000, 6000, 7000, *range(10_000, 40_001, 1000)]
    plain, _ = resolve_config(base)
    assert "also" not in legacy_identity(plain)["eval"] and identity(cfg)["eval"]["also"] == [5000, 6000, 7000]
    save_yaml(cfg, tmp_path / "config.yml")
    assert config_hash(load_yaml(tmp_path / "config.yml")) == config_hash(cfg)
    with pytest.raises(ConfigError, match="eval.also must hold iterations >= 1"):
        resolve_config([*base, "--eval.also", "0"])


def test_a_run_trains_the_same_with_or_without_lpips(small_scene, tmp_path):
    """LPIPS is a score, not part of training: whether its weights are found must not move the run
    (its layers are built before their weights are loaded; drawn from the run's generator, their
    random initial weights used to shift every random number after them)."""
    from liquidgs.eval.lpips import _FEATURE_BUILDERS

    weights = tmp_path / "weights"
    weights.mkdir()
    state = {f"features.{k}": v for k, v in _FEATURE_BUILDERS["alex"]().state_dict().items()}
    torch.save(state, weights / "alexnet_features.pth")
    flags = ["--data", str(small_scene), "--field", "sde", *SMOKE_FLAGS, "--eval.lpips-backbone", "alex"]
    scored = run_train([*flags, "--eval.lpips-weights", str(weights), "--out", str(tmp_path / "scored")])
    unscored = run_train([*flags, "--eval.lpips-weights", str(tmp_path / "none"), "--out", str(tmp_path / "unscored")])
    assert scored.final["lpips"] is not None and unscored.final["lpips"] is None
    a = torch.load(tmp_path / "scored" / "checkpoint.pt", weights_only=False)
    b = torch.load(tmp_path / "unscored" / "checkpoint.pt", weights_only=False)
    for key, value in a["params"].items():
        assert torch.equal(value, b["params"][key]), key
    assert scored.final["psnr"] == unscored.final["psnr"]
