"""The wear clock's bridge from the machine's wear model to the estimators (issue 7).

``harness.wear_clock``: the accelerated wear clock, and ``wear_law_params``, the
off-line constants of the reduced wear law read from the machine's model, with the
tool-life monitor that uses them (seed 004 (3)-(8)).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimators.errors import ParameterError as EstParameterError
from estimators.wear.law import WearLawParams
from estimators.wear.monitor import ToolLifeMonitor, ToolLifeParams
from harness.wear_clock import AcceleratedToolWear, wear_law_params
from machine.errors import ParameterError as MachParameterError
from machine.tool_wear import DEFAULT_WEAR_PARAMS, ToolWearModel


def test_accelerated_clock_advances_wear_by_rate() -> None:
    w = AcceleratedToolWear(feed=0.1, wear_minutes_per_second=2.0)
    t_end, F, x = w.cut_pass(0.5)
    assert t_end == pytest.approx(1.0)
    m = ToolWearModel()
    ref = m.simulate(np.full(20, 0.1), 1.0 / 20)
    np.testing.assert_allclose(x, ref.states[-1], rtol=1e-12)
    assert F == pytest.approx(float(np.mean(ref.force)))
    rec = w.observe_pass(F)
    assert rec.t[0] == pytest.approx(1.0)
    with pytest.raises(EstParameterError, match="wear_minutes_per_second"):
        AcceleratedToolWear(wear_minutes_per_second=0.0)
    with pytest.raises(MachParameterError, match="feed"):
        AcceleratedToolWear(feed=-0.1)
    assert math.isfinite(F)


# ---------------------------------------------------------------- wear-law life prediction


def _passes(model: ToolWearModel, feed: float, until_vb: float = 0.3, dt: float = 0.2):
    """True pass-mean forces and end-of-pass flank wear of a tool cut until ``until_vb``."""
    x = np.zeros(3)
    t, F, vb = [], [], []
    while not vb or vb[-1] < until_vb:
        tr = model.simulate(np.full(10, feed), dt / 10, x0=x)
        x = tr.states[-1]
        t.append(dt * (len(t) + 1))
        F.append(float(np.mean(tr.force)))
        vb.append(float(x[0] + x[1]))
    return np.array(t), np.array(F), np.array(vb)


def _monitor(law: WearLawParams | None) -> ToolLifeMonitor:
    m = ToolWearModel()
    return ToolLifeMonitor(
        ToolLifeParams(
            force_per_flank_wear=m.params.K13 * m.condition.depth, crater_force_rate=1.2, law=law
        )
    )


def test_wear_law_absorbs_other_scale_factors_and_predicts_the_life() -> None:
    # a tool whose abrasive and diffusive wear coefficients differ from the off-line
    # ones: the two fitted scale factors absorb them
    true = ToolWearModel(
        params=replace(
            DEFAULT_WEAR_PARAMS, K1=0.8 * DEFAULT_WEAR_PARAMS.K1, K2=2.0 * DEFAULT_WEAR_PARAMS.K2
        )
    )
    t, F, vb = _passes(true, 0.1)
    life = float(np.interp(0.3, vb, t))
    mon = _monitor(wear_law_params(ToolWearModel(), 0.1))
    _, rec = mon.step(mon.initial_state(), t, F, np.full(len(t), 0.1))
    for frac in (0.25, 0.5, 0.75):
        j = int(np.searchsorted(t, frac * life))
        assert rec.remaining_life[j] == pytest.approx(life - t[j], abs=0.02 * life)
        assert 0.0 < rec.remaining_life_sd[j] < 0.5 * (life - t[j])
        # the fitted flank wear follows the true one (crater law compensated)
        assert rec.vb_trend[j] == pytest.approx(vb[j], abs=0.005)
    # the straight line of the earlier monitor was late by more than the law's error
    line = _monitor(None)
    _, rl = line.step(line.initial_state(), t, F, np.full(len(t), 0.1))
    j = int(np.searchsorted(t, 0.5 * life))
    assert abs(rl.remaining_life[j] - (life - t[j])) > 5 * abs(
        rec.remaining_life[j] - (life - t[j])
    )


@settings(max_examples=6, deadline=None)
@given(
    k1=st.floats(min_value=0.7, max_value=1.3),
    k2=st.floats(min_value=0.5, max_value=2.5),
)
def test_wear_law_remaining_life_for_any_abrasive_and_diffusive_scale(k1: float, k2: float) -> None:
    # property: whatever the tool's K1, K2 (the law's two fitted scale factors), the
    # remaining life at mid-life is within the predicted 3 sigma and within 3 % of life
    p0 = DEFAULT_WEAR_PARAMS
    true = ToolWearModel(params=replace(p0, K1=k1 * p0.K1, K2=k2 * p0.K2))
    t, F, vb = _passes(true, 0.1)
    life = float(np.interp(0.3, vb, t))
    mon = _monitor(wear_law_params(ToolWearModel(), 0.1))
    _, rec = mon.step(mon.initial_state(), t, F, np.full(len(t), 0.1))
    j = int(np.searchsorted(t, 0.5 * life))
    err = rec.remaining_life[j] - (life - t[j])
    assert abs(err) <= 3.0 * rec.remaining_life_sd[j]
    assert abs(err) <= 0.03 * life


def test_wear_law_sd_contains_the_model_form_part() -> None:
    t, F, _ = _passes(ToolWearModel(), 0.1, until_vb=0.22)
    law = wear_law_params(ToolWearModel(), 0.1)
    sds = []
    for kw in ({"activation_rel_sd": 0.0, "crater_rel_sd": 0.0}, {}, {"crater_rel_sd": 0.9}):
        mon = _monitor(replace(law, **kw))
        _, rec = mon.step(mon.initial_state(), t, F, np.full(len(t), 0.1))
        sds.append(float(rec.remaining_life_sd[-1]))
    assert sds[0] < sds[1] < sds[2]
    assert all(math.isfinite(v) for v in sds)


def test_monitor_with_law_uses_the_line_at_another_feed() -> None:
    t, F, _ = _passes(ToolWearModel(), 0.125, until_vb=0.2)
    f = np.full(len(t), 0.125)
    law = wear_law_params(ToolWearModel(), 0.1)  # constants of another feed
    with_law, without = _monitor(law), _monitor(None)
    _, r1 = with_law.step(with_law.initial_state(), t, F, f)
    _, r2 = without.step(without.initial_state(), t, F, f)
    np.testing.assert_allclose(r1.remaining_life, r2.remaining_life, rtol=1e-12)


def test_wear_law_params_reject_bad_input() -> None:
    law = wear_law_params(ToolWearModel(), 0.1)
    with pytest.raises(EstParameterError, match=r"activation_rel_sd.*\[0, 0.5\).*0\.6"):
        replace(law, activation_rel_sd=0.6)
    with pytest.raises(EstParameterError, match=r"tau_abrasive.*> 0"):
        replace(law, tau_abrasive=0.0)
    with pytest.raises(EstParameterError, match=r"crater_gain.*>= 0.*-1"):
        replace(law, crater_gain=-1.0)
    with pytest.raises(EstParameterError, match=r"n3.*reduced wear law"):
        wear_law_params(ToolWearModel(params=replace(DEFAULT_WEAR_PARAMS, n3=1.5)), 0.1)


def test_life_sd_off_skips_only_the_spread() -> None:
    # life_sd=False (the live pipeline's setting): remaining_life_sd is NaN, every other
    # output equal to the full monitor's, with the law and with the trend alike
    t, F, _ = _passes(ToolWearModel(), 0.1)
    feed = np.full(len(t), 0.1)
    for law in (wear_law_params(ToolWearModel(), 0.1), None):
        full = _monitor(law)
        lean = ToolLifeMonitor(replace(full.params, life_sd=False))
        _, a = full.step(full.initial_state(), t, F, feed)
        _, b = lean.step(lean.initial_state(), t, F, feed)
        for name in ("vb", "vb_trend", "wear_rate", "remaining_life", "life_fraction"):
            assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
        assert np.array_equal(a.warning, b.warning) and np.array_equal(a.alarm, b.alarm)
        assert np.isfinite(a.remaining_life_sd).any()
        assert np.isnan(b.remaining_life_sd).all()
