"""evaluate_views on synthetic frames, and the atomic JSON writer."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass

import numpy as np
import pytest
import torch

from liquidgs.atomic import write_json_atomic
from liquidgs.errors import ConfigError
from liquidgs.eval import LPIPS, evaluate_views, psnr, quantize_8bit, ssim


@dataclass
class SyntheticFrame:
    name: str
    time: float
    truth: torch.Tensor

    def image(self) -> torch.Tensor:
        return self.truth


def make_frames(count: int = 3, size: int = 24) -> list[SyntheticFrame]:
    gen = torch.Generator().manual_seed(0)
    return [
        SyntheticFrame(f"r_{i:03d}", i / max(count - 1, 1), torch.rand(size, size, 3, generator=gen))
        for i in range(count)
    ]


def noisy_render(noise: float):
    """A render_fn: the ground truth plus deterministic noise that grows with the frame time."""

    def render(frame: SyntheticFrame) -> torch.Tensor:
        gen = torch.Generator().manual_seed(int(frame.time * 100))
        level = noise * (1 + frame.time)
        return frame.truth + level * torch.randn(frame.truth.shape, generator=gen)

    return render


def test_per_view_scores_and_summary_without_lpips():
    frames = make_frames()
    render = noisy_render(0.05)
    summary, per_view = evaluate_views(render, frames, lpips=None, lpips_error="no VGG weights")

    assert [view["name"] for view in per_view] == ["r_000", "r_001", "r_002"]
    assert [view["time"] for view in per_view] == [0.0, 0.5, 1.0]
    for frame, view in zip(frames, per_view):
        expected_render = quantize_8bit(render(frame).clamp(0, 1))
        expected_truth = quantize_8bit(frame.truth)
        assert view["psnr"] == pytest.approx(psnr(expected_render, expected_truth).item())
        assert view["ssim"] == pytest.approx(ssim(expected_render, expected_truth).item())
        assert view["lpips"] is None

    psnrs = np.array([view["psnr"] for view in per_view])
    assert summary["psnr"] == pytest.approx(psnrs.mean())
    assert summary["psnr_std"] == pytest.approx(psnrs.std(ddof=1))
    assert summary["ssim_std"] > 0
    assert summary["lpips"] is None and summary["lpips_std"] is None
    assert summary["lpips_unavailable"] == "no VGG weights; no other LPIPS backbone was used instead"
    assert summary["n_views"] == 3
    assert summary["quantized_8bit"] is True
    assert not any(key.startswith("lpips_backbone") for key in summary)


def test_quantize_flag_changes_the_inputs():
    frames = make_frames(count=1)
    _, quantized = evaluate_views(noisy_render(0.02), frames, lpips=None)
    summary, raw = evaluate_views(noisy_render(0.02), frames, lpips=None, quantize=False)
    assert summary["quantized_8bit"] is False
    assert quantized[0]["psnr"] != pytest.approx(raw[0]["psnr"], abs=1e-4)
    expected = psnr(noisy_render(0.02)(frames[0]).clamp(0, 1), frames[0].truth).item()
    assert raw[0]["psnr"] == pytest.approx(expected)
    assert summary["psnr_std"] == 0.0  # one view
    assert summary["lpips_unavailable"] == "no LPIPS model was given; no other LPIPS backbone was used instead"


def test_with_lpips_model_and_no_grad(lpips_weights):
    lpips = LPIPS("alex", weights=lpips_weights)
    frames = make_frames(count=2, size=64)
    grad_modes = []

    def render(frame: SyntheticFrame) -> torch.Tensor:
        grad_modes.append(torch.is_grad_enabled())
        weight = torch.ones((), requires_grad=True)  # as a trainable model's output would be
        return weight * (frame.truth * 0.9 + 0.05)

    summary, per_view = evaluate_views(render, frames, lpips=lpips)
    assert grad_modes == [False, False]
    for frame, view in zip(frames, per_view):
        expected = lpips(quantize_8bit(frame.truth * 0.9 + 0.05), quantize_8bit(frame.truth)).item()
        assert view["lpips"] == pytest.approx(expected, abs=1e-6)
    assert summary["lpips"] == pytest.approx(np.mean([view["lpips"] for view in per_view]))
    assert summary["lpips_backbone"] == "alex"
    assert summary["lpips_metric"] == "LPIPS-Alex"
    assert summary["lpips_normalize"] is True
    assert summary["lpips_weights"] == str(lpips_weights / "alexnet_features.pth")
    assert "lpips_unavailable" not in summary


def test_rejects_contradictory_or_empty_input(lpips_weights):
    with pytest.raises(ConfigError, match="no views"):
        evaluate_views(noisy_render(0.1), [], lpips=None)
    lpips = LPIPS("alex", weights=lpips_weights)
    with pytest.raises(ConfigError, match="not both"):
        evaluate_views(noisy_render(0.1), make_frames(1), lpips=lpips, lpips_error="unavailable")


def test_write_json_atomic_round_trip_and_replace(tmp_path):
    target = tmp_path / "run" / "results.json"
    summary, per_view = evaluate_views(noisy_render(0.05), make_frames(), lpips=None)
    write_json_atomic(target, {"final": summary, "per_view": per_view})
    assert json.loads(target.read_text()) == {"final": summary, "per_view": per_view}

    write_json_atomic(target, {"version": 2})
    assert json.loads(target.read_text()) == {"version": 2}
    assert sorted(p.name for p in target.parent.iterdir()) == ["results.json"]


def test_write_json_atomic_keeps_old_file_on_failure(tmp_path):
    target = tmp_path / "results.json"
    write_json_atomic(target, {"done": True})
    with pytest.raises(TypeError):
        write_json_atomic(target, {"done": object()})  # not serialisable
    assert json.loads(target.read_text()) == {"done": True}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.json"]


def test_eval_imports_no_pipeline_stage():
    """The trainer imports eval, never the reverse; and importing eval loads no lpips/torchvision."""
    code = (
        "import sys, liquidgs.eval; "
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('lpips', 'torchvision') "
        "or m.startswith(('liquidgs.train', 'liquidgs.data', 'liquidgs.render'))))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"


def test_describe_lpips_names_the_metric_or_the_reason():
    from liquidgs.eval import describe_lpips

    assert describe_lpips({"lpips": 0.123456, "lpips_metric": "LPIPS-Alex"}) == "LPIPS-Alex 0.1235"
    missing = {"lpips": None, "lpips_unavailable": "LPIPS-VGG unavailable: no vgg16 weights"}
    assert describe_lpips(missing) == "(LPIPS-VGG unavailable: no vgg16 weights)"


def test_images_too_small_for_the_lpips_network_are_reported_not_a_crash(lpips_weights):
    """AlexNet needs 31 px: at 16 px LPIPS is unavailable with the reason, PSNR and SSIM still come."""
    lpips = LPIPS("alex", weights=lpips_weights)
    summary, per_view = evaluate_views(noisy_render(0.05), make_frames(count=2, size=16), lpips=lpips)
    assert summary["lpips"] is None and all(view["lpips"] is None for view in per_view)
    assert summary["lpips_unavailable"].startswith("LPIPS-Alex unavailable: images of 16x16 are smaller than the 31 px")
    assert summary["psnr"] > 0 and len(per_view) == 2
    assert evaluate_views(noisy_render(0.05), make_frames(count=1, size=31), lpips=lpips)[0]["lpips"] is not None
