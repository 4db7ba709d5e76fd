"""The one-sided 95 % bounds every reproduction takes (server/experiments/confidence.py).

Each bound is checked against its defining property (the binomial or Poisson tail at the
bound is 5 %), not against numbers copied from elsewhere, and the two sample sizes the
docs state: >= 99 % detection needs 299 events with no miss, <= 1 false alarm per 10 h
needs 30 h with none.
"""

from __future__ import annotations

import math

import pytest
from scipy.stats import binom, poisson

from server.experiments import confidence as ci


@pytest.mark.parametrize(("k", "n"), [(1, 10), (5, 10), (9, 10), (368, 370), (54, 60)])
def test_share_bounds_leave_five_percent_in_their_tail(k: int, n: int) -> None:
    lo, hi = ci.proportion_bounds(k, n)
    # lower: P(X >= k | lo) = 5 %; upper: P(X <= k | hi) = 5 %
    assert binom.sf(k - 1, n, lo) == pytest.approx(0.05, rel=1e-6)
    assert binom.cdf(k, n, hi) == pytest.approx(0.05, rel=1e-6)
    assert lo < k / n < hi


def test_share_bounds_at_the_ends() -> None:
    assert ci.proportion_lower(4, 4) == pytest.approx(0.05**0.25)
    assert ci.proportion_upper(4, 4) == 1.0
    assert ci.proportion_lower(0, 7) == 0.0
    assert ci.proportion_upper(0, 7) == pytest.approx(1 - 0.05 ** (1 / 7))
    with pytest.raises(ValueError, match="k=5, n=4"):
        ci.proportion_lower(5, 4)


def test_299_events_without_a_miss_reach_99_percent() -> None:
    assert ci.events_for(0.99) == 299
    assert ci.proportion_lower(299, 299) >= 0.99 > ci.proportion_lower(298, 298)
    # one miss needs more events
    assert ci.proportion_lower(299, 300) < 0.99


def test_30_hours_without_an_alarm_reach_one_per_10_hours() -> None:
    assert ci.hours_for(0.1) == pytest.approx(29.957, abs=1e-3)
    assert ci.rate_upper(0, 30.0) <= 0.1 < ci.rate_upper(0, 29.9)
    assert ci.rate_upper(0, 38.0) == pytest.approx(-math.log(0.05) / 38.0)
    for k in (1, 3, 10):
        hi = ci.rate_upper(k, 20.0)
        lo = ci.rate_lower(k, 20.0)
        assert poisson.cdf(k, hi * 20.0) == pytest.approx(0.05, rel=1e-6)
        assert poisson.sf(k - 1, lo * 20.0) == pytest.approx(0.05, rel=1e-6)
    with pytest.raises(ValueError, match="exposure"):
        ci.rate_upper(0, 0.0)


def test_quantile_upper_bound_covers_the_quantile() -> None:
    assert ci.quantile_upper([1.0, 2.0, 3.0], 0.95) == math.inf
    assert math.isnan(ci.quantile_upper([], 0.5))
    x = [float(i) for i in range(200)]
    u = ci.quantile_upper(x, 0.5)
    assert 100 <= u < 120
    # x[u] is the (u + 1)-th order statistic: P(Binom(200, 0.5) <= u) >= 95 %, and the
    # one below it would not do
    assert binom.cdf(u, 200, 0.5) >= 0.95 > binom.cdf(u - 1, 200, 0.5)
