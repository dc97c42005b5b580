"""Confidence intervals for per-method figures: Wilson score intervals for success rates
(:func:`rate_interval`), percentile bootstrap for times and other means (:func:`bootstrap_ci`).

Percentile bootstrap: resample the n per-run values with replacement B times, compute the
statistic on each resample, and take the (α/2, 1 − α/2) quantiles of those B values as the
interval (α = 1 − level). Seeded, so a report is reproducible.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np


@dataclass(frozen=True)
class Interval:
    """A statistic and its bootstrap interval; all NaN when there are no values."""

    value: float
    low: float
    high: float
    n: int

    def __str__(self) -> str:
        if self.n == 0:
            return "—"
        return f"{self.value:.2f} [{self.low:.2f}, {self.high:.2f}]"


def bootstrap_ci(values, statistic: Callable[[np.ndarray], float] = np.mean,
                 level: float = 0.95, resamples: int = 4000, seed: int = 0) -> Interval:
    """``statistic`` of ``values`` (NaN dropped; booleans count as 0/1) with its percentile
    bootstrap interval at ``level``."""
    x = np.asarray(values, dtype=float).ravel()
    x = x[np.isfinite(x)]
    n = len(x)
    if n == 0:
        return Interval(np.nan, np.nan, np.nan, 0)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, n, size=(resamples, n))
    stats = np.apply_along_axis(statistic, 1, x[idx]) if statistic is not np.mean \
        else x[idx].mean(axis=1)
    alpha = 1.0 - level
    low, high = np.quantile(stats, [alpha / 2, 1 - alpha / 2])
    return Interval(float(statistic(x)), float(low), float(high), n)


def rate_interval(values, level: float = 0.95) -> Interval:
    """A success rate k/n of 0/1 ``values`` (NaN dropped) with its Wilson score interval at
    ``level``: ``(p̂ + z²/2n ± z √(p̂(1 − p̂)/n + z²/4n²)) / (1 + z²/n)``, z the normal quantile.
    Unlike a bootstrap of 0/1 values it does not collapse to a point at 0 or 1 (30 of 30 is
    [0.89, 1.00], not [1.00, 1.00])."""
    x = np.asarray(values, dtype=float).ravel()
    x = x[np.isfinite(x)]
    n = len(x)
    if n == 0:
        return Interval(np.nan, np.nan, np.nan, 0)
    p = float(x.mean())
    z = NormalDist().inv_cdf(0.5 + level / 2.0)
    denom = 1.0 + z * z / n
    center = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1.0 - p) / n + z * z / (4 * n * n)) / denom
    return Interval(p, min(p, max(0.0, center - half)), max(p, min(1.0, center + half)), n)


def mcnemar_exact(lost: int, gained: int) -> float:
    """Two-sided exact McNemar test of paired 0/1 outcomes on the same scenarios: the
    probability, if either change were as likely as the other, of discordant pairs at least as
    uneven as ``lost`` (1 → 0) against ``gained`` (0 → 1),
    ``p = min(1, 2 Σ_{k ≤ min(b, c)} C(b + c, k) / 2^(b + c))``; 1 when there is none."""
    n = lost + gained
    if n == 0:
        return 1.0
    k = min(lost, gained)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2.0 ** n
    return float(min(1.0, 2.0 * tail))
