"""PSNR over a region of the test pixels (the moving pixels, the foreground), pooled over views.

The squared errors of every masked pixel of every view (all three channels) are summed before
the log is taken, so a view weighs what its masked pixels weigh and a view whose region is
empty adds nothing. (The whole-image PSNR of results.json is the mean of per-view PSNRs.)
Images are 8-bit, as the evaluation scores renders.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import torch

from liquidgs.errors import ConfigError
from liquidgs.eval.metrics import MIN_MSE, psnr_from_mse


def region_psnr(
    renders: Iterable[np.ndarray], truths: Iterable[np.ndarray], masks: Iterable[np.ndarray]
) -> float | None:
    """PSNR (dB) over the pixels where `masks` (bool [H,W]) hold, of uint8 [H,W,3] renders
    against uint8 ground truths, pooled over the views; None when no pixel is masked."""
    squared, count = 0.0, 0
    for render, truth, mask in zip(renders, truths, masks, strict=True):
        if render.shape != truth.shape or mask.shape != truth.shape[:2]:
            raise ConfigError(
                f"region PSNR: render {render.shape}, truth {truth.shape} and mask {mask.shape} do not match"
            )
        error = (render.astype(np.float64) - truth.astype(np.float64)) / 255.0
        squared += float(np.square(error[mask]).sum())
        count += int(mask.sum()) * truth.shape[-1]
    if count == 0:
        return None
    # Identical regions score 120 dB (MIN_MSE) rather than infinity.
    return float(psnr_from_mse(torch.tensor(max(squared / count, MIN_MSE), dtype=torch.float64)))


def region_share(masks: Iterable[np.ndarray]) -> float:
    """The fraction of all pixels of the views that the masks hold."""
    inside, total = 0, 0
    for mask in masks:
        inside += int(mask.sum())
        total += mask.size
    return inside / total if total else 0.0
