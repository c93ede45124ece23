"""Paired differences with a bootstrap confidence interval: is one method better than another?

The pairs are per-view PSNRs of two runs trained alike (same scene, seed and perturbation),
matched by test view. Views of one run share its training and are correlated, so the
bootstrap is two-level: it resamples the (scene, seed) clusters with replacement, then the
views within each drawn cluster, and takes the mean difference of the pooled draw.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CONFIDENCE = 0.95
BOOTSTRAP_DRAWS = 4000
BOOTSTRAP_SEED = 0
"""Fixed, so the same runs always give the same interval."""


@dataclass(frozen=True)
class PairedDifference:
    mean: float
    """Mean of the per-view differences (a minus b), pooled over every cluster."""
    low: float
    high: float
    """The CONFIDENCE bootstrap percentile interval of the mean."""
    pairs: int
    clusters: int

    @property
    def verdict(self) -> str:
        """'helps' / 'hurts' when the interval excludes 0 (a above / below b), else 'tie'."""
        if self.low > 0:
            return "helps"
        if self.high < 0:
            return "hurts"
        return "tie"


def paired_difference(clusters: list[np.ndarray], draws: int = BOOTSTRAP_DRAWS) -> PairedDifference:
    """The mean difference and its two-level bootstrap interval; each array is one cluster's
    per-view differences."""
    clusters = [np.asarray(c, dtype=np.float64) for c in clusters if len(c)]
    if not clusters:
        raise ValueError("no paired differences")
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    means = np.empty(draws)
    for d in range(draws):
        picked = rng.integers(0, len(clusters), len(clusters))
        total = count = 0.0
        for k in picked:
            views = clusters[k]
            total += views[rng.integers(0, len(views), len(views))].sum()
            count += len(views)
        means[d] = total / count
    tail = (1.0 - CONFIDENCE) / 2.0
    low, high = np.quantile(means, [tail, 1.0 - tail])
    pooled = np.concatenate(clusters)
    return PairedDifference(float(pooled.mean()), float(low), float(high), len(pooled), len(clusters))


def per_view_differences(a: dict, b: dict) -> np.ndarray:
    """PSNR of a minus b on each test view both per_view.json files hold, matched by view name."""
    psnr_b = {view["name"]: view["psnr"] for view in b["views"]}
    return np.array([view["psnr"] - psnr_b[view["name"]] for view in a["views"] if view["name"] in psnr_b])
