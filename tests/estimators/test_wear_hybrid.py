"""The hybrid wear filter (issue 35) on synthetic tools with a known signal-wear map.

Each synthetic tool wears along its own curve, its signal is ``level(feed) + offset +
a VB`` plus noise; nothing here reads the real data.
"""

from __future__ import annotations

import numpy as np
import pytest

from estimators.errors import ParameterError
from estimators.wear.hybrid import (
    HybridConfig,
    ToolData,
    _pava,
    candidates,
    fit,
    fresh_reference,
    life_end,
)

A = 0.8


def tool(seed: int, n: int = 150, start: float = 0.0, feed: float = 2260.0) -> ToolData:
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    vb = start + rng.uniform(1.0, 2.0) * k
    level = 300.0 + 0.05 * (feed - 2000.0)
    y = level + rng.normal(0, 5) + A * vb + rng.normal(0, 6, n)
    return ToolData(seed, y[:, None], np.full(n, feed), vb, start)


def test_candidates_are_the_protocols_list() -> None:
    c = candidates(revision=2)
    assert len(c) == 176 and len({x.label for x in c}) == 176
    assert len(candidates(revision=1)) == 40
    # revision 3 (shrunk by physics): every one filtered, monotone maps on the _MEANs,
    # boosting on every feature, the rate's random walk at most 1e-4
    c3 = candidates()
    assert len(c3) == 36 == len({x.label for x in c3})
    assert all(x.smoothing is not None and x.smoothing <= 1e-4 for x in c3)
    assert {(x.map, x.features) for x in c3} == {
        ("linear", "mean"),
        ("isotonic", "mean"),
        ("gbr", "five"),
    }


def test_bad_config_names_the_field() -> None:
    with pytest.raises(ParameterError, match="map"):
        HybridConfig(map="spline")
    with pytest.raises(ParameterError, match="smoothing"):
        HybridConfig(smoothing=-1.0)


def test_pava_is_monotone_and_keeps_the_mean() -> None:
    y = np.array([3.0, 1.0, 2.0, 5.0, 4.0])
    f = _pava(y, np.ones(5))
    assert np.all(np.diff(f) >= 0) and f.mean() == pytest.approx(y.mean())


def test_fresh_reference_is_a_line_in_the_feed() -> None:
    tools = [tool(s, feed=2000.0 + 500.0 * (s % 3)) for s in range(1, 31)]
    ref = fresh_reference(tools)
    # the level rises 0.05 per feed unit = 50 per 1000 units (tool offsets S.D. 5)
    assert ref[1, 0] == pytest.approx(50.0, abs=15.0)


@pytest.mark.parametrize(
    "cfg",
    [HybridConfig("conditions", m, 1e-2) for m in ("linear", "quadratic", "isotonic", "gbr")]
    + [HybridConfig("conditions", "linear", 1e-3, offset=True)],
)
def test_filter_tracks_an_unseen_tool_and_its_rate_never_falls_below_zero(
    cfg: HybridConfig,
) -> None:
    m = fit([tool(s) for s in range(1, 7)], cfg)
    new = tool(99)
    est, sd, rate = m.run(new)
    assert new.vb is not None
    assert float(np.mean(np.abs(est - new.vb))) < 20.0
    assert np.all(rate >= 0.0) and np.all(sd > 0)


def test_map_alone_has_the_maps_sd() -> None:
    m = fit([tool(s) for s in range(1, 5)], HybridConfig("none", "linear", None))
    _, sd, rate = m.run(tool(50))
    assert np.all(np.isnan(rate)) and np.allclose(sd, np.sqrt(m.sigma2))


def test_a_tool_entered_part_way_starts_from_its_record_not_as_new() -> None:
    m = fit([tool(s) for s in range(1, 7)], HybridConfig("conditions", "linear", 1e-3))
    worn = tool(42, start=0.0)
    assert worn.vb is not None
    k = 100
    with_record = worn.tail(k, record=True)
    assert with_record.start_vb == pytest.approx(worn.vb[k])
    e_rec, _, _ = m.run(with_record)
    e_none, _, _ = m.run(worn.tail(k, record=False))
    assert with_record.vb is not None
    # with its record the first estimate is near the true VB; with none it starts from
    # a fresh tool's prior (~0) and the map pulls it up
    assert abs(e_rec[0] - worn.vb[k]) < 20.0
    assert e_none[0] < e_rec[0]


def test_life_end_is_linear_in_the_rate_and_never_for_zero() -> None:
    est = np.array([0.0, 10.0, 20.0])
    assert life_end(est, np.array([10.0, 10.0, 10.0]), 2, 100.0) == pytest.approx(10.0)
    assert life_end(est, np.zeros(3), 2, 100.0) == float("inf")
    # the training tools' rate at these conditions, whatever the filter's rate says
    assert life_end(est, np.zeros(3), 2, 100.0, method="prior", prior=5.0) == pytest.approx(
        2.0 + (100.0 - est[2]) / 5.0
    )
