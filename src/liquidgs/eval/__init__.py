"""Evaluation: PSNR / SSIM / LPIPS metrics and the evaluation of a set of rendered views.

Importing this package loads no weights; an :class:`LPIPS` reads its files when built.
"""

from liquidgs.eval.evaluate import EvalFrame, describe_lpips, evaluate_views
from liquidgs.eval.lpips import LPIPS, LPIPSUnavailable, lin_weights_path, resolve_backbone_weights
from liquidgs.eval.metrics import psnr, quantize_8bit, ssim

__all__ = [
    "LPIPS",
    "EvalFrame",
    "LPIPSUnavailable",
    "describe_lpips",
    "evaluate_views",
    "lin_weights_path",
    "psnr",
    "quantize_8bit",
    "resolve_backbone_weights",
    "ssim",
]
