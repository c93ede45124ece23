"""Scores inside and outside per-view masks of the moving subject (`liquidgs eval --mask DIR`).

A mask is DIR/<view name>.png, the size of the view as evaluated; nonzero pixels are the moving
subject (the convention of `data video --mask-dynamic`, whose masks of a video are named by frame
number as its views are). PSNR pools the squared errors of a region over the views
(eval.regions.region_psnr); SSIM is the mean of the SSIM map (eval.metrics.ssim_map, averaged over
channels) over the region's pixels of every view.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from liquidgs.data.validate import open_image
from liquidgs.errors import DataError
from liquidgs.eval.metrics import ssim_map
from liquidgs.eval.regions import region_psnr, region_share


def read_masks(mask_dir: Path, views: Sequence) -> list[np.ndarray]:
    """bool [H, W] per view (`views` have .name and .camera); a missing or mis-sized mask is one
    DataError naming its file."""
    if not Path(mask_dir).is_dir():
        raise DataError(mask_dir, "--mask: mask folder not found")
    masks = []
    for view in views:
        path = Path(mask_dir) / f"{view.name}.png"
        if not path.is_file():
            raise DataError(path, f"--mask: no mask for view '{view.name}' (one per evaluated view, <view name>.png)")
        mask = np.asarray(open_image(path, "L", "--mask mask")) > 0
        width, height = view.camera.width, view.camera.height
        if mask.shape != (height, width):
            size = f"{mask.shape[1]}x{mask.shape[0]}"
            raise DataError(path, f"--mask: mask is {size}, view '{view.name}' is {width}x{height}")
        masks.append(mask)
    return masks


def masked_scores(renders: Sequence[torch.Tensor], truths: Sequence[torch.Tensor], masks: Sequence[np.ndarray]) -> dict:
    """PSNR and SSIM inside and outside the masks of 8-bit-valued [H, W, 3] float renders and truths."""
    as_uint8 = [[np.rint(t.detach().cpu().double().numpy() * 255).astype(np.uint8) for t in ts]
                for ts in (renders, truths)]  # fmt: skip
    maps = [ssim_map(r.cpu().double(), t.cpu().double()).numpy() for r, t in zip(renders, truths, strict=True)]
    scores = {}
    for region, select in (("inside", lambda m: m), ("outside", lambda m: ~m)):
        chosen = [select(m) for m in masks]
        pixels = sum(int(m.sum()) for m in chosen)
        scores[region] = {
            "psnr": region_psnr(*as_uint8, chosen),
            "ssim": float(sum(float(s[m].sum()) for s, m in zip(maps, chosen)) / pixels) if pixels else None,
            "share": region_share(chosen),
        }
    return scores
