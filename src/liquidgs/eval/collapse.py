"""When a run's renders have collapsed: the baselines its test views are held against.

A render that is one flat colour, or that scores no better than the background alone (an empty
scene), is not a result whatever its PSNR: on a scene with a black background an all-black image
scores 20 dB. evaluate_views records, per view, the background-only image's PSNR and whether
the render is flat; `collapse_reason` turns a summary into a verdict.
"""

from __future__ import annotations

import torch

from liquidgs.eval.metrics import MIN_MSE, psnr_from_mse

BACKGROUND_MARGIN_DB = 0.1
"""A test PSNR less than this above the background-only image's is no better than rendering nothing."""
LEARNED_MARGIN_DB = 1.0
"""A run whose PSNR was once this far above the background's had learned the scene: if it falls back
to the background's, it collapsed (rather than never having learned, as a run of a few steps)."""
FLAT_STD = 1.0 / 255.0
"""A render whose pixels vary less than one 8-bit level (standard deviation) is one flat colour."""


def background_psnr(truth: torch.Tensor, background: torch.Tensor) -> float:
    """PSNR of the image that shows only the background, against `truth` [H, W, 3] (finite)."""
    mse = (truth - background.to(truth)).pow(2).mean()
    return float(psnr_from_mse(mse.clamp_min(MIN_MSE)))


def is_flat(render: torch.Tensor, truth: torch.Tensor) -> bool:
    """The render is one flat colour where the ground truth is not."""
    return float(render.std()) < FLAT_STD <= float(truth.std())


def collapse_reason(summary: dict, learned: bool) -> str | None:
    """Why the evaluation `summary` (evaluate_views' with a background) is a collapse, or None.

    Every view flat is a collapse; a PSNR no better than the background's is one when the run had
    `learned` (was once LEARNED_MARGIN_DB above it), else it is a run too short to say.
    """
    views, flat = summary["n_views"], summary["flat_views"]
    if flat == views:
        return f"every test render is one flat colour ({views} views)"
    if learned and summary["psnr"] < summary["background_psnr"] + BACKGROUND_MARGIN_DB:
        return (
            f"the test renders are no better than the background alone: PSNR {summary['psnr']:.2f} dB, "
            f"background-only image {summary['background_psnr']:.2f} dB"
        )
    return None


def below_background_note(summary: dict) -> str | None:
    """For a run that finished without having learned (collapse_reason's `learned` false): a note
    when its test PSNR is still no better than the background alone, else None."""
    if "background_psnr" not in summary or summary["psnr"] >= summary["background_psnr"] + BACKGROUND_MARGIN_DB:
        return None
    return (
        f"the final test PSNR ({summary['psnr']:.2f} dB) is no better than the background alone "
        f"({summary['background_psnr']:.2f} dB): the run is too short to have learned the scene"
    )
