"""The turning-wear observer on synthetic tools with a known force-wear relation.

Each synthetic tool wears along its own accelerating curve (seeded), its feed rate steps
between blocks (with glitch values as the real table has), and its signal is
``y_r + d (F/F_r - 1) + a1 VB + a2 VB^2`` plus noise. Nothing here reads the real data.
"""

from __future__ import annotations

import numpy as np
import pytest

from estimators.errors import ParameterError
from estimators.wear.turning import (
    ToolSeries,
    TurningWearModel,
    TurningWearParams,
    clean_condition,
    estimate,
    fit,
    life_from,
)

A1, A2, D = 0.4, 0.002, 40.0


def tool(seed: int, n: int = 150, noise: float = 8.0) -> ToolSeries:
    rng = np.random.default_rng(seed)
    rate = rng.uniform(0.8, 2.0)
    k = np.arange(n)
    vb = rate * k * (1 + k / (1.5 * n))
    feed = np.repeat(rng.uniform(1900, 3400, 5), -(-n // 5))[:n]
    y = 350 + rng.normal(0, 10) + D * (feed / feed[0] - 1) + A1 * vb + A2 * vb**2
    y = y + rng.normal(0, noise, n)
    feed_glitched = feed.copy()
    feed_glitched[[20, 77]] = feed[[20, 77]] * 25.0
    return ToolSeries(seed, y, clean_condition(feed_glitched)[0], vb)


def test_clean_condition_replaces_isolated_glitches_and_zeros() -> None:
    x = np.full(30, 2000.0)
    x[10:] = 2500.0
    x[[5, 20]] = [50000.0, 0.0]
    out, n = clean_condition(x)
    assert n == 2
    assert out[5] == 2000.0 and out[20] == 2500.0
    assert np.array_equal(out[[4, 9, 10, 29]], [2000.0, 2000.0, 2500.0, 2500.0])


def test_fit_recovers_the_output_relation_and_estimates_held_out_tools() -> None:
    train = [tool(s) for s in range(8)]
    m = fit(train, "synthetic")
    assert m.a1 == pytest.approx(A1, rel=0.25)
    assert m.a2 == pytest.approx(A2, rel=0.25)
    assert m.d == pytest.approx(D, rel=0.3)
    errs, cover = [], []
    for i in range(100, 110):
        s = tool(i)
        e = estimate(m, s, life=i < 102)
        assert s.vb is not None
        errs.append(np.mean(np.abs(e.vb - s.vb)))
        cover.append(np.mean((s.vb >= e.vb_lo) & (s.vb <= e.vb_hi)))
        assert np.all(e.rate >= 0) and np.all(e.vb_lo <= e.vb) and np.all(e.vb <= e.vb_hi)
        if i < 102:
            assert np.all(e.life_left[e.vb >= 300.0] == 0.0)
            inside = (e.life_left_lo <= e.life_left) & (e.life_left <= e.life_left_hi)
            assert np.mean(inside) > 0.9
    assert max(errs) < 20.0  # noise 8 N at ~0.6 N/um: a few um per segment
    # 10 held-out tools, 95 % intervals calibrated on the 8 training tools (measured 0.91)
    assert np.mean(cover) > 0.85


def test_model_round_trips_and_refuses_another_version() -> None:
    m = fit([tool(1), tool(2)], "x")
    d = m.to_dict()
    assert TurningWearModel.from_dict(d) == m
    with pytest.raises(ParameterError, match="version"):
        TurningWearModel.from_dict({**d, "version": 99})


def test_life_from_the_law() -> None:
    # straight line when lambda is long; 0 at the criterion; inf with no rate
    assert life_from(np.array([100.0]), np.array([2.0]), 300.0, 1e9)[0] == pytest.approx(100.0)
    assert life_from(np.array([300.0]), np.array([2.0]), 300.0, 100.0)[0] == 0.0
    assert np.isinf(life_from(np.array([10.0]), np.array([0.0]), 300.0, 100.0)[0])
    # an accelerating law ends sooner
    assert life_from(np.array([100.0]), np.array([2.0]), 300.0, 100.0)[0] < 100.0


def test_fit_refuses_tools_without_vb() -> None:
    s = tool(3)
    with pytest.raises(ParameterError, match="measured VB"):
        fit([ToolSeries(3, s.y, s.feed, None)])
    with pytest.raises(ParameterError, match="coverage"):
        TurningWearParams(coverage=1.5)
