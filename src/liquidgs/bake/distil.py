"""Distil a trained run's deformation field into per-Gaussian keyframe tracks (bake/tracks.py)
within an error budget.

The field is sampled at 2 M - 1 uniform times over the capture's time range [0, 1], M the most
keyframes allowed: every keyframe time of every count on the ladder 1, m, 2m - 1, 4m - 3, ..., M
(m the fewest keyframes of a Gaussian that moves) and the midpoints between the most keyframes,
where a spline strays most from its samples. Each Gaussian gets the first count on the ladder
whose spline, quantised as stored, stays within the budget at every one of those times against
the field itself; one keyframe (the value at t = 0.5) for a Gaussian that does not move. What
still exceeds the budget at M keyframes is baked anyway and reported (which Gaussians, at which
times). A Gaussian's size counts as at least BakeSettings.pixel_floor pixel widths (in the camera
that sees it finest), so that sub-pixel Gaussians are not held to sub-pixel accuracy no camera of
the scene shows. Quantisation takes a quarter of the budget: a channel group is stored in 8 bits where
its range allows, else in 16. An 'sde' run is baked from its mean (the noise off), as eval and
render show it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch

from liquidgs.bake.motion import (
    POSITION,
    QUATERNION,
    SCALE,
    align_quaternion_signs,
    count_ladder,
    keyframe_times,
    pack_keyframe,
    state_error,
)
from liquidgs.bake.tracks import CODE_LEVELS, Tracks, pack, unpack
from liquidgs.errors import LiquidGSError

VISIBLE_OPACITY = 1.0 / 255.0
"""Gaussians below this opacity cannot change an 8-bit pixel on their own: their error is not
checked, and they keep one keyframe."""
WORST_LISTED = 100
"""Gaussian/time pairs over budget listed in baked.json (the worst first)."""
QUANTISATION_SHARE = 0.25
"""The share of the budget left to quantisation; the keyframe count is chosen within the rest."""
CHUNK = 8192
"""Gaussians whose errors at every sample time are held at once (memory: times x CHUNK x 10 floats)."""


@dataclass
class BakeSettings:
    tolerance: float = 0.1
    """Error budget at every sample time: position and scale error as a fraction of the
    Gaussian's largest axis, rotation error in radians; every visible Gaussian must stay within it."""
    min_keyframes: int = 2
    """The fewest keyframes of a Gaussian that moves (2: a straight line)."""
    max_keyframes: int = 65
    """Past it the budget is reported, not chased."""
    pixel_floor: float = 4.0
    """In the budget a Gaussian's size counts as at least this many pixel widths in the camera that
    sees it finest: an error within 0.4 px (the default tolerance of 4 px) cannot show at the scene's
    resolution. Measured on the demo scene (MLP, 2,000 iterations): 543 bytes per Gaussian, 53.4 dB
    against the field on its worst test view, where 0 (the size alone) took 959 bytes for 57.2 dB."""

    def ladder(self) -> list[int]:
        return count_ladder(self.min_keyframes, self.max_keyframes)


@dataclass
class Distilled:
    tracks: Tracks
    """As stored: the keyframes dequantised."""
    stored: dict
    """tracks.pack()'s payload."""
    report: dict
    """The budget and the error measured at every sample time, quantisation included."""

    @property
    def keyframes(self) -> torch.Tensor:
        """[K, N, 10]: Tracks.uniform()."""
        return self.tracks.uniform()

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


def field_samples(settings: BakeSettings) -> int:
    """The times distil samples the field at: the keyframe times of the most keyframes and the
    midpoints between them."""
    return 2 * settings.ladder()[-1] - 1


def spline_errors(keyframes: torch.Tensor, truth: torch.Tensor, times: torch.Tensor, floor: torch.Tensor):
    """Relative and position errors [S, n] of the keyframes' splines [K, n, 10] at `times` against
    the field's states there [S, n, 10] (sizes at least `floor` [n]), CHUNK Gaussians at a time."""
    relative, position = [], []
    for start in range(0, keyframes.shape[1], CHUNK):
        part = slice(start, start + CHUNK)
        tracks = Tracks.from_keyframes(keyframes[:, part])
        errors = state_error(tracks.sampled(times), truth[:, part], floor[part])
        relative.append(errors[0])
        position.append(errors[1])
    return torch.cat(relative, dim=1), torch.cat(position, dim=1)


def keys_at(truth: torch.Tensor, count: int) -> torch.Tensor:
    """`count` keyframes [count, n, 10] from the samples [2M - 1, n, 10] at their times: the
    middle sample where `count` is 1."""
    if count == 1:
        return truth[truth.shape[0] // 2][None].clone()
    return align_quaternion_signs(truth[:: (truth.shape[0] - 1) // (count - 1)])


def tracks_errors(tracks: Tracks, truth: torch.Tensor, times: torch.Tensor, floor: torch.Tensor):
    """Relative and position errors [S, N] of every Gaussian's track against the field's samples."""
    relative = torch.empty(truth.shape[:2])
    position = torch.empty(truth.shape[:2])
    for index, keyframes in tracks.groups:
        relative[:, index], position[:, index] = spline_errors(keyframes, truth[:, index], times, floor[index])
    return relative, position


def code_widths(keyframes: torch.Tensor, truth: torch.Tensor, floor: torch.Tensor, budget: float) -> torch.Tensor:
    """[n] uint8, bit c set where channel group c needs 16 bits: 8-bit codes err by at most
    1.25 span / 510 per channel (1.25: the most the spline's weights add up to in absolute value),
    which must stay within `budget` (a fraction of the Gaussian's smallest largest-axis over time,
    or radians: a quaternion's error e turns it by at most 2 |e|)."""
    span = keyframes.amax(0) - keyframes.amin(0)
    size = torch.maximum(truth[..., SCALE].abs().amax(-1).amin(0), floor).clamp_min(1e-12)
    step = 1.25 / (2 * CODE_LEVELS[8])
    errors = (
        step * span[:, POSITION].norm(dim=-1) / size,
        2 * step * span[:, QUATERNION].norm(dim=-1),
        step * span[:, SCALE].amax(-1) / size,
    )
    wide = torch.zeros(keyframes.shape[1], dtype=torch.uint8)
    for group, error in enumerate(errors):
        wide |= ((error > budget).to(torch.uint8)) << group
    return wide


def pixel_widths(cameras, positions: torch.Tensor) -> torch.Tensor:
    """[N]: the width of one pixel at each position in the camera that sees it finest (depth /
    focal length; cameras it is behind count as none), infinite where no camera has it in front."""
    width = torch.full((positions.shape[0],), float("inf"))
    for camera in cameras:
        view = camera.viewmat.float().cpu()
        depth = positions @ view[2, :3] + view[2, 3]
        seen = depth > 1e-6
        width = torch.where(seen, torch.minimum(width, depth / float(camera.K[0, 0])), width)
    return width


def distil(run, settings: BakeSettings, cameras=(), on_sample: Callable[[], None] = lambda: None) -> Distilled:
    """on_sample() after each of the field_samples(settings) field samples."""
    visible = torch.sigmoid(run.params["opacities"]).detach().cpu() >= VISIBLE_OPACITY
    ladder = settings.ladder()
    top = ladder[-1]
    times = keyframe_times(field_samples(settings))
    truth = align_quaternion_signs(sample_field(run, times, on_sample).cpu())
    n = truth.shape[1]
    floor = (
        settings.pixel_floor * pixel_widths(cameras, truth[truth.shape[0] // 2, :, POSITION]).clamp(max=1e30)
        if len(cameras) and settings.pixel_floor
        else torch.zeros(n)
    )
    counts = torch.full((n,), top, dtype=torch.long)
    counts[~visible] = 1
    open_ = visible.clone()
    for count in ladder[:-1]:
        index = open_.nonzero().flatten()
        if not len(index):
            break
        keyframes = keys_at(truth[:, index], count)
        relative, _ = spline_errors(keyframes, truth[:, index], times, floor[index])
        settled = relative.amax(0) <= (1 - QUANTISATION_SHARE) * settings.tolerance
        counts[index[settled]] = count
        open_[index[settled]] = False
    groups = []
    wide = torch.zeros(n, dtype=torch.uint8)
    for count in sorted(set(counts.tolist())):
        index = (counts == count).nonzero().flatten()
        keyframes = keys_at(truth[:, index], count)
        groups.append((index, keyframes))
        wide[index] = code_widths(keyframes, truth[:, index], floor[index], QUANTISATION_SHARE * settings.tolerance)
    stored = pack(Tracks(counts, groups), wide)
    tracks = unpack(stored, n)
    relative, position = tracks_errors(tracks, truth, times, floor)
    relative = torch.where(visible[None, :], relative, torch.zeros_like(relative))
    return Distilled(tracks, stored, error_report(settings, counts, relative, position, times, visible))


def error_report(settings, counts, relative, position, times, visible) -> dict:
    flat = relative.flatten()
    worst = torch.topk(flat, min(WORST_LISTED, flat.numel()))
    over = [divmod(int(i), relative.shape[1]) for v, i in zip(worst.values, worst.indices) if v > settings.tolerance]
    visible_relative = relative[:, visible]
    checked = visible_relative.numel() > 0
    histogram = {str(count): int((counts == count).sum()) for count in sorted(set(counts.tolist()))}
    return {
        "tolerance": settings.tolerance,
        "pixel_floor": settings.pixel_floor,
        "budget": "position and scale error / the Gaussian's largest axis (at least pixel_floor pixel widths in "
        "the camera that sees it finest), rotation error in radians, "
        "at every sample time (the keyframe times of the most keyframes and the midpoints between them), "
        "quantisation included, for Gaussians of opacity >= 1/255",
        "sample_times": len(times),
        "keyframe_counts": histogram,
        "mean_keyframes": float(counts.double().mean()) if len(counts) else 0.0,
        "max_keyframes": settings.ladder()[-1],
        "checked_gaussians": int(visible.sum()),
        "max_relative_error": float(visible_relative.max()) if checked else 0.0,
        "p99_relative_error": float(torch.quantile(quantile_sample(visible_relative), 0.99)) if checked else 0.0,
        "max_position_error": float(position[:, visible].max()) if checked else 0.0,
        "mean_position_error": float(position[:, visible].mean()) if checked else 0.0,
        "gaussians_over_budget": int((relative > settings.tolerance).any(0).sum()),
        "over_budget": [
            {"gaussian": g, "time": round(float(times[m]), 6), "relative_error": float(relative[m, g])}
            for m, g in over[:WORST_LISTED]
        ],
    }


def quantile_sample(values: torch.Tensor) -> torch.Tensor:
    """values flattened, every k-th kept so that at most 16M remain (torch.quantile's limit)."""
    flat = values.flatten().double()
    return flat[:: flat.numel() // 16_000_000 + 1]


def describe_over_budget(report: dict, total: int) -> str:
    """The warning line: how many Gaussians exceed the budget, and the worst few with their times."""
    worst = ", ".join(
        f"#{item['gaussian']} at t={item['time']:.3f} ({item['relative_error']:.2f})"
        for item in report["over_budget"][:5]
    )
    share = 100.0 * report["gaussians_over_budget"] / max(total, 1)
    return (
        f"{report['gaussians_over_budget']:,} of {total:,} Gaussians ({share:.2f}%) exceed the error budget "
        f"{report['tolerance']:g} at {report['max_keyframes']} keyframes (the most allowed); worst: {worst}"
    )
