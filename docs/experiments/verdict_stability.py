"""How many (scene, seed) clusters does the stress test need for verdicts that survive a change of machine?

No training: a simulation built on the stress-mini run the README reports (docs/experiments/stress-mini/,
commit 7b60eee, the report of the two-level bootstrap that came before the t-interval). Its "does noise
help?" table gives, for each of the 12 distinct comparisons, the mean difference and the 95% bootstrap
interval over 4 clusters (copied below); the spread s of the cluster means is recovered from the
interval's half-width h as s = h / (1.96 * sqrt(3/4) / 2), the bootstrap's width at 4 clusters. For OU
noise at the 0.75 time split the larger spread of the other machine's four cluster means (issue 22:
-0.20, -0.57, -0.76, -1.54) is used.

A change of machine is modelled as its worst case: every cluster re-drawn, as a change of seed would
(issue 22: the AVX-512 machine moved 4-cluster means by 0.03-0.13 dB, as much as the seed spread; the
README's three runs of stress-mini on different code moved the OU extrapolation mean by up to 0.35 dB).
For n clusters, each of two machines draws n cluster means per comparison around the comparison's
difference, and the report's rule (significance.call: at least MIN_CLUSTERS clusters, the t-interval
wholly beyond +-floor) gives the 12 verdicts. Printed: the share of machine pairs whose 12 verdicts all
agree, with the floor the stress-mini CfC's measured seed spread gives (2 x 0.055 dB: puppet 0.037,
hellwarrior 0.069), a pessimistic one (2 x 0.09 dB, the spread pooled over CfC and SDE-LNN), and no floor
(a verdict wherever the interval excludes 0). "small effects real" takes every measured difference as
the truth, "small effects 0" sets the differences under 0.1 dB to 0. Under 6 clusters nothing is called,
so 4 clusters agree trivially, with no answer.

    .venv/bin/python docs/experiments/verdict_stability.py      # about 20 s
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from liquidgs.experiments.report.significance import MIN_CLUSTERS, call, t_interval

# (variant, strength) -> mean difference, bootstrap interval: docs/experiments/stress-mini/report.md at 7b60eee.
STRESS_MINI = {
    ("sde-l0.1", "0"): (0.016, -0.043, 0.083),
    ("sde-annealed", "0"): (0.027, -0.046, 0.094),
    ("sde-ou", "0"): (-0.460, -0.661, -0.187),
    ("sde-l0.1", "0.03"): (-0.062, -0.122, 0.018),
    ("sde-annealed", "0.03"): (-0.047, -0.110, 0.030),
    ("sde-ou", "0.03"): (-0.551, -0.733, -0.304),
    ("sde-l0.1", "0.1"): (0.025, -0.053, 0.102),
    ("sde-annealed", "0.1"): (-0.008, -0.142, 0.122),
    ("sde-ou", "0.1"): (-0.401, -0.567, -0.257),
    ("sde-l0.1", "0.75"): (-0.066, -0.192, 0.037),
    ("sde-annealed", "0.75"): (0.001, -0.133, 0.119),
    ("sde-ou", "0.75"): (-0.641, -0.935, -0.270),
}
OTHER_MACHINE_OU_SPLIT = [-0.20, -0.57, -0.76, -1.54]
BOOTSTRAP_WIDTH_AT_4 = 1.96 * math.sqrt(3 / 4) / 2
FLOORS = {"CfC seed spread (0.110 dB)": 0.110, "pessimistic (0.180 dB)": 0.180, "no floor": 0.0}
CLUSTERS = (4, 6, 8, 12, 16, 20, 24, 32)
DRAWS = 4000


def comparisons() -> list[tuple[str, float, float]]:
    """(name, mean difference, spread of the cluster means) for each distinct comparison."""
    out = []
    for (variant, strength), (mean, low, high) in STRESS_MINI.items():
        spread = (high - low) / 2 / BOOTSTRAP_WIDTH_AT_4
        if (variant, strength) == ("sde-ou", "0.75"):
            spread = max(spread, float(np.std(OTHER_MACHINE_OU_SPLIT, ddof=1)))
        out.append((f"{variant} at {strength}", mean, spread))
    return out


def verdicts(rng, truth: np.ndarray, spread: np.ndarray, n: int, floor: float) -> np.ndarray:
    """DRAWS x comparisons verdict codes (+1 helps, -1 hurts, 0 tie, 2 too few) of one machine."""
    x = truth[None, :, None] + spread[None, :, None] * rng.standard_normal((DRAWS, len(truth), n))
    mean = x.mean(axis=2)
    half = stats.t.ppf(0.975, n - 1) * x.std(axis=2, ddof=1) / math.sqrt(n)
    codes = np.where(mean - half > floor, 1, np.where(mean + half < -floor, -1, 0))
    if n < MIN_CLUSTERS:
        codes[:] = 2
    # The vectorised rule is significance.call's: check it on a few draws.
    names = {1: "helps", -1: "hurts", 0: "tie", 2: "too few runs to call"}
    for d in range(3):
        for k in range(len(truth)):
            m, low, high = t_interval(x[d, k])
            assert call(m, low, high, n, floor) == names[int(codes[d, k])]
    return codes


def main() -> None:
    table = comparisons()
    print("comparison: mean difference, spread of the cluster means (dB)")
    for name, mean, spread in table:
        print(f"  {name}: {mean:+.3f}, {spread:.3f}")
    spread = np.array([s for _, _, s in table])
    for label, small_zero in (("small effects real", False), ("small effects 0", True)):
        truth = np.array([0.0 if small_zero and abs(m) < 0.1 else m for _, m, _ in table])
        print(f"\nP(all 12 verdicts agree on two machines), {label}:")
        print("  floor".ljust(30) + "".join(f"{n:>8}" for n in CLUSTERS))
        for floor_label, floor in FLOORS.items():
            rng = np.random.default_rng(0)
            agree = []
            for n in CLUSTERS:
                a, b = verdicts(rng, truth, spread, n, floor), verdicts(rng, truth, spread, n, floor)
                agree.append((a == b).all(axis=1).mean())
            print(f"  {floor_label}".ljust(30) + "".join(f"{p:>8.3f}" for p in agree))


if __name__ == "__main__":
    main()
