"""The compiled CPU SSIM held against the torch implementation (the reference): scores, gradients, the loss."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import torch

from liquidgs.eval import cpu_ssim
from liquidgs.eval.metrics import ssim, ssim_torch

pytestmark = pytest.mark.skipif(
    cpu_ssim.unavailable_reason() is not None,
    reason=f"compiled CPU SSIM unavailable: {cpu_ssim.unavailable_reason()}",
)

SHAPES = [(128, 128, 3), (37, 23, 3), (5, 3, 1), (1, 1, 3), (16, 40, 2)]


def pair(shape, seed, dtype=torch.float64):
    generator = torch.Generator().manual_seed(seed)
    ref = torch.rand(shape, generator=generator, dtype=dtype)
    # Correlated with the reference, as a render is with its ground truth, so the map varies.
    img = (ref + 0.3 * torch.rand(shape, generator=generator, dtype=dtype) - 0.15).clamp(0, 1)
    return img, ref


def score_and_grad(fn, img, ref):
    leaf = img.detach().clone().requires_grad_(True)
    score = fn(leaf, ref)
    score.backward()
    return score.detach(), leaf.grad


def training_loss(fn, img, ref):
    return 0.8 * (img - ref).abs().mean() + 0.2 * (1.0 - fn(img, ref))


def test_ssim_runs_the_compiled_kernel_on_cpu_images():
    img, ref = pair((8, 8, 3), 0)
    assert type(ssim(img.requires_grad_(True), ref).grad_fn).__name__ == "_SSIMCPUBackward"
    assert type(ssim_torch(img, ref).grad_fn).__name__ != "_SSIMCPUBackward"


@pytest.mark.parametrize("shape", SHAPES)
def test_score_and_gradient_equal_the_torch_ssim_float64(shape):
    img, ref = pair(shape, seed=sum(shape))
    ours, ours_grad = score_and_grad(ssim, img, ref)
    want, want_grad = score_and_grad(ssim_torch, img, ref)
    assert 0.05 < want.item() < 0.99
    torch.testing.assert_close(ours, want, rtol=1e-12, atol=1e-14)
    assert want_grad.abs().max() > 0
    torch.testing.assert_close(ours_grad, want_grad, rtol=1e-12, atol=1e-12 * want_grad.abs().max().item())


@pytest.mark.parametrize("shape", SHAPES)
def test_identical_images_score_one_with_the_torch_gradient(shape):
    _, ref = pair(shape, seed=1)
    ours, ours_grad = score_and_grad(ssim, ref, ref)
    want, want_grad = score_and_grad(ssim_torch, ref, ref)
    assert ours.item() == pytest.approx(1.0, abs=1e-14)
    assert ssim(ref.float(), ref.float()).item() == pytest.approx(1.0, abs=1e-7)
    # At the maximum the gradient vanishes up to rounding, in both implementations.
    torch.testing.assert_close(ours_grad, want_grad, rtol=0, atol=1e-12)


@pytest.mark.parametrize("shape", [(128, 128, 3), (37, 23, 3), (1, 1, 3)])
def test_float32_within_a_stated_tolerance(shape):
    """float32: the kernel and torch both round in float32, in different summation orders.

    Measured against the float64 reference: scores within 1e-7, gradients within 5e-7 of their
    largest entry; the bounds leave a factor of 10-20.
    """
    img, ref = pair(shape, seed=7)
    exact, exact_grad = score_and_grad(ssim_torch, img, ref)
    for fn in (ssim, ssim_torch):
        score, grad = score_and_grad(fn, img.float(), ref.float())
        assert score.dtype == grad.dtype == torch.float32
        assert abs(score.double() - exact).item() < 2e-6, fn.__name__
        scale = exact_grad.abs().max().item()
        torch.testing.assert_close(grad.double(), exact_grad, rtol=0, atol=1e-5 * scale, msg=fn.__name__)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_training_loss_gradient_equals_the_torch_loss(dtype):
    img, ref = pair((64, 48, 3), seed=3, dtype=dtype)
    ours = score_and_grad(lambda x, y: training_loss(ssim, x, y), img, ref)
    want = score_and_grad(lambda x, y: training_loss(ssim_torch, x, y), img, ref)
    tolerance = 1e-12 if dtype == torch.float64 else 1e-5
    torch.testing.assert_close(ours[0], want[0], rtol=tolerance, atol=tolerance)
    torch.testing.assert_close(ours[1], want[1], rtol=0, atol=tolerance * want[1].abs().max().item())


def test_a_batch_loops_over_its_images():
    imgs, refs = pair((3, 20, 17, 3), seed=4)
    ours, ours_grad = score_and_grad(lambda x, y: ssim(x, y).sum(), imgs, refs)
    want, want_grad = score_and_grad(lambda x, y: ssim_torch(x, y).sum(), imgs, refs)
    torch.testing.assert_close(ssim(imgs, refs), ssim_torch(imgs, refs), rtol=1e-12, atol=1e-14)
    torch.testing.assert_close(ours_grad, want_grad, rtol=1e-12, atol=1e-12 * want_grad.abs().max().item())
    assert ssim(imgs, refs).shape == (3,) and ssim(imgs[0], refs[0]).shape == ()


def test_views_no_grad_and_a_reference_needing_grad():
    img, ref = pair((24, 30, 3), seed=5)
    want = ssim_torch(img, ref)
    # A non-contiguous view of the image goes through the kernel too.
    wide = torch.cat([img, img], dim=1)[:, ::2]
    assert not wide.is_contiguous()
    torch.testing.assert_close(ssim(wide, ref), ssim_torch(wide, ref), rtol=1e-12, atol=1e-14)
    with torch.no_grad():
        torch.testing.assert_close(ssim(img, ref), want, rtol=1e-12, atol=1e-14)
    # A reference that needs a gradient takes the torch path, which gives it one.
    ref_leaf = ref.clone().requires_grad_(True)
    ssim(img, ref_leaf).backward()
    assert ref_leaf.grad is not None and ref_leaf.grad.abs().max() > 0


def test_results_repeat_bit_for_bit_for_any_thread_count():
    img, ref = pair((128, 128, 3), seed=6, dtype=torch.float32)
    threads = torch.get_num_threads()
    try:
        results = []
        for count in (1, 2, 3, 2):
            torch.set_num_threads(count)
            results.append(score_and_grad(ssim, img, ref))
    finally:
        torch.set_num_threads(threads)
    for score, grad in results[1:]:
        assert torch.equal(score, results[0][0])
        assert torch.equal(grad, results[0][1])


def run_python(code: str, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=os.environ | env, check=False, timeout=120
    )


SSIM_TWICE = """
import torch
from liquidgs.eval.metrics import ssim, ssim_torch
img, ref = torch.rand(20, 30, 3, dtype=torch.float64), torch.rand(20, 30, 3, dtype=torch.float64)
img.requires_grad_(True)
scores = [ssim(img, ref) for _ in range(2)]
print(type(scores[0].grad_fn).__name__, scores[1].item() == ssim_torch(img, ref).item())
"""


@pytest.mark.parametrize(
    ("env", "reason"),
    [
        ({"LIQUIDGS_CPU_KERNEL": "0"}, "LIQUIDGS_CPU_KERNEL=0"),
        ({"CXX": "false"}, "false failed on cpu_ssim.cpp"),
    ],
)
def test_without_the_kernel_ssim_is_the_torch_ssim_with_one_line(tmp_path, env, reason):
    result = run_python(SSIM_TWICE, LIQUIDGS_CACHE_DIR=str(tmp_path / "cache"), **env)
    assert result.returncode == 0, result.stderr
    grad_fn, same = result.stdout.split()
    assert grad_fn != "_SSIMCPUBackward" and same == "True"
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert reason in lines[0] and lines[0].startswith("liquidgs: compiled SSIM unavailable")
    assert lines[0].endswith("using the torch SSIM")
