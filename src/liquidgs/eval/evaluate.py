"""Evaluate a set of views, whatever renders them."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Protocol

import torch

from liquidgs.errors import ConfigError
from liquidgs.eval.collapse import background_psnr, is_flat
from liquidgs.eval.lpips import LPIPS, LPIPSUnavailable
from liquidgs.eval.metrics import psnr, quantize_8bit, ssim


class EvalFrame(Protocol):
    """What evaluation needs from a view: its name, its time and its ground-truth image."""

    name: str
    time: float

    def image(self) -> torch.Tensor:
        """Ground truth, [H, W, 3] float in [0, 1]."""
        ...


def _mean_std(values: list[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (ddof=1, as nerfstudio reports it; 0 for one value)."""
    mean = math.fsum(values) / len(values)
    if len(values) < 2:
        return mean, 0.0
    variance = math.fsum((v - mean) ** 2 for v in values) / (len(values) - 1)
    return mean, math.sqrt(variance)


def evaluate_views(
    render_fn: Callable[[EvalFrame], torch.Tensor],
    frames: Sequence[EvalFrame],
    *,
    lpips: LPIPS | None,
    lpips_error: str | None = None,
    quantize: bool = True,
    background: torch.Tensor | None = None,
) -> tuple[dict[str, object], list[dict[str, object]]]:
    """Score ``render_fn(frame)`` against ``frame.image()`` for every frame.

    Both images are clamped to [0, 1] (the reference saves them clamped) and, with
    ``quantize``, passed through the 8-bit PNG round trip the reference's metrics script
    sees. ``lpips=None`` leaves LPIPS out; ``lpips_error`` then says why (e.g. the message of
    :class:`~liquidgs.eval.lpips.LPIPSUnavailable`, "LPIPS-VGG unavailable: ...") and lands in
    the summary, which also says that no other backbone stood in for it. With ``background``
    (RGB), each view also records the background-only image's PSNR and whether the render is
    one flat colour (eval.collapse), and the summary their mean and count.

    Returns ``(summary, per_view)``: the summary holds psnr/ssim/lpips means with ``*_std``
    (sample std), ``n_views``, ``quantized_8bit`` and either the ``lpips_*`` description or
    ``lpips_unavailable``; each per-view record holds name, time, psnr, ssim, lpips.
    """
    if lpips is not None and lpips_error is not None:
        raise ConfigError("evaluate_views: give an LPIPS model or the reason it is unavailable, not both")
    if len(frames) == 0:
        raise ConfigError("evaluate_views: no views to evaluate")

    per_view: list[dict[str, object]] = []
    with torch.no_grad():
        for frame in frames:
            render = render_fn(frame).clamp(0, 1)
            truth = frame.image().to(render.device, render.dtype).clamp(0, 1)
            if quantize:
                render, truth = quantize_8bit(render), quantize_8bit(truth)
            score = None
            if lpips is not None:
                try:
                    score = lpips(render, truth).item()
                except LPIPSUnavailable as err:  # images too small for its network: reported, not a crash
                    lpips, lpips_error = None, str(err)
            view = {
                "name": frame.name,
                "time": float(frame.time),
                "psnr": psnr(render, truth).item(),
                "ssim": ssim(render, truth).item(),
                "lpips": score,
            }
            if background is not None:
                empty = background.to(truth).expand_as(truth)
                empty = quantize_8bit(empty) if quantize else empty
                view["background_psnr"] = background_psnr(truth, empty)
                view["flat"] = is_flat(render, truth)
            per_view.append(view)
    if lpips is None:
        for view in per_view:
            view["lpips"] = None

    summary: dict[str, object] = {}
    for metric in ("psnr", "ssim"):
        summary[metric], summary[f"{metric}_std"] = _mean_std([view[metric] for view in per_view])
    if lpips is not None:
        summary["lpips"], summary["lpips_std"] = _mean_std([view["lpips"] for view in per_view])
        summary.update({f"lpips_{key}": value for key, value in lpips.describe().items()})
    else:
        summary["lpips"] = summary["lpips_std"] = None
        # No backbone stands in for a missing one: a score of another backbone is not comparable.
        reason = lpips_error or "no LPIPS model was given"
        summary["lpips_unavailable"] = f"{reason}; no other LPIPS backbone was used instead"
    if background is not None:
        summary["background_psnr"] = math.fsum(view["background_psnr"] for view in per_view) / len(per_view)
        summary["flat_views"] = sum(view["flat"] for view in per_view)
    summary["n_views"] = len(per_view)
    summary["quantized_8bit"] = quantize
    return summary, per_view


def describe_lpips(summary: dict) -> str:
    """LPIPS of an evaluation summary for a one-line report: the metric and value, or why it is missing."""
    if summary.get("lpips") is None:
        return f"({summary.get('lpips_unavailable', 'LPIPS not computed')})"
    return f"{summary.get('lpips_metric', 'LPIPS')} {summary['lpips']:.4f}"
