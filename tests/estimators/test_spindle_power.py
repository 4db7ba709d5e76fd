"""The spindle's cutting power over the idle power taught per speed
(estimators/monitoring/spindle_power.py), on synthetic data and on the simulated machining
centre's 500 Hz trace."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.errors import ParameterError
from estimators.monitoring.spindle_power import IdlePower, IdlePowerParams
from machine.centre.sim import MachiningCentre
from machine.centre.trace import CncTrace, TraceParams

TS = 0.002


def test_the_idle_power_is_the_air_level_under_long_cuts() -> None:
    # 8,000 rpm: 2 s in the air (800 W +- 7 W), then 8 s cutting (1,800 W), ten times
    rng = np.random.default_rng(0)
    ip = IdlePower(IdlePowerParams(sample_time=TS))
    s = ip.initial_state()
    air, cut = round(2 / TS), round(8 / TS)
    for _ in range(10):
        p = np.r_[np.full(air, 800.0), np.full(cut, 1800.0)] + 7.0 * rng.standard_normal(air + cut)
        s, rec = ip.step(s, np.full(air + cut, 8000.0), p)
    # the 0.5 % quantile of the air's power: 800 - 2.6 sigma
    assert rec.idle[-1] == pytest.approx(800.0 - 2.6 * 7.0, abs=6.0)
    assert np.nanmean(rec.cutting[-cut:]) == pytest.approx(1000.0 + 2.6 * 7.0, abs=6.0)


def test_a_falling_idle_is_followed_at_once_a_rising_one_slowly() -> None:
    ip = IdlePower(IdlePowerParams(sample_time=TS))
    s, _ = ip.step(ip.initial_state(), np.full(500, 8000.0), np.full(500, 1000.0))
    _, rec = ip.step(s, np.full(round(20 / TS), 8000.0), np.full(round(20 / TS), 900.0))
    assert rec.idle[-1] == pytest.approx(900.0, abs=10.0)  # down 10 % in 20 s
    _, rec = ip.step(s, np.full(round(20 / TS), 8000.0), np.full(round(20 / TS), 1100.0))
    assert 1000.0 < rec.idle[-1] < 1005.0  # up 10 %: 0.3 % of it in 20 s


def test_nothing_is_taught_while_the_speed_changes_or_the_spindle_stands() -> None:
    ip = IdlePower(IdlePowerParams(sample_time=TS))
    ramp = np.linspace(0.0, 8000.0, 500)  # 1 s run-up: 8,000 rpm/s
    s, rec = ip.step(ip.initial_state(), ramp, np.full(500, 5000.0))
    assert not rec.taught.any() and np.all(np.isnan(rec.cutting[ramp >= 300]))
    s, rec = ip.step(s, np.zeros(200), np.zeros(200))
    assert not rec.taught.any() and np.all(rec.idle == 0.0)
    # held steady: teaches after the hold time
    s, rec = ip.step(s, np.full(200, 3000.0), np.full(200, 250.0))
    assert not rec.taught[: round(0.1 / TS)].any() and rec.taught[-1]


def test_parameters_and_inputs_are_checked() -> None:
    with pytest.raises(ParameterError, match="quantile"):
        IdlePowerParams(sample_time=TS, quantile=0.7)
    with pytest.raises(ParameterError, match="max_rpm"):
        IdlePowerParams(sample_time=TS, max_rpm=400.0)
    ip = IdlePower(IdlePowerParams(sample_time=TS))
    with pytest.raises(ParameterError, match="power_w"):
        ip.step(ip.initial_state(), np.zeros(10), np.zeros(9))


def _watch(seed: int, parts: float) -> tuple:  # type: ignore[type-arg]
    """The default part run ``parts`` times, its 500 Hz trace through the teacher."""
    m = MachiningCentre(override_prob=0.0)
    st = m.initial_state(seed=seed)
    trace = CncTrace(TraceParams(500.0), m.sample_time)
    tst = trace.initial_state()
    ip = IdlePower(IdlePowerParams(sample_time=1 / 500))
    s = ip.initial_state()
    rows = []
    for _ in range(round(parts * 32)):
        st, rec = m.step(st, 10_000)
        tst, tr = trace.export(tst, rec)
        s, r = ip.step(s, tr.signal("S.speed"), tr.signal("S.power"))
        w = tr.signal("S.speed_true") * math.pi / 30
        rows.append((tr.line, tr.part, r.cutting, tr.signal("S.torque_cut") * w))
    cat = [np.concatenate(c) for c in zip(*rows, strict=True)]
    return m, st, ip, s, cat


@pytest.mark.slow  # two simulated parts per seed (~5 s each)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_cutting_power_of_each_cut_is_the_cut_s_own(seed: int) -> None:
    m, st, ip, s, (line, part, cut_hat, truth) = _watch(seed, 2.0)
    for p in (0, 1):
        for ln in (60, 140, 150, 250):
            on = (part == p) & (line == ln)
            # mean over the block: within 3 % (the 0.5 % quantile sits ~2.6 sigma low)
            assert np.nanmean(cut_hat[on]) == pytest.approx(truth[on].mean(), rel=0.03), (p, ln)
    # the friction model fitted to the taught bins: the spindle's own, warming up
    c1, c2 = ip.model(s)
    sp = m.params.spindle
    run = st.ss[7]  # seconds turned (kernel SS_RUN)
    assert c2 == pytest.approx(sp.viscous, rel=0.1)
    assert c1 == pytest.approx(sp.coulomb * (1 + sp.warmup_share * math.exp(-run / sp.warmup_time)),
                               rel=0.1)  # fmt: skip
    # a speed never run: from the model, within 5 % of the spindle's idle there
    w = 5000 * math.pi / 30
    want = c1 * w + sp.viscous * w * w
    assert float(ip.idle_at(s, [5000.0])[0]) == pytest.approx(want, rel=0.05)
