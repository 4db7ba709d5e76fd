"""The hybrid wear filter (issue 35) on synthetic tools with a known signal-wear map.

Each synthetic tool wears along its own curve, its signal is ``level(feed) + offset +
a VB`` plus noise; nothing here reads the real data.
"""

from __future__ import annotations

import numpy as np
import pytest

from estimators.errors import ParameterError
from estimators.wear.hybrid import (
    TAYLOR_B,
    HybridConfig,
    ToolData,
    _pava,
    candidates,
    choose_rate_law,
    fit,
    fresh_reference,
    life_end,
    median_rate,
    segment_b,
    segment_fit,
    taylor_fit,
    taylor_rate,
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
    with pytest.raises(ParameterError, match="rate_law"):
        HybridConfig(rate_law="power")
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


def test_revision_4_keeps_revision_3s_configurations() -> None:
    # the prior rate's rule is chosen per fold on the rates, not a configuration
    assert candidates(revision=4) == candidates(revision=3)
    assert HybridConfig(rate_law="taylor").label.endswith("/rate=taylor")
    assert "rate=" not in HybridConfig().label


def test_taylor_law_recovers_its_exponent_and_clips_it_to_the_physical_range() -> None:
    feeds = [2000.0, 2100.0, 2260.0, 2260.0, 2500.0, 3300.0]
    for b in (1.0, 2.5, 4.0):
        rates = [(f, 1.8 * (f / 2260.0) ** b) for f in feeds]
        level, bf, raw, vref = taylor_fit(rates)
        assert vref == 2260.0 and bf == pytest.approx(b) and raw == pytest.approx(b)
        assert taylor_rate((level, bf, raw, vref), 3000.0) == pytest.approx(
            1.8 * (3000.0 / 2260.0) ** b
        )
    # a rate that falls with the speed, or grows faster than any carbide: clipped
    falling = [(f, 1.8 * (f / 2260.0) ** -1.5) for f in feeds]
    assert taylor_fit(falling)[1] == TAYLOR_B[0] and taylor_fit(falling)[2] == pytest.approx(-1.5)
    steep = [(f, 1.8 * (f / 2260.0) ** 9) for f in feeds]
    assert taylor_fit(steep)[1] == TAYLOR_B[1]
    # one condition: no slope, the least extrapolation; the level is the median
    one = [(2260.0, r) for r in (0.5, 1.0, 3.0)]
    level, bf, raw, _ = taylor_fit(one)
    assert bf == TAYLOR_B[0] and np.isnan(raw)
    assert taylor_rate((level, bf, raw, 2260.0), 2260.0) == pytest.approx(1.0)
    with pytest.raises(ParameterError, match="rates"):
        taylor_fit([(2260.0, 1.0)])


def test_a_tool_alone_at_its_speed_gets_the_laws_rate_not_the_median() -> None:
    rates = [(f, 1.5 * (f / 2260.0) ** 2) for f in (2080.0, 2090.0, *[2260.0] * 6)]
    assert median_rate(rates, 3320.0) == pytest.approx(1.5)  # the median over all
    law = taylor_fit(rates)
    assert taylor_rate(law, 3320.0) == pytest.approx(1.5 * (3320.0 / 2260.0) ** 2)
    m = fit([tool(s, feed=f) for s, f in enumerate((2080.0, 2260.0, 2260.0))], HybridConfig())
    r_med = m.prior_rate(3320.0)[0]
    m.config = HybridConfig(rate_law="taylor")
    assert m.prior_rate(3320.0)[0] == pytest.approx(taylor_rate(m.taylor, 3320.0))
    assert m.prior_rate(3320.0)[0] != pytest.approx(r_med)


def test_the_rate_law_is_chosen_on_what_it_predicts() -> None:
    rng = np.random.default_rng(4)
    feeds = [2080.0, 2090.0, 2260.0, 2265.0, 2270.0, 2500.0, 2900.0, 3300.0]
    law = [(f, 1.5 * (f / 2260.0) ** 3 * rng.lognormal(0, 0.05)) for f in feeds]
    best, score = choose_rate_law(law)
    assert best == "taylor" and score["taylor"] < score["median"]
    # one condition: both rules are the median of the others, a tie goes to median
    best, score = choose_rate_law([(2260.0, r) for r in (0.5, 1.0, 1.8, 3.0)])
    assert best == "median" and score["taylor"] == pytest.approx(score["median"])


def _scheduled(seed: int, b: float, *, accel: float = 0.0) -> ToolData:
    """A tool cut at a schedule of four speed blocks (VB measured at each change), its
    wear per segment 1.5 (v / 2260)^b (1 + accel VB / 100)."""
    rng = np.random.default_rng(seed)
    blocks = rng.permutation([1930.0, 2260.0, 2480.0, 2730.0])
    feed = np.repeat(blocks, 40)
    vb = np.zeros(len(feed))
    for k in range(1, len(feed)):
        vb[k] = vb[k - 1] + 1.5 * (feed[k - 1] / 2260.0) ** b * (1 + accel * vb[k - 1] / 100)
    kn = np.array([0, 40, 80, 120, len(feed) - 1])
    vb = np.interp(np.arange(len(feed)), kn, vb[kn])  # measured at the changes only
    return ToolData(seed, vb[:, None], feed, vb, 0.0)


def test_revision_5_reads_the_speed_exponent_from_within_the_tools() -> None:
    for b in (0.0, 2.0, 4.0):
        tools = [_scheduled(s, b, accel=0.2) for s in range(5)]
        assert segment_b(tools, 2260.0) == pytest.approx(b, abs=0.6)
    # the filter's prediction scales each segment's wear by its speed; the prior rate
    # is the training tools' rate at vref, read at the segment's speed
    tools = [_scheduled(s, 2.0) for s in range(5)]
    m = fit(tools, HybridConfig(rate_law="segment", smoothing=1e-6))
    vref = m.taylor[3]  # the training tools' median feed rate
    assert m.speed_b == 2.0 and m.rate_ref == pytest.approx(1.5 * (vref / 2260.0) ** 2, rel=0.05)
    assert m.prior_rate(2730.0)[0] == pytest.approx(m.rate_ref * (2730.0 / vref) ** 2)
    test = _scheduled(9, 2.0)
    est, _, rate = m.run(test)
    assert np.all(np.diff(est) >= -1e-9)
    ratio = rate[1:] / np.where(rate[:-1] > 0, rate[:-1], np.nan)
    jump = np.flatnonzero(np.diff(test.feed) != 0)[0] + 1  # the first change of block
    assert ratio[jump - 1] == pytest.approx((test.feed[jump] / test.feed[jump - 1]) ** 2, rel=0.05)
    # the other rules do not scale
    assert np.all(fit(tools, HybridConfig()).scale(test.feed) == 1.0)


def test_revision_5_records_when_b_falls_back_to_zero() -> None:
    """Straight-line tools give one knot interval each, fewer than the tools + 2: no
    slope to fit, b falls back to 0 and the model says so; scheduled tools fit b."""
    straight = [tool(s) for s in range(4)]
    assert segment_fit(straight, 2260.0) == (0.0, True)
    m = fit(straight, HybridConfig(rate_law="segment"))
    assert m.speed_b == 0.0 and m.speed_b_fallback
    sched = [_scheduled(s, 2.0) for s in range(5)]
    assert segment_fit(sched, 2260.0) == (2.0, False)
    assert not fit(sched, HybridConfig(rate_law="segment")).speed_b_fallback
