"""LPIPS: the published check values, weight resolution, and the errors when weights are unusable."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from liquidgs.errors import ConfigError, LiquidGSError
from liquidgs.eval import LPIPS, LPIPSUnavailable, lin_weights_path, resolve_backbone_weights
from liquidgs.eval.lpips import WEIGHTS_ENV
from shared_data import LPIPS_DIR, require_shared

ALEX_WEIGHTS = "alexnet_features.pth"
ALEX_HUB_NAME = "alexnet-owt-7be5be79.pth"


@pytest.fixture(autouse=True)
def isolated_weight_lookup(tmp_path, monkeypatch):
    """No test sees the user's environment variable or hub cache: TORCH_HOME is an empty folder."""
    monkeypatch.delenv(WEIGHTS_ENV, raising=False)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch_home"))


def load_example(name: str) -> torch.Tensor:
    path = require_shared(LPIPS_DIR / name)
    return torch.from_numpy(np.array(Image.open(path).convert("RGB"))).float() / 255


@pytest.fixture
def examples() -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """LPIPS' own example images (../shared/data/lpips)."""
    return load_example("ex_ref.png"), load_example("ex_p0.png"), load_example("ex_p1.png")


@pytest.mark.parametrize("backbone,expected", [("alex", (0.7219, 0.1376)), ("squeeze", (0.7110, 0.1479))])
def test_reproduces_published_check_values(backbone, expected, examples, lpips_weights):
    ref, p0, p1 = examples
    metric = LPIPS(backbone, normalize=True, weights=lpips_weights)
    assert round(metric(p0, ref).item(), 4) == expected[0]
    assert round(metric(p1, ref).item(), 4) == expected[1]
    batched = metric(torch.stack([p0, p1]), torch.stack([ref, ref]))
    assert batched.shape == (2,)
    assert batched.tolist() == pytest.approx([metric(p0, ref).item(), metric(p1, ref).item()], abs=1e-6)
    assert metric(ref, ref).item() == pytest.approx(0.0, abs=1e-7)


def test_unnormalized_quirk_feeds_inputs_unchanged(examples, lpips_weights):
    alex_file = lpips_weights / ALEX_WEIGHTS
    ref, p0, _ = examples
    quirk = LPIPS("alex", normalize=False, weights=alex_file)
    correct = LPIPS("alex", normalize=True, weights=alex_file)
    # Without normalisation x is read as if it were 2y - 1 for y = (x + 1) / 2.
    assert quirk(p0, ref).item() == pytest.approx(correct((p0 + 1) / 2, (ref + 1) / 2).item(), abs=1e-6)
    assert quirk(p0, ref).item() != pytest.approx(correct(p0, ref).item(), abs=1e-3)
    assert quirk.describe()["normalize"] is False
    assert "quirk" in quirk.describe()["input_range"]


def test_describe_records_backbone_version_and_sources(lpips_weights):
    info = LPIPS("squeeze", weights=lpips_weights).describe()
    assert info["backbone"] == "squeeze"
    assert info["version"] == "0.1"
    assert info["normalize"] is True
    assert info["weights"] == str(lpips_weights / "squeezenet1_1_features.pth")
    assert info["weights_source"] == "weights argument"
    assert info["lin_weights"].endswith(str(Path("lpips", "weights", "v0.1", "squeeze.pth")))


def test_environment_variable_file_or_directory(monkeypatch, lpips_weights):
    alex_file = lpips_weights / ALEX_WEIGHTS
    monkeypatch.setenv(WEIGHTS_ENV, str(lpips_weights))
    assert resolve_backbone_weights("alex") == (alex_file, f"${WEIGHTS_ENV}")
    monkeypatch.setenv(WEIGHTS_ENV, str(alex_file))
    assert resolve_backbone_weights("alex") == (alex_file, f"${WEIGHTS_ENV}")
    monkeypatch.setenv(WEIGHTS_ENV, str(lpips_weights / "missing.pth"))
    with pytest.raises(LPIPSUnavailable, match="missing.pth does not exist"):
        resolve_backbone_weights("alex")


def test_explicit_path_wins_and_is_not_replaced(tmp_path, monkeypatch, lpips_weights):
    alex_file = lpips_weights / ALEX_WEIGHTS
    monkeypatch.setenv(WEIGHTS_ENV, str(lpips_weights))
    assert resolve_backbone_weights("alex", alex_file) == (alex_file, "weights argument")
    # A wrong explicit path fails even though the variable would have found a file.
    with pytest.raises(LPIPSUnavailable, match="nowhere.pth"):
        resolve_backbone_weights("alex", tmp_path / "nowhere.pth")


def test_hub_cache_full_checkpoint(tmp_path, examples, lpips_weights):
    """torchvision's full model checkpoint in $TORCH_HOME: only ``features.*`` is taken."""
    alex_file = lpips_weights / ALEX_WEIGHTS
    checkpoints = tmp_path / "torch_home" / "hub" / "checkpoints"
    checkpoints.mkdir(parents=True)
    state = torch.load(alex_file, weights_only=True)
    state["classifier.1.weight"] = torch.zeros(4096, 9216)
    torch.save(state, checkpoints / ALEX_HUB_NAME)

    metric = LPIPS("alex")
    assert metric.describe()["weights_source"] == "torch hub cache"
    assert metric.weights_path == checkpoints / ALEX_HUB_NAME
    ref, p0, _ = examples
    assert round(metric(p0, ref).item(), 4) == 0.7219


def test_vgg_unavailable_names_what_was_looked_for(tmp_path, monkeypatch, lpips_weights):
    with pytest.raises(LPIPSUnavailable) as caught:
        LPIPS("vgg")
    message = str(caught.value)
    assert message.startswith("LPIPS-VGG unavailable: backbone weights not found; looked for: ")
    assert caught.value.backbone == "vgg"
    assert str(tmp_path / "torch_home" / "hub" / "checkpoints" / "vgg16-397923af.pth") in message
    assert isinstance(caught.value, LiquidGSError)

    monkeypatch.setenv(WEIGHTS_ENV, str(lpips_weights))
    with pytest.raises(LPIPSUnavailable, match="vgg16_features.pth"):
        LPIPS("vgg")


def test_vgg_layout_matches_torchvision_keys(tmp_path, examples):
    """No VGG weights offline: check the layout against torchvision's key names and shapes."""
    convs = [(0, 3, 64), (2, 64, 64), (5, 64, 128), (7, 128, 128), (10, 128, 256), (12, 256, 256)]
    convs += [(14, 256, 256), (17, 256, 512), (19, 512, 512), (21, 512, 512), (24, 512, 512)]
    convs += [(26, 512, 512), (28, 512, 512)]
    gen = torch.Generator().manual_seed(0)
    state = {}
    for index, c_in, c_out in convs:
        state[f"features.{index}.weight"] = torch.randn(c_out, c_in, 3, 3, generator=gen) * 0.05
        state[f"features.{index}.bias"] = torch.zeros(c_out)
    path = tmp_path / "vgg16_features.pth"
    torch.save(state, path)

    metric = LPIPS("vgg", weights=tmp_path)
    ref, p0, p1 = examples
    scores = metric(torch.stack([p0, p1]), torch.stack([ref, ref]))
    assert torch.isfinite(scores).all() and (scores > 0).all()
    assert metric.describe()["weights"] == str(path)


def test_corrupt_weight_file_is_named(tmp_path):
    corrupt = tmp_path / "alexnet_features.pth"
    corrupt.write_bytes(b"not a torch checkpoint")
    with pytest.raises(LPIPSUnavailable, match="cannot read .*alexnet_features.pth"):
        LPIPS("alex", weights=corrupt)


def test_weights_of_another_backbone_are_rejected(lpips_weights):
    with pytest.raises(LPIPSUnavailable, match=r"squeezenet1_1_features.pth does not fit the network"):
        LPIPS("alex", weights=lpips_weights / "squeezenet1_1_features.pth")


def test_missing_lpips_package(monkeypatch):
    monkeypatch.setattr("liquidgs.eval.lpips.importlib.util.find_spec", lambda name: None)
    with pytest.raises(
        LPIPSUnavailable, match="^LPIPS-Alex unavailable: lin-layer weights: .*'lpips' is not installed"
    ):
        lin_weights_path("alex")


def test_unknown_backbone():
    with pytest.raises(ConfigError, match="unknown LPIPS backbone 'resnet'"):
        LPIPS("resnet")
