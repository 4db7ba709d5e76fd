"""The detectors' confirmations are physical quantities, the same at every rate (issue 32).

A synthetic cut (a steady force with a once-per-revolution pattern, a little noise) is
taught and then watched at 5 kHz and 500 Hz: a lost tool alarms the same time after it
is lost at both rates, a dip of the mean shorter than the missing-tool confirmation
raises nothing at either (the rule in samples took it for a lost tool at 500 Hz), and a
collision needs 0.4 ms and at least two samples over the limit; a breakage an eighth of a
revolution and at least three samples, in samples per revolution of the rate and speed.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimators.errors import ParameterError
from estimators.monitoring.process import MonitorParams, ProcessMonitor

RPM = 6000.0  # 10 ms a revolution: shorter than the 30 ms missing-tool confirmation
BLOCK_S = 1.0
F0 = 100.0  # N
#: the rule in samples of the rate, as before issue 32's change
BEFORE = {"breakage_rev": 0.0, "collision_s": 0.0, "missing_s": 0.0}


def _block(rate: float, seed: int, scale: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    n = int(BLOCK_S * rate)
    t = np.arange(n) / rate
    psi = np.mod(2 * math.pi * RPM / 60.0 * t, 2 * math.pi)
    rng = np.random.default_rng(seed)
    f = F0 * (1.0 + 0.2 * np.cos(psi)) + rng.normal(0.0, 1.0, n)
    if scale is not None:
        f = f * scale
    return f, np.zeros(n), psi


def _taught(rate: float, **kw: float) -> tuple[ProcessMonitor, dict[str, np.ndarray]]:
    mon = ProcessMonitor(MonitorParams(sample_time=1.0 / rate, teach_parts=3, **kw))
    st = mon.initial_state()
    for seed in range(3):
        rec = mon.step(st, *_block(rate, seed), tool=1, program="O1", line=10, new_block=True)
        assert rec.teaching and not rec.alarms
    return mon, st


def _watch(rate: float, scale: np.ndarray, detector: str, **kw: float) -> list[float]:
    """Alarm times [s] of ``detector`` in one watched execution with the force scaled
    (the force lost or a spike also moves the pattern: the breakage detector's own)."""
    mon, st = _taught(rate, **kw)
    k0 = int(st["samples"][0])
    rec = mon.step(st, *_block(rate, 9, scale), tool=1, program="O1", line=10, new_block=True)
    return [(a.sample - k0) / rate for a in rec.alarms if a.detector == detector]


def _scale(rate: float, t0: float, t1: float, value: float) -> np.ndarray:
    t = np.arange(int(BLOCK_S * rate)) / rate
    return np.where((t >= t0) & (t < t1), value, 1.0)


def test_a_lost_tool_alarms_the_same_time_after_at_5khz_and_500hz() -> None:
    got = {}
    for rate in (5000.0, 500.0):
        (t_al,) = _watch(rate, _scale(rate, 0.4, 2.0, 0.0), "missing_tool")
        got[rate] = t_al - 0.4
    # half a revolution for the mean to fall under the limit, then 30 ms under it
    for rate, d in got.items():
        assert 0.030 <= d <= 0.030 + 0.010 + 2.0 / rate, (rate, d)
    assert abs(got[5000.0] - got[500.0]) <= 0.005


@pytest.mark.parametrize("rate", [5000.0, 500.0])
def test_a_dip_shorter_than_the_confirmation_is_not_a_lost_tool(rate: float) -> None:
    # the force gone for 2 revolutions (20 ms) and back: under 30 ms, nothing at either
    # rate; the rule of one revolution took it for a lost tool
    dip = _scale(rate, 0.4, 0.42, 0.0)
    assert _watch(rate, dip, "missing_tool") == []
    assert len(_watch(rate, dip, "missing_tool", **BEFORE)) == 1


@pytest.mark.parametrize("rate", [5000.0, 1000.0, 500.0])
def test_a_collision_needs_two_samples_over_the_limit_at_every_rate(rate: float) -> None:
    one = np.ones(int(BLOCK_S * rate))
    one[int(0.5 * rate)] = 5.0  # a single sample at 5 times the force
    assert _watch(rate, one, "collision") == []
    two = one.copy()
    two[int(0.5 * rate) + 1] = 5.0
    # confirmed on the second sample over the limit (0.4 ms is 2 samples at 5 kHz)
    assert _watch(rate, two, "collision") == [pytest.approx(0.5 + 1.0 / rate)]


def test_the_confirmations_are_checked_and_named() -> None:
    for name in ("breakage_rev", "collision_s", "missing_s"):
        with pytest.raises(ParameterError, match=name):
            MonitorParams(**{name: -1.0})


def _pattern_step(rate: float, rpm: float, seed: int, t0: float | None) -> tuple[np.ndarray, ...]:
    """One block at ``rpm``: the once-per-revolution pattern 0.2 of the force, 0.8 from
    ``t0`` on (a tooth broken: the mean stays, the pattern moves by 0.6)."""
    n = int(BLOCK_S * rate)
    t = np.arange(n) / rate
    psi = np.mod(2 * math.pi * rpm / 60.0 * t, 2 * math.pi)
    amp = np.where(t >= t0, 0.8, 0.2) if t0 is not None else np.full(n, 0.2)
    f = F0 * (1.0 + amp * np.cos(psi)) + np.random.default_rng(seed).normal(0.0, 1.0, n)
    return f, np.zeros(n), psi


@pytest.mark.parametrize(
    ("rate", "rpm", "expected"),
    [
        (5000.0, 6000.0, 7),  # 50 samples a revolution: an eighth is 6.25 -> 7
        (5000.0, 1500.0, 25),  # 200 a revolution: 25
        (1000.0, 1500.0, 5),  # 40 a revolution: 5
        (500.0, 6000.0, 3),  # 5 a revolution: an eighth is under one sample, the floor 3
    ],
)
def test_a_breakage_is_confirmed_over_an_eighth_of_a_revolution_at_least_3_samples(
    rate: float, rpm: float, expected: int
) -> None:
    spr = rate * 60.0 / rpm  # samples per revolution, from the rate and the speed alone
    assert expected == max(3, math.ceil(spr / 8.0 - 1e-9))
    mon = ProcessMonitor(MonitorParams(sample_time=1.0 / rate, teach_parts=3))
    st = mon.initial_state()
    kw = {"tool": 1, "program": "O1", "line": 10, "new_block": True}
    for seed in range(3):
        assert mon.step(st, *_pattern_step(rate, rpm, seed, None), **kw).teaching  # type: ignore[arg-type]
    k0 = int(st["samples"][0])
    rec = mon.step(st, *_pattern_step(rate, rpm, 9, 0.5), **kw)  # type: ignore[arg-type]
    (al,) = [a for a in rec.alarms if a.detector == "breakage"]
    k = al.sample - k0
    over = rec.pattern > rec.pattern_limit  # NaN compares False
    assert not over[: int(0.5 * rate)].any()  # nothing before the tooth breaks
    # the alarm closes the first run of samples over the limit, ``expected`` long
    assert over[k - expected + 1 : k + 1].all(), (rate, rpm)
    assert not over[k - expected], (rate, rpm)
