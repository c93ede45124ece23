"""Image metrics as the D-3DGS reference computes them: PSNR, SSIM and its 8-bit PNG round trip.

Images are channel-last, the rasteriser's layout: one image is [H, W, 3], a batch is
[B, H, W, 3]; values are in [0, 1]. Every metric returns one score per image: a 0-d tensor
for a single image, a [B] tensor for a batch.
"""

from __future__ import annotations

import functools
import math

import torch
import torch.nn.functional as F

from liquidgs import native
from liquidgs.errors import ConfigError
from liquidgs.eval import cpu_ssim

MIN_MSE = 1e-12
"""Where a PSNR must stay finite (training's running PSNR, region PSNRs), the MSE is floored here: 120 dB."""
SSIM_WINDOW = 11
SSIM_SIGMA = 1.5
SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2


def as_batch(img: torch.Tensor, name: str = "image") -> tuple[torch.Tensor, bool]:
    """Return ``img`` as [B, H, W, C] and whether the input was a single [H, W, C] image."""
    if img.dim() == 3:
        return img.unsqueeze(0), True
    if img.dim() == 4:
        return img, False
    raise ConfigError(f"{name}: expected [H, W, C] or [B, H, W, C], got shape {tuple(img.shape)}")


def image_pair(img: torch.Tensor, ref: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, bool]:
    """Both images as [B, H, W, C] batches of the same shape, and whether they were single images."""
    if img.shape != ref.shape:
        raise ConfigError(f"image and reference differ in shape: {tuple(img.shape)} vs {tuple(ref.shape)}")
    img_b, single = as_batch(img)
    ref_b, _ = as_batch(ref, "reference")
    return img_b, ref_b, single


def psnr_from_mse(mse: torch.Tensor) -> torch.Tensor:
    """PSNR in dB of [0, 1] images from their mean squared error: 20 log10(1 / sqrt(MSE)), the
    reference's formula (+inf at 0)."""
    return 20.0 * torch.log10(1.0 / torch.sqrt(mse))


def psnr(img: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    """Peak signal-to-noise ratio in dB per image on [0, 1] images (`psnr_from_mse`).

    Identical images give +inf, as the reference formula does.
    """
    img_b, ref_b, single = image_pair(img, ref)
    scores = psnr_from_mse((img_b - ref_b).pow(2).flatten(1).mean(dim=1))
    return scores[0] if single else scores


def gaussian_window_1d(size: int = SSIM_WINDOW, sigma: float = SSIM_SIGMA) -> torch.Tensor:
    """The normalised 1-D Gaussian whose outer product is the reference's 2-D SSIM window."""
    centre = size // 2
    weights = torch.tensor(
        [math.exp(-((x - centre) ** 2) / (2.0 * sigma**2)) for x in range(size)], dtype=torch.float64
    )
    return weights / weights.sum()


def _gaussian_blur(maps: torch.Tensor, window: torch.Tensor) -> torch.Tensor:
    """Zero-padded "same" Gaussian filter of each channel of ``maps`` [B, N, H, W] separately.

    The 2-D window is separable and the padding is zeros, so a row pass followed by a column
    pass equals the reference's single 11x11 depthwise convolution exactly (up to rounding),
    at a fraction of the cost.
    """
    channels, size = maps.shape[1], window.numel()
    rows = window.view(1, 1, 1, size).expand(channels, 1, 1, size)
    cols = window.view(1, 1, size, 1).expand(channels, 1, size, 1)
    maps = F.conv2d(maps, rows, padding=(0, size // 2), groups=channels)
    return F.conv2d(maps, cols, padding=(size // 2, 0), groups=channels)


def ssim(img: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    """Structural similarity as in the D-3DGS / 3DGS reference ``ssim``, per image.

    Gaussian window 11x11 with sigma 1.5, C1 = 0.01^2, C2 = 0.03^2, zero-padded "same"
    filtering of each channel separately, then the mean of the SSIM map over pixels and
    channels. Differentiable, so the training loss 0.8 L1 + 0.2 (1 - SSIM) uses it too.

    On the CPU (float32/float64, a reference that needs no gradient) the compiled kernel
    eval/cpu_ssim.cpp computes it in one pass - the same score and gradient up to rounding, a
    fraction of the time; elsewhere, or where the kernel cannot be built (one line on stderr
    says why), `ssim_torch` does.
    """
    img_b, ref_b, single = image_pair(img, ref)
    if cpu_ssim.applies(img_b, ref_b):
        reason = cpu_ssim.unavailable_reason()
        if reason is None:
            window = _cpu_window(img.dtype)
            if single:
                return cpu_ssim.ssim_cpu(img, ref, window, SSIM_C1, SSIM_C2)
            return torch.stack([cpu_ssim.ssim_cpu(i, r, window, SSIM_C1, SSIM_C2) for i, r in zip(img, ref)])
        native.report_fallback("SSIM", reason, "the torch SSIM")
    return ssim_torch(img, ref)


@functools.cache
def _cpu_window(dtype: torch.dtype) -> torch.Tensor:
    return gaussian_window_1d().to(dtype)


def ssim_torch(img: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    """`ssim` in torch ops: the reference the compiled kernel is held to, and its fallback.

    Gaussian window 11x11 with sigma 1.5, C1 = 0.01^2, C2 = 0.03^2, zero-padded "same"
    filtering of each channel separately, then the mean of the SSIM map over pixels and
    channels. Differentiable in both images, on any device.
    """
    img_b, ref_b, single = image_pair(img, ref)
    scores = _ssim_maps(img_b, ref_b).flatten(1).mean(dim=1)
    return scores[0] if single else scores


def ssim_map(img: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    """The SSIM map of one image pair [H, W, 3], averaged over channels: [H, W] (its mean is `ssim`)."""
    img_b, ref_b, _ = image_pair(img, ref)
    return _ssim_maps(img_b, ref_b)[0].mean(dim=0)


def _ssim_maps(img_b: torch.Tensor, ref_b: torch.Tensor) -> torch.Tensor:
    """[B, 3, H, W] SSIM maps of batched [B, H, W, 3] images."""
    channels = img_b.shape[-1]
    window = gaussian_window_1d().to(device=img_b.device, dtype=img_b.dtype)

    # One filter call for all five local statistics of every channel.
    x = img_b.permute(0, 3, 1, 2)
    y = ref_b.permute(0, 3, 1, 2)
    stacked = torch.cat([x, y, x * x, y * y, x * y], dim=1)
    mu_x, mu_y, xx, yy, xy = _gaussian_blur(stacked, window).split(channels, dim=1)

    mu_xx, mu_yy, mu_xy = mu_x * mu_x, mu_y * mu_y, mu_x * mu_y
    sigma_xx = xx - mu_xx
    sigma_yy = yy - mu_yy
    sigma_xy = xy - mu_xy
    return ((2 * mu_xy + SSIM_C1) * (2 * sigma_xy + SSIM_C2)) / (
        (mu_xx + mu_yy + SSIM_C1) * (sigma_xx + sigma_yy + SSIM_C2)
    )


def quantize_8bit(img: torch.Tensor) -> torch.Tensor:
    """The reference's PNG round trip: what a render becomes once saved and read back.

    D-3DGS writes renders and ground truth with ``torchvision.utils.save_image``, which maps
    x to uint8 as ``x * 255 + 0.5`` clamped to [0, 255] and truncated (round half up), and
    its metrics script reads the PNGs back as ``uint8 / 255``. Same shape and dtype as ``img``.
    """
    # Values are non-negative after the clamp, so the uint8 cast truncates = floors.
    levels = (img * 255 + 0.5).clamp(0, 255).to(torch.uint8)
    return levels.to(img.dtype) / 255
