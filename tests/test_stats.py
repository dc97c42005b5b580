"""The success-rate interval: Wilson's score interval, checked against its definition by
inversion (the normal test of each bound's rate just rejects the observed rate) and against the
coverage it promises."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tamedpuma.analysis.stats import rate_interval


@pytest.mark.parametrize("k,n", [(0, 10), (3, 10), (7, 7), (28, 30), (30, 30), (97, 100)])
def test_each_bound_is_the_rate_whose_score_test_just_rejects_the_observed_rate(k, n):
    iv = rate_interval(np.r_[np.ones(k), np.zeros(n - k)])
    p_hat, z = k / n, 1.959963984540054
    assert iv.value == pytest.approx(p_hat) and iv.n == n
    for bound in (iv.low, iv.high):
        if 1e-9 < bound < 1.0 - 1e-9:  # |p̂ − p| = z √(p(1 − p)/n) at each bound
            assert abs(p_hat - bound) == pytest.approx(
                z * math.sqrt(bound * (1 - bound) / n), rel=1e-9)
    assert iv.low <= p_hat <= iv.high
    assert iv.low < iv.high  # never a point, also at 0 and 1 (a bootstrap's [1.00, 1.00])


def test_30_of_30_is_not_a_point_and_the_interval_covers_at_its_level():
    assert str(rate_interval(np.ones(30))) == "1.00 [0.89, 1.00]"
    rng = np.random.default_rng(0)
    for p in (0.5, 0.9, 0.97):
        draws = rng.random((4000, 60)) < p
        covered = np.mean([(lambda iv: iv.low <= p <= iv.high)(rate_interval(d)) for d in draws])
        assert covered >= 0.92  # Wilson's coverage is close to 95 % at n = 60


def test_no_values_and_nan_are_left_out():
    assert str(rate_interval([])) == "—"
    assert rate_interval([1.0, np.nan, 0.0]).n == 2
