"""Paired differences between two methods, and when a difference may be called one.

The unit of replication is the cluster: a pair of runs trained alike (same scene, seed and
perturbation), or for the ties rule of the paper tables the two methods' runs on one
(scene, seed). The test views of a run share its training, so they are not independent draws:
each cluster is reduced to its mean difference, and every statistic is over the cluster means.

**Interval: Student's t on the cluster means**, n - 1 degrees of freedom,
mean +- t(0.975, n-1) * s / sqrt(n). Why this one:
- it is exact when the cluster means are normal, and with few clusters it is the standard
  remedy (cluster-robust inference with G clusters uses t with G - 1 degrees of freedom);
  what the runs differ by - the training trajectory a seed, or a machine's float rounding,
  sends a run on - is a sum of many small effects, so normal cluster means are the natural model;
- it is an interval in dB, which the tables print next to the difference.
The two-level percentile bootstrap used before (resample the clusters, then their views) is
too narrow with few clusters: it uses the spread of the cluster means with divisor n instead of
n - 1 and normal-like quantiles instead of t(n - 1) ones, so at 4 clusters its interval is
about 1.96 * sqrt(3/4) / 3.18 = 0.53 of the t-interval's width.
A sign test or a sign-flip permutation test of the cluster means needs no normality, but it
gives a p-value, not an interval in dB, and it cannot reach p < 0.05 at all with few clusters:
its smallest two-sided p-value is 2 / 2^n (0.125 at 4 clusters, 0.0625 at 5, 0.031 at 6).

**Minimum: MIN_CLUSTERS = 6.** Below it no distribution-free test of the cluster means could
call any difference at the 5% level, so a verdict would rest on the normality of 4 or 5 points,
which they cannot check; the verdict is then 'too few runs to call' (the interval is still
printed). From 6 clusters on the t-interval decides.

**Floor (the paper's ties rule).** The paper reads differences under 2 sigma of the
run-to-run PSNR as ties. Here a difference is called only when its whole interval lies beyond
that floor (low > floor: helps; high < -floor: hurts): with 95% confidence it is then larger
than what re-running moves a run by. Re-running the same code on another machine moves a
run by as much as a change of seed (float rounding sends training elsewhere), so an effect of a
few hundredths of a dB is a coin toss between machines for any affordable number of clusters;
with the floor on the interval, a verdict flips only for effects near floor + t * s / sqrt(n),
and more clusters move that boundary in to the floor (docs/experiments/verdict_stability.py
sizes the stress spec by it). With floor 0 this is the plain test of 'the interval excludes 0'.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
MIN_CLUSTERS = 6
"""The fewest clusters a verdict is given on: the smallest n whose sign-flip test can reach 2 / 2^n < 5%."""
TOO_FEW = "too few runs to call"
VERDICTS = ("helps", "hurts", "tie", TOO_FEW)


def smallest_sign_flip_p(n: int) -> float:
    """The smallest two-sided p-value an exact sign (or sign-flip permutation) test of n clusters can give."""
    return min(1.0, 2.0 / 2**n)


def t_interval(values: Sequence[float], confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """(mean, low, high): Student's t-interval of the mean of `values`; low and high are nan below 2 values."""
    x = np.asarray(values, dtype=np.float64)
    if x.size == 0:
        raise ValueError("no values")
    mean = float(x.mean())
    if x.size < 2:
        return mean, math.nan, math.nan
    half = float(stats.t.ppf(0.5 + confidence / 2.0, x.size - 1) * x.std(ddof=1) / math.sqrt(x.size))
    return mean, mean - half, mean + half


def call(mean: float, low: float, high: float, clusters: int, floor: float = 0.0) -> str:
    """'helps' / 'hurts' (a above / below b), 'tie', or TOO_FEW below MIN_CLUSTERS clusters.

    A difference is called when its interval lies wholly above `floor` or wholly below -`floor`."""
    if clusters < MIN_CLUSTERS:
        return TOO_FEW
    if low > floor:
        return "helps"
    if high < -floor:
        return "hurts"
    return "tie"


@dataclass(frozen=True)
class PairedDifference:
    mean: float
    """Mean of the cluster means (a minus b): every cluster weighs the same."""
    low: float
    high: float
    """The CONFIDENCE t-interval of the mean over the clusters (nan with one cluster)."""
    pairs: int
    """Paired values behind it (test views, or runs for the ties rule)."""
    clusters: int
    floor: float = 0.0
    """The interval must lie beyond +-floor (dB) for a verdict; 0: it must exclude 0."""

    @property
    def verdict(self) -> str:
        return call(self.mean, self.low, self.high, self.clusters, self.floor)

    def interval_text(self, digits: int = 3) -> str:
        if math.isnan(self.low):
            return "-"
        return f"[{self.low:+.{digits}f}, {self.high:+.{digits}f}]"


def cluster_difference(means: Sequence[float], floor: float = 0.0, pairs: int | None = None) -> PairedDifference:
    """The difference and its t-interval from one mean difference per cluster."""
    if not len(means):
        raise ValueError("no paired differences")
    mean, low, high = t_interval(means)
    return PairedDifference(mean, low, high, len(means) if pairs is None else pairs, len(means), floor)


def paired_difference(clusters: list[np.ndarray], floor: float = 0.0) -> PairedDifference:
    """The difference over clusters of per-view differences (one array per cluster), each cluster
    reduced to its mean."""
    clusters = [np.asarray(c, dtype=np.float64) for c in clusters if len(c)]
    if not clusters:
        raise ValueError("no paired differences")
    return cluster_difference([float(c.mean()) for c in clusters], floor, sum(len(c) for c in clusters))


def pooled_sigma(groups: Sequence[Sequence[float]]) -> tuple[float | None, int, int]:
    """(sigma, cells, runs): the root mean sample variance over the groups with at least two values
    (each a cell of runs alike but for the seed); sigma is None when no group has two."""
    variances = [float(np.var(g, ddof=1)) for g in groups if len(g) > 1]
    if not variances:
        return None, 0, 0
    return math.sqrt(math.fsum(variances) / len(variances)), len(variances), sum(len(g) for g in groups if len(g) > 1)


def per_view_differences(a: dict, b: dict) -> np.ndarray:
    """PSNR of a minus b on each test view both per_view.json files hold, matched by view name."""
    psnr_b = {view["name"]: view["psnr"] for view in b["views"]}
    return np.array([view["psnr"] - psnr_b[view["name"]] for view in a["views"] if view["name"] in psnr_b])
