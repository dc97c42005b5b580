"""Bootstrap confidence intervals for per-method figures (success rate, times).

Percentile bootstrap: resample the n per-run values with replacement B times, compute the
statistic on each resample, and take the (α/2, 1 − α/2) quantiles of those B values as the
interval (α = 1 − level). Seeded, so a report is reproducible.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

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
