"""PSNR, SSIM and the 8-bit round trip against independent numpy / scipy / PIL computations."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest
import torch
from PIL import Image
from scipy.signal import correlate2d

from liquidgs.errors import ConfigError
from liquidgs.eval import psnr, quantize_8bit, ssim
from liquidgs.eval.metrics import MIN_MSE, psnr_from_mse


def smooth_image(height: int, width: int, seed: int, dtype=torch.float64) -> torch.Tensor:
    """A structured [H, W, 3] image in [0, 1]: gradients plus a little texture."""
    gen = torch.Generator().manual_seed(seed)
    ys = torch.linspace(0, 1, height, dtype=dtype).view(-1, 1, 1)
    xs = torch.linspace(0, 1, width, dtype=dtype).view(1, -1, 1)
    phase = torch.rand(1, 1, 3, generator=gen, dtype=dtype) * 6
    base = 0.5 + 0.3 * torch.sin(4 * xs + 3 * ys + phase)
    return (base + 0.1 * torch.rand(height, width, 3, generator=gen, dtype=dtype)).clamp(0, 1)


def ssim_reference(img: np.ndarray, ref: np.ndarray) -> float:
    """The D-3DGS formula written out directly: full 11x11 window, zero-padded 'same' filtering."""
    offsets = np.arange(11) - 5
    g = np.exp(-(offsets**2) / (2 * 1.5**2))
    g /= g.sum()
    window = np.outer(g, g)

    def blur(channel: np.ndarray) -> np.ndarray:
        return correlate2d(channel, window, mode="same", boundary="fill", fillvalue=0.0)

    c1, c2 = 0.01**2, 0.03**2
    maps = []
    for c in range(img.shape[2]):
        x, y = img[..., c], ref[..., c]
        mu_x, mu_y = blur(x), blur(y)
        var_x = blur(x * x) - mu_x**2
        var_y = blur(y * y) - mu_y**2
        cov = blur(x * y) - mu_x * mu_y
        maps.append(((2 * mu_x * mu_y + c1) * (2 * cov + c2)) / ((mu_x**2 + mu_y**2 + c1) * (var_x + var_y + c2)))
    return float(np.mean(maps))


def test_psnr_known_value_and_shapes():
    ref = torch.zeros(8, 6, 3)
    img = torch.full((8, 6, 3), 0.1)  # MSE 0.01 -> 20 dB
    assert psnr(img, ref).shape == ()
    assert psnr(img, ref).item() == pytest.approx(20.0, abs=1e-5)

    batch = torch.stack([img, torch.full((8, 6, 3), 0.01)])
    scores = psnr(batch, torch.zeros_like(batch))
    assert scores.shape == (2,)
    assert scores.tolist() == pytest.approx([20.0, 40.0], abs=1e-4)
    assert math.isinf(psnr(ref, ref).item())


def test_psnr_is_per_image_not_pooled():
    ref = torch.zeros(2, 4, 4, 3)
    img = ref.clone()
    img[0] = 0.1
    img[1] = 0.2
    pooled_mse = ((img - ref) ** 2).mean().item()
    scores = psnr(img, ref)
    assert scores[0].item() == pytest.approx(psnr(img[0], ref[0]).item())
    assert scores.mean().item() != pytest.approx(-10 * math.log10(pooled_mse), abs=1e-3)


def test_metrics_reject_bad_shapes():
    with pytest.raises(ConfigError, match="differ in shape"):
        psnr(torch.zeros(4, 4, 3), torch.zeros(4, 5, 3))
    with pytest.raises(ConfigError, match=r"\[H, W, C\]"):
        ssim(torch.zeros(4, 3), torch.zeros(4, 3))


@pytest.mark.parametrize("height,width", [(40, 37), (11, 16)])
def test_ssim_matches_direct_formula(height, width):
    img = smooth_image(height, width, seed=1)
    ref = (img + 0.08 * torch.randn(height, width, 3, generator=torch.Generator().manual_seed(2))).clamp(0, 1)
    expected = ssim_reference(img.numpy(), ref.numpy())
    assert ssim(img, ref).item() == pytest.approx(expected, abs=1e-10)
    # float32, the dtype renders have, stays within the brief's 1e-6.
    assert ssim(img.float(), ref.float()).item() == pytest.approx(expected, abs=1e-6)


def test_ssim_batch_equals_single_images():
    imgs = torch.stack([smooth_image(24, 20, seed=s) for s in (3, 4, 5)])
    refs = torch.stack([smooth_image(24, 20, seed=s) for s in (6, 7, 8)])
    batched = ssim(imgs, refs)
    assert batched.shape == (3,)
    for i in range(3):
        assert batched[i].item() == pytest.approx(ssim(imgs[i], refs[i]).item(), abs=1e-12)


def test_ssim_properties():
    img = smooth_image(32, 32, seed=9)
    other = smooth_image(32, 32, seed=10)
    assert ssim(img, img).item() == pytest.approx(1.0, abs=1e-12)
    assert ssim(img, other).item() == pytest.approx(ssim(other, img).item(), abs=1e-12)
    gen = torch.Generator().manual_seed(11)
    noise = torch.randn(32, 32, 3, generator=gen, dtype=torch.float64)
    scores = [ssim((img + level * noise).clamp(0, 1), img).item() for level in (0.01, 0.05, 0.2)]
    assert 1.0 > scores[0] > scores[1] > scores[2]


def test_ssim_is_differentiable():
    # Small, as gradcheck costs two evaluations per input value.
    img = smooth_image(6, 5, seed=12).requires_grad_(True)
    ref = smooth_image(6, 5, seed=13)
    assert torch.autograd.gradcheck(lambda x: ssim(x, ref), (img,))
    loss = 1 - ssim(img.float(), ref.float())
    loss.backward()
    assert img.grad is not None and img.grad.abs().sum() > 0


def test_quantize_8bit_matches_save_image_and_png_round_trip():
    gen = torch.Generator().manual_seed(14)
    img = torch.rand(16, 16, 3, generator=gen) * 1.2 - 0.1  # some values outside [0, 1]
    # 2.5 / 255 times 255 is exactly 2.5 in float32: save_image rounds it up to 3, where
    # round-half-to-even would give 2.
    img[0, 0] = torch.tensor([2.5 / 255, 0.0, 1.0])

    # torchvision.utils.save_image: mul(255).add_(0.5).clamp_(0, 255) -> uint8, in float32.
    levels = np.clip(img.numpy() * np.float32(255) + np.float32(0.5), 0, 255).astype(np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(levels).save(buffer, format="PNG")
    buffer.seek(0)
    read_back = torch.from_numpy(np.array(Image.open(buffer))).float() / 255

    quantized = quantize_8bit(img)
    assert quantized.dtype == img.dtype and quantized.shape == img.shape
    assert torch.equal(quantized, read_back)
    assert quantized[0, 0].tolist() == pytest.approx([3 / 255, 0.0, 1.0])
    assert torch.equal(quantize_8bit(quantized), quantized)


def test_psnr_from_mse_is_the_reference_formula_and_the_floor_is_120_db():
    mse = torch.tensor([1e-6, 0.01, 0.25], dtype=torch.float64)
    torch.testing.assert_close(psnr_from_mse(mse), -10.0 * torch.log10(mse))
    assert psnr_from_mse(torch.tensor(0.0)).item() == math.inf
    assert psnr_from_mse(torch.tensor(MIN_MSE, dtype=torch.float64)).item() == pytest.approx(120.0)
