"""Learning-rate schedules of 3DGS / D-3DGS."""

from __future__ import annotations

import math


def log_linear_lr(step: int, lr_init: float, lr_final: float, max_steps: int) -> float:
    """Log-linear interpolation from lr_init to lr_final over max_steps, then constant.

    This is 3DGS's get_expon_lr_func without the delay (D-3DGS calls it with no delay steps,
    so its delay multiplier has no effect).
    """
    if lr_init == 0.0 and lr_final == 0.0:
        return 0.0
    t = min(max(step / max(max_steps, 1), 0.0), 1.0)
    return math.exp(math.log(lr_init) * (1.0 - t) + math.log(lr_final) * t)


def smooth_time_noise_scale(step: int, anneal_steps: int = 20_000) -> float:
    """D-3DGS annealed smooth training: s(i) = 0.1 (1 - c) + 1e-15 c, c = clip(i / 20k, 0, 1)."""
    c = min(max(step / anneal_steps, 0.0), 1.0)
    return 0.1 * (1.0 - c) + 1e-15 * c
