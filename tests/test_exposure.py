"""Exposure compensation (a colour correction per training frame) and fixed sizes (a field that moves
and turns Gaussians but does not resize them): on for captures, off for D-NeRF and the paper's specs,
written to the run folder, resumed bit-exactly, and read back by a run made before they existed."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import yaml

from liquidgs.data import generate_synthetic
from liquidgs.data.loading import load_dataset
from liquidgs.data.perturb import PerturbConfig, _rng, perturb_dataset
from liquidgs.data.scene import DataConfig
from liquidgs.errors import ConfigError, LiquidGSError
from liquidgs.train.config import load_yaml
from liquidgs.train.exposure import ExposureCompensation, ExposureConfig, compensates
from liquidgs.train.model import deform
from liquidgs.train.run import load_run
from shared_data import use_optional_lpips
from tiny_runs import interrupt_at, run_cli, run_train, tiny_flags


@pytest.fixture(autouse=True)
def optional_lpips(monkeypatch):
    use_optional_lpips(monkeypatch)


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    return generate_synthetic("puppet", tmp_path_factory.mktemp("capture") / "puppet", size=24, frames=16, seed=2)


def _frames(*names: str) -> list:
    return [SimpleNamespace(name=name) for name in names]


def test_on_for_captures_off_for_dnerf():
    assert compensates(ExposureConfig(), "nerfies") and not compensates(ExposureConfig(), "dnerf")
    assert not compensates(ExposureConfig(apply="off"), "nerfies") and compensates(ExposureConfig(apply="on"), "dnerf")
    with pytest.raises(ConfigError, match="exposure.max-change must be a finite number > 0"):
        ExposureConfig(max_change=0)


def test_a_capture_switch_of_another_value_names_the_setting(tmp_path, capsys):
    """cameras.refine, motion.apply and exposure.apply share their choices: a config.yml with another
    value is one line naming the file and the setting, and trains nothing."""
    for group, key in (("cameras", "refine"), ("motion", "apply"), ("exposure", "apply")):
        out = tmp_path / group
        out.mkdir()
        (out / "config.yml").write_text(yaml.safe_dump({"data": {"path": str(tmp_path)}, group: {key: "sometimes"}}))
        code, _, stderr = run_cli(["train", "--config", str(out / "config.yml"), "--out", str(out / "run")])
        assert code == 2 and stderr.count("\n") == 1, stderr
        assert f"config.yml: setting '{group}.{key}' must be one of auto, on, off, got 'sometimes'" in stderr
        assert not (out / "run").exists()
    with pytest.raises(ConfigError, match="exposure.apply must be one of auto, on, off, got 'sometimes'"):
        ExposureConfig(apply="sometimes")  # built in code, past the settings loader


def test_a_frame_s_correction_learns_its_brightness_and_only_its_own():
    exposure = ExposureCompensation(ExposureConfig(lr=0.02, lr_final=0.002), _frames("a", "b"), 200, "cpu", 1e-15)
    render = torch.rand(8, 8, 3) * 0.5 + 0.2
    shot = render * torch.tensor([1.2, 1.1, 0.9])  # frame "b" came out brighter in red, darker in blue
    for step in range(200):
        (exposure.correct(render, 1) - shot).abs().mean().backward()
        exposure.step(step)
    error = (exposure.correct(render, 1).detach() - shot).abs().mean()
    assert error < 0.15 * (render - shot).abs().mean()
    assert not exposure.gains[0].any() and not exposure.offsets[0].any()  # a frame never drawn is as rendered
    report = exposure.report(200)
    assert [f["name"] for f in report["frames"]] == ["a", "b"] and report["largest_gain"] > 0.05


def test_a_correction_past_its_bound_is_one_line_naming_the_frame():
    exposure = ExposureCompensation(ExposureConfig(max_change=0.3), _frames("000001", "000002"), 10, "cpu", 1e-15)
    with torch.no_grad():
        exposure.offsets[1, 2] = 0.4
    exposure.correct(torch.zeros(2, 2, 3), 0).sum().backward()
    with pytest.raises(LiquidGSError) as err:
        exposure.step(3)
    message = str(err.value)
    assert "\n" not in message and "train frame '000002'" in message and "--exposure.apply off" in message


def test_the_state_comes_back_and_a_checkpoint_of_other_frames_is_refused(tmp_path):
    exposure = ExposureCompensation(ExposureConfig(), _frames("a", "b"), 10, "cpu", 1e-15)
    with torch.no_grad():
        exposure.gains[1] = torch.tensor([0.1, -0.2, 0.05])
    saved = exposure.state_dict()
    again = ExposureCompensation(ExposureConfig(), _frames("a", "b"), 10, "cpu", 1e-15)
    again.load_state_dict(saved, tmp_path / "checkpoint.pt")
    assert torch.equal(again.gains, exposure.gains)
    with pytest.raises(LiquidGSError, match="other training frames"):
        ExposureCompensation(ExposureConfig(), _frames("a", "c"), 10, "cpu", 1e-15).load_state_dict(saved, tmp_path)
    with pytest.raises(LiquidGSError, match="--exposure.apply off"):
        again.load_state_dict(None, tmp_path / "checkpoint.pt")


def test_exposure_flicker_scales_each_training_frame_and_leaves_the_test_views_clean(capture):
    dataset = load_dataset(DataConfig(path=capture / "nerfies"))
    flickered = perturb_dataset(dataset, PerturbConfig(exposure=0.2), seed=4)
    gains = np.clip(1 + _rng(4, "exposure").normal(0.0, 0.2, (len(dataset.train), 3)), 0, None)
    for frame, clean, gain in zip(flickered.train, dataset.train, gains):
        seen, truth = frame.image_uint8().astype(float), clean.image_uint8().astype(float)
        bright = truth[..., :3].mean((0, 1)) > 20
        ratio = seen[..., :3].mean((0, 1))[bright] / truth[..., :3].mean((0, 1))[bright]
        assert np.allclose(ratio, np.minimum(gain[bright], 255 / truth[..., :3].max()), atol=0.15)
        assert np.array_equal(frame.image_uint8(), frame.image_uint8())  # the same on every read
    assert flickered.test == dataset.test
    with pytest.raises(ConfigError, match="perturb.exposure"):
        PerturbConfig(exposure=-0.1)


@pytest.mark.slow  # a run long enough to learn exposures
def test_a_run_on_flickering_frames_learns_each_frame_s_exposure(tmp_path):
    """The still scene (nothing moves: only a frame's exposure explains its colours) with each training
    frame's channels scaled by 1 + N(0, 0.15^2): the corrections in exposure.json follow the true
    gains (up to one gain shared by all frames, which the scene's colours can take instead)."""
    scene = generate_synthetic("still", tmp_path / "still", size=48, frames=32, seed=0)
    flags = ["--data", str(scene / "nerfies"), "--field", "static", "--out", str(tmp_path / "run"), *tiny_flags({
        "iterations": 300, "optim.means_lr_steps": 300, "densify.stop": 250, "densify.opacity_reset_interval": 150,
        "eval.start": 300, "checkpoint_every": 300, "cameras.refine": "off", "cameras.align_steps": 5,
        "perturb.exposure": 0.15, "exposure.lr": 0.01, "exposure.lr_final": 0.001,
    })]  # fmt: skip
    results = run_train(flags)
    written = json.loads((tmp_path / "run" / "exposure.json").read_text())
    learned = np.array([frame["gain"] for frame in written["frames"]])
    truth = np.clip(1 + _rng(0, "exposure").normal(0.0, 0.15, learned.shape), 0, None) - 1
    centred = [x - x.mean(axis=0) for x in (learned, truth)]
    assert np.corrcoef(centred[0].ravel(), centred[1].ravel())[0, 1] > 0.6
    assert "gain and offset" in results.final_aligned["cameras"]  # test views: their exposure fitted too


@pytest.mark.slow
def test_a_capture_run_holds_sizes_resumes_bit_exactly_and_writes_its_exposure(capture, tmp_path, monkeypatch):
    flags = ["--data", str(capture / "nerfies"), "--field", "mlp",
             *tiny_flags({"iterations": 30, "cameras.align_steps": 5, "exposure.lr": 0.01})]  # fmt: skip
    run_train([*flags, "--out", str(tmp_path / "whole")])
    interrupt_at(15, [*flags, "--out", str(tmp_path / "cut")], monkeypatch)
    run_train([*flags, "--out", str(tmp_path / "cut"), "--resume"])
    a = torch.load(tmp_path / "whole" / "checkpoint.pt", weights_only=True)
    b = torch.load(tmp_path / "cut" / "checkpoint.pt", weights_only=True)
    assert a["exposure"]["gains"].abs().max() > 0 and a["sizes_held"] is True
    for key in ("gains", "offsets"):
        assert torch.equal(a["exposure"][key], b["exposure"][key]), key
    for key, value in a["params"].items():
        assert torch.equal(value, b["params"][key]), key
    assert len(json.loads((tmp_path / "whole" / "exposure.json").read_text())["frames"]) == 12

    run = load_run(tmp_path / "whole", "cpu")  # the field moves Gaussians but never resizes them
    canonical = deform(run.params, None, 0.0).scales
    assert all(torch.equal(run.at_time(t).scales, canonical) for t in (0.1, 0.9))
    assert not torch.equal(run.at_time(0.1).means, run.at_time(0.9).means)
    run_train([*flags, "--out", str(tmp_path / "free"), "--motion.no-fixed-sizes"])
    free = load_run(tmp_path / "free", "cpu")
    assert not torch.equal(free.at_time(0.1).scales, deform(free.params, None, 0.0).scales)


def test_a_run_made_before_exposure_and_fixed_sizes_resumes_as_it_was_trained(capture, tmp_path, monkeypatch):
    """Its config.yml has no `exposure` and a `motion` without fixed_sizes; its checkpoint neither."""
    out = tmp_path / "old"
    flags = ["--data", str(capture / "nerfies"), "--field", "mlp", "--out", str(out),
             *tiny_flags({"iterations": 30, "cameras.align_steps": 5})]  # fmt: skip
    interrupt_at(15, [*flags, "--exposure.apply", "off", "--motion.no-fixed-sizes"], monkeypatch)
    stored = yaml.safe_load((out / "config.yml").read_text())
    del stored["exposure"], stored["motion"]["fixed_sizes"]
    (out / "config.yml").write_text(yaml.safe_dump(stored, sort_keys=False))
    payload = torch.load(out / "checkpoint.pt", weights_only=True)
    del payload["exposure"], payload["sizes_held"]
    torch.save(payload, out / "checkpoint.pt")
    cfg = load_yaml(out / "config.yml")
    assert cfg.exposure.apply == "off" and cfg.motion.fixed_sizes is False
    code, _, _ = run_cli(["train", "--out", str(out), "--resume"])
    assert code == 0 and not (out / "exposure.json").exists()
    run = load_run(out, "cpu")
    assert not torch.equal(run.at_time(0.9).scales, deform(run.params, None, 0.0).scales)  # sizes as trained: free
