"""Scores inside and outside per-view masks of the moving subject (`liquidgs eval --mask DIR`).

A mask is DIR/<view name>.png, the size of the view as evaluated; pixels of nonzero grey level are
the moving subject (the convention of `data video --mask-dynamic`, whose masks of a video are named
by frame number as its views are). In a mask with an alpha channel whose grey level is one value
over the image, nonzero alpha is the subject; one whose grey level and alpha both vary is refused
unless they mark the same pixels. A view's mask may be empty (the subject has left the frame: the
view adds nothing inside); a set that is empty in every view, or covers every pixel of every view,
is refused, as it leaves one region without a pixel to score. PSNR pools the squared errors of a region over the views
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


def _subject(path: Path) -> np.ndarray:
    """The mask file's subject as bool [H, W], by the rule of the module's text."""
    grey, alpha = np.moveaxis(np.asarray(open_image(path, "LA", "--mask mask")), -1, 0)
    if (alpha == alpha.flat[0]).all():
        return grey > 0
    if (grey == grey.flat[0]).all():
        return alpha > 0
    if not np.array_equal(grey > 0, alpha > 0):
        raise DataError(path, "--mask: its grey level and its alpha channel mark different pixels (keep the mask "
                        "in one of them, the other one flat)")  # fmt: skip
    return grey > 0


def read_masks(mask_dir: Path, views: Sequence) -> list[np.ndarray]:
    """bool [H, W] per view (`views` have .name and .camera); a missing, mis-sized or ambiguous mask
    is one DataError naming its file, a set with no pixel inside or none outside one naming the folder."""
    if not Path(mask_dir).is_dir():
        raise DataError(mask_dir, "--mask: mask folder not found")
    masks = []
    for view in views:
        path = Path(mask_dir) / f"{view.name}.png"
        if not path.is_file():
            raise DataError(path, f"--mask: no mask for view '{view.name}' (one per evaluated view, <view name>.png)")
        mask = _subject(path)
        width, height = view.camera.width, view.camera.height
        if mask.shape != (height, width):
            size = f"{mask.shape[1]}x{mask.shape[0]}"
            raise DataError(path, f"--mask: mask is {size}, view '{view.name}' is {width}x{height}")
        masks.append(mask)
    if not any(mask.any() for mask in masks):
        raise DataError(mask_dir, "--mask: every mask is empty (no nonzero pixel in any view): nothing inside to score")
    if all(mask.all() for mask in masks):
        raise DataError(mask_dir, "--mask: every mask covers its whole view: nothing outside to score")
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
