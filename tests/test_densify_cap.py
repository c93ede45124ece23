"""The Gaussians-per-pixel cap of densification (DensifyConfig.max_per_pixel) and the quick look
that `liquidgs data video` prints with it."""

import json
from pathlib import Path

import pytest
import torch

from liquidgs.commands.data import quick_look_commands
from liquidgs.data import generate_synthetic
from liquidgs.train.config import config_hash, identity, legacy_identity, preset_config
from liquidgs.train.strategy import D3DGSStrategy, DensifyConfig
from test_strategy import make_info, make_setup
from tiny_runs import run_cli

OWN_VIDEO_PAGE = Path(__file__).resolve().parents[1] / "docs" / "own-video.md"


def test_an_uncapped_config_has_the_version_1_identity_of_before_the_cap_existed():
    cfg = preset_config("tiny", Path("scene"))
    assert cfg.densify.max_per_pixel == 0
    assert "max_per_pixel" not in legacy_identity(cfg)["densify"]
    capped = preset_config("tiny", Path("scene"))
    capped.densify.max_per_pixel = 1.0
    assert identity(capped)["densify"]["max_per_pixel"] == 1.0
    assert config_hash(capped) != config_hash(cfg)


def test_a_negative_cap_is_refused_before_anything_is_written(tmp_path):
    flags = ["--preset", "tiny", "--densify.max-per-pixel", "-1", "--out", str(tmp_path / "run")]
    code, _, stderr = run_cli(["train", "--data", str(tmp_path), *flags])
    assert code == 2 and "densify.max-per-pixel must be a finite number >= 0" in stderr, stderr
    assert not (tmp_path / "run").exists()


def test_the_cap_keeps_the_largest_gradients_and_counts_a_split_as_its_extra_children():
    # Six Gaussians: 0-2 small (clone, +1 each), 3-5 large (split in two, +1 each).
    params, optimizers = make_setup()
    # A 2x4 image is 8 pixels; 1.0 per pixel leaves room for 2 more Gaussians.
    strategy = D3DGSStrategy(DensifyConfig(start=0, interval=100, max_per_pixel=1.0), scene_extent=1.0)
    state = strategy.initial_state(6, torch.device("cpu"))
    grad = torch.zeros(6, 2)
    # NDC gradient = pixel gradient * width / 2 (width 2): every one is over 0.0007, 4 and 1 most.
    grad[:, 0] = torch.tensor([0.001, 0.002, 0.0009, 0.0008, 0.005, 0.0011])
    means = params["means"].detach().clone()
    report = strategy.step_post_backward(params, optimizers, state, 100, make_info(grad, torch.full((6,), 3), 2, 4))
    assert report["cloned"] == 1 and report["split"] == 1
    assert params["means"].shape[0] == 8 == strategy.cap(8)
    assert D3DGSStrategy(DensifyConfig(max_per_pixel=0.3), 1.0).cap(160 * 90) == 4320
    # The clone kept is Gaussian 1 (the larger small-Gaussian gradient), appended after the originals.
    assert torch.equal(params["means"][5].detach(), means[1])


def test_no_room_means_no_growth_but_pruning_still_runs():
    params, optimizers = make_setup()
    with torch.no_grad():
        params["opacities"][0] = torch.logit(torch.tensor(0.001))
    strategy = D3DGSStrategy(DensifyConfig(start=0, interval=100, max_per_pixel=0.5), scene_extent=1.0)
    state = strategy.initial_state(6, torch.device("cpu"))
    grad = torch.full((6, 2), 1.0)
    report = strategy.step_post_backward(params, optimizers, state, 100, make_info(grad, torch.full((6,), 3), 2, 4))
    assert report["cloned"] == report["split"] == 0 and report["pruned"] == 1
    assert params["means"].shape[0] == 5


def test_without_the_cap_every_candidate_grows():
    params, optimizers = make_setup()
    strategy = D3DGSStrategy(DensifyConfig(start=0, interval=100), scene_extent=1.0)
    state = strategy.initial_state(6, torch.device("cpu"))
    grad = torch.full((6, 2), 1.0)
    report = strategy.step_post_backward(params, optimizers, state, 100, make_info(grad, torch.full((6,), 3), 2, 4))
    assert report["cloned"] == 3 and report["split"] == 3 and params["means"].shape[0] == 12


@pytest.mark.slow
def test_a_capped_training_stays_under_the_cap_where_the_uncapped_one_passes_it(tmp_path, one_torch_thread):
    """The built-in puppet at 32x32 (1,024 pixels), 300 tiny iterations from 2,000 random points:
    uncapped, densification grows past 1 per pixel; with --densify.max-per-pixel 1 it never does."""
    data = Path(generate_synthetic("puppet", tmp_path / "puppet", size=32, frames=24, seed=0)) / "dnerf"
    counts = {}
    for name, extra in (("uncapped", []), ("capped", ["--densify.max-per-pixel", "1"])):
        code, _, stderr = run_cli(
            ["train", "--data", str(data), "--field", "static", "--preset", "tiny", "--iterations", "300",
             "--init-points", "300", "--densify.start", "50", "--densify.interval", "25", "--densify.stop", "300",
             "--densify.opacity-reset-interval", "1000", "--eval.start", "300", "--eval.fps-frames", "1",
             "--out", str(tmp_path / name), *extra]
        )  # fmt: skip
        assert code == 0, stderr
        counts[name] = json.loads((tmp_path / name / "results.json").read_text())["num_gaussians"]
    print("Gaussians:", counts)
    assert counts["uncapped"] > 32 * 32 >= counts["capped"]


def test_the_quick_look_is_the_one_the_docs_name():
    """The commands `data video` prints for a 16:9 clip captured at the default --max-size 800
    (800x448) into scenes/clip are in the docs' "Your own video", step 4, word for word."""
    lines = quick_look_commands(Path("scenes/clip"), (800, 448))
    commands = [line.strip() for line in lines if line.strip().startswith("liquidgs ")]
    assert len(commands) == 2 and "--downscale 4" in commands[0] and "--densify.max-per-pixel" in commands[0]
    page = OWN_VIDEO_PAGE.read_text()
    section = page[page.index("## 4. The quick look on a CPU") :]
    section = section[: section.index("\n## ", 1)]
    for command in commands:
        assert command in section, command
