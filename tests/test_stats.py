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


@pytest.mark.parametrize("value,count", [
    ("a,b,c", 3), ("1", 1), ("[1,2],[3,4]", 2), ("range(2000,2100)", 100),
    ("range(2000, 2005)", 5), ("range(5)", 5), ("range(0,1,0.25)", 4), ("range(3,1)", 0),
    ("glob(fpm/*)", None)])
def test_a_sweep_override_counts_its_values_as_hydra_sweeps_them(value, count):
    from tamedpuma.analysis.sweep_values import sweep_size, value_count

    assert value_count(value) == count
    if count is not None:  # as Hydra's own parser sweeps it
        from hydra.core.override_parser.overrides_parser import OverridesParser

        override = OverridesParser.create().parse_override(f"k={value}")
        assert count == (len(list(override.sweep_string_iterator()))
                         if override.is_sweep_override() else 1)
    assert sweep_size(["tomato,pouring", value]) == (None if count is None else 2 * count)
