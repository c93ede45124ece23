"""Distil a trained run's deformation field into keyframes (bake/motion.py) within an error budget.

The field is sampled at K uniform keyframe times over the capture's time range [0, 1]; the
spline passes through those samples. The error is measured where a spline strays most from its
samples, half-way between keyframes, against the field itself there. While some visible
Gaussian exceeds the budget the keyframe count is doubled (2K - 1: the old midpoints become
keyframes, so no field sample is wasted), up to a maximum; what still exceeds the budget then is
baked anyway and reported (which Gaussians, at which times). An 'sde' run is baked from its mean
(the noise off), as eval and render show it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import torch

from liquidgs.bake.motion import align_quaternion_signs, interpolate, keyframe_times, pack_keyframe, state_error
from liquidgs.errors import LiquidGSError

VISIBLE_OPACITY = 1.0 / 255.0
"""Gaussians below this opacity cannot change an 8-bit pixel on their own: their error is not checked."""
WORST_LISTED = 100
"""Gaussian/time pairs over budget listed in baked.json (the worst first)."""


@dataclass
class BakeSettings:
    tolerance: float = 0.1
    """Error budget at the midpoints between keyframes: position and scale error as a fraction of the
    Gaussian's largest axis, rotation error in radians; every visible Gaussian must stay within it."""
    min_keyframes: int = 9
    max_keyframes: int = 65
    """Measured on the demo scene (MLP, 2,000 iterations): 65 keyframes render at 63 dB against the field
    (129: 72 dB), half the bytes; past it the budget is reported, not chased."""


@dataclass
class Distilled:
    keyframes: torch.Tensor
    """[K, N, 10]"""
    report: dict
    """The budget and the error measured at the midpoints of the final keyframes."""

    @property
    def over_budget(self) -> list[dict]:
        return self.report["over_budget"]


def check_finished(run, command: str) -> None:
    """Only a finished run is baked (a failed or unfinished one would be published as if done)."""
    if not run.finished:
        raise LiquidGSError(f"{run.run_dir}: {run.progress_label}; {command} needs a finished run")


def sample_field(run, times: torch.Tensor, on_sample: Callable[[], None] = lambda: None) -> torch.Tensor:
    """The field's deformed Gaussians [len(times), N, 10] (the noise off); on_sample after each time."""
    states = []
    for t in times.tolist():
        g = run.at_time(t)
        states.append(pack_keyframe(g.means, g.quats, g.scales).float())
        on_sample()
    return torch.stack(states)


def most_samples(settings: BakeSettings) -> int:
    """The field samples distil takes when the keyframes double up to the most allowed."""
    count, samples = settings.min_keyframes, settings.min_keyframes
    while True:
        samples += count - 1
        if 2 * count - 1 > settings.max_keyframes:
            return samples
        count = 2 * count - 1


def interleave(keyframes: torch.Tensor, midpoints: torch.Tensor) -> torch.Tensor:
    """Keyframes at 2K - 1 uniform times from the K keyframes and the K - 1 samples between them."""
    merged = torch.empty(2 * keyframes.shape[0] - 1, *keyframes.shape[1:], dtype=keyframes.dtype)
    merged[0::2], merged[1::2] = keyframes, midpoints
    return merged


def midpoint_errors(keyframes: torch.Tensor, midpoints: torch.Tensor, times: torch.Tensor):
    """Relative errors [M, N] and position errors [M, N] of the spline at `times` against the field."""
    pairs = [state_error(interpolate(keyframes, t), truth) for t, truth in zip(times.tolist(), midpoints)]
    return torch.stack([p[0] for p in pairs]), torch.stack([p[1] for p in pairs])


def distil(run, settings: BakeSettings, on_sample: Callable[[int], None] = lambda keyframes: None) -> Distilled:
    """on_sample(keyframes) after each field sample, with the keyframe count being checked."""
    visible = torch.sigmoid(run.params["opacities"]).cpu() >= VISIBLE_OPACITY
    count = settings.min_keyframes
    keyframes = align_quaternion_signs(sample_field(run, keyframe_times(count), partial(on_sample, count)).cpu())
    while True:
        grid = keyframe_times(count)
        mid_times = (grid[:-1] + grid[1:]) / 2
        midpoints = sample_field(run, mid_times, partial(on_sample, count)).cpu()
        relative, position = midpoint_errors(keyframes, midpoints, mid_times)
        relative = torch.where(visible[None, :], relative, torch.zeros_like(relative))
        if bool((relative <= settings.tolerance).all()) or 2 * count - 1 > settings.max_keyframes:
            break
        # The midpoints join the keyframes, hemisphere-aligned with the keyframe before each.
        keyframes = align_quaternion_signs(interleave(keyframes, midpoints))
        count = 2 * count - 1
    return Distilled(keyframes, error_report(settings, count, relative, position, mid_times, visible))


def error_report(settings, count, relative, position, mid_times, visible) -> dict:
    over = (relative > settings.tolerance).nonzero().tolist()
    over.sort(key=lambda pair: -float(relative[pair[0], pair[1]]))
    visible_relative = relative[:, visible]
    return {
        "tolerance": settings.tolerance,
        "budget": "position and scale error / the Gaussian's largest axis, rotation error in radians, "
        "at the midpoints between keyframes, for Gaussians of opacity >= 1/255",
        "keyframes": count,
        "max_keyframes": settings.max_keyframes,
        "checked_gaussians": int(visible.sum()),
        "max_relative_error": float(visible_relative.max()) if visible_relative.numel() else 0.0,
        "p99_relative_error": float(torch.quantile(visible_relative.flatten().double(), 0.99))
        if visible_relative.numel()
        else 0.0,
        "max_position_error": float(position[:, visible].max()) if visible_relative.numel() else 0.0,
        "mean_position_error": float(position[:, visible].mean()) if visible_relative.numel() else 0.0,
        "gaussians_over_budget": len({g for _, g in over}),
        "over_budget": [
            {"gaussian": g, "time": round(float(mid_times[m]), 6), "relative_error": float(relative[m, g])}
            for m, g in over[:WORST_LISTED]
        ],
    }


def describe_over_budget(report: dict, total: int) -> str:
    """The warning line: how many Gaussians exceed the budget, and the worst few with their times."""
    worst = ", ".join(
        f"#{item['gaussian']} at t={item['time']:.3f} ({item['relative_error']:.2f})"
        for item in report["over_budget"][:5]
    )
    share = 100.0 * report["gaussians_over_budget"] / max(total, 1)
    return (
        f"{report['gaussians_over_budget']:,} of {total:,} Gaussians ({share:.2f}%) exceed the error budget "
        f"{report['tolerance']:g} at {report['keyframes']} keyframes (the most allowed); worst: {worst}"
    )
