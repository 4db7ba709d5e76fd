"""Seed 002's x-axis, IMBDO and harmonic DFO: closed-form checks, properties, errors."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from estimators import dfo
from estimators import imbdo as im
from estimators.errors import ParameterError as EParameterError
from machine import xy_axis as xa
from machine.errors import ParameterError as MParameterError


def _analytic_step(axis: xa.XYAxisParams, t: np.ndarray) -> np.ndarray:
    """Position after a unit voltage step at t = 0 through eq. (1), closed form."""
    p1, p2 = np.roots([1.0, axis.b, axis.c]).real
    tt = np.maximum(t - axis.delay, 0.0)
    z = axis.a * (
        1 / (p1 * p2) + np.exp(p1 * tt) / (p1 * (p1 - p2)) + np.exp(p2 * tt) / (p2 * (p2 - p1))
    )
    return np.where(t > axis.delay, z, 0.0)


def _run_open_loop(axis: xa.XYAxisParams, u: np.ndarray, d: np.ndarray) -> np.ndarray:
    stt = xa.initial_state(axis)
    z_all = np.empty(u.size)
    blk = axis.delay_samples
    for k0 in range(0, u.size, blk):
        k1 = min(k0 + blk, u.size)
        stt, z = xa.step(axis, stt, d[k0:k1])
        z_all[k0:k1] = z
        stt = xa.apply(axis, stt, u[k0:k1])
    return z_all


@pytest.mark.parametrize(("ts", "delay"), [(1e-4, 1.2e-3), (1e-4, 1.25e-3), (7e-4, 1.2e-3)])
def test_plant_delay_is_exact_including_the_fraction(ts: float, delay: float) -> None:
    axis = xa.XYAxisParams(delay=delay, sample_time=ts)
    n = round(0.5 / ts)
    z = _run_open_loop(axis, np.ones(n), np.zeros(n))
    t = np.arange(n) * ts
    ref = _analytic_step(axis, t)
    assert np.max(np.abs(z - ref)) < 1e-9 * np.max(np.abs(ref))
    # the fraction matters: a whole-sample delay would be visibly off
    if axis.delay_fraction > 0:
        rounded = xa.XYAxisParams(delay=axis.delay_samples * ts, sample_time=ts)
        z2 = _run_open_loop(rounded, np.ones(n), np.zeros(n))
        assert np.max(np.abs(z2 - ref)) > 1e-4 * np.max(np.abs(ref))


def test_plant_disturbance_bypasses_the_delay() -> None:
    axis = xa.XYAxisParams()
    n = 200
    z = _run_open_loop(axis, np.zeros(n), np.ones(n))
    assert z[0] == 0.0 and z[1] > 0.0  # moves one sample after the force, not after Td


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"a": 0.0}, "'a': expected a finite value > 0"),
        ({"b": -1.0}, "'b': expected a finite value > 0"),
        ({"c": math.nan}, "'c': expected a finite value > 0"),
        ({"delay": 0.0}, "'delay': expected a finite value > 0"),
        ({"delay": 5e-5}, r"'delay': expected a delay >= one sample"),
    ],
)
def test_plant_rejects_bad_parameters(kwargs: dict[str, float], match: str) -> None:
    with pytest.raises(MParameterError, match=match):
        xa.XYAxisParams(**kwargs)


def test_plant_block_protocol_errors() -> None:
    axis = xa.XYAxisParams()
    s0 = xa.initial_state(axis)
    with pytest.raises(MParameterError, match=r"'disturbance': expected a 1-D block of 1..12"):
        xa.step(axis, s0, np.zeros(13))
    s1, _ = xa.step(axis, s0, np.zeros(12))
    with pytest.raises(MParameterError, match="previous block's commands applied first"):
        xa.step(axis, s1, np.zeros(12))
    with pytest.raises(MParameterError, match="'commands': expected a 1-D block of 12"):
        xa.apply(axis, s1, np.zeros(3))
    with pytest.raises(MParameterError, match="'ref': expected a 1-D block shaped like z"):
        xa.cascade_step(xa.CascadeParams(), xa.CascadeState(), np.zeros(3), np.zeros(4))
    with pytest.raises(MParameterError, match="'kv': expected a finite value > 0"):
        xa.CascadeParams(kv=0.0)
    with pytest.raises(MParameterError, match="'amplitudes': expected 2 amplitudes"):
        xa.HarmonicForce((26.0, 52.0), (1.0,), (0.0, 0.0))


def _closed_loop_const_disturbance(with_imbdo: bool) -> np.ndarray:
    axis = xa.XYAxisParams()
    ctrl = xa.CascadeParams(ki=0.0)  # P/P: leaves a steady error under a constant force
    ip = im.ImbdoParams(axis.a, axis.b, axis.c, axis.sample_time, model_delay=axis.delay)
    stt, cs, ist = xa.initial_state(axis), xa.CascadeState(), im.Imbdo(ip).initial_state()
    n = 30000
    z_all = np.empty(n)
    blk = axis.delay_samples
    for k0 in range(0, n, blk):
        stt, z = xa.step(axis, stt, np.full(blk, 0.02))
        z_all[k0 : k0 + blk] = z
        cs, u = xa.cascade_step(ctrl, cs, z, np.zeros(blk))
        if with_imbdo:
            ist, rec = im.Imbdo(ip).step(ist, z, u)
            u = rec.v
        stt = xa.apply(axis, stt, u)
    return z_all


def test_imbdo_with_exact_model_rejects_a_constant_disturbance() -> None:
    without = _closed_loop_const_disturbance(False)
    with_i = _closed_loop_const_disturbance(True)
    assert abs(without[-1]) > 1e-3  # mm: the P/P loop alone keeps an offset
    assert abs(with_i[-1]) < 1e-6 * abs(without[-1])
    assert np.all(np.isfinite(with_i))


def test_imbdo_estimate_converges_to_the_disturbance_open_loop() -> None:
    axis = xa.XYAxisParams()
    ip = im.ImbdoParams(axis.a, axis.b, axis.c, axis.sample_time, model_delay=axis.delay)
    stt, ist = xa.initial_state(axis), im.Imbdo(ip).initial_state()
    blk = axis.delay_samples
    dh = np.empty(0)
    for _ in range(1000):
        stt, z = xa.step(axis, stt, np.full(blk, 0.005))
        ist, rec = im.Imbdo(ip).step(ist, z, np.zeros(blk))
        stt = xa.apply(axis, stt, rec.v)
        dh = rec.d_hat
    assert dh[-1] == pytest.approx(0.005, rel=1e-6)


def _delay_error_plant(f: np.ndarray) -> np.ndarray:
    return im.continuous_response([xa.PAPER_A], [1.0, xa.PAPER_B, xa.PAPER_C], f, 1.2e-3)


def _nominal(f: np.ndarray) -> np.ndarray:
    return im.continuous_response([xa.PAPER_A], [1.0, xa.PAPER_B, xa.PAPER_C], f)


def test_stability_check_against_closed_form() -> None:
    f = np.linspace(1.0, 800.0, 79901)
    # |1/Delta| of a pure delay error is 1 / (2 |sin(pi f Td)|)
    bound = im.inverse_delta(_delay_error_plant(f), _nominal(f))
    np.testing.assert_allclose(bound, 1 / (2 * np.abs(np.sin(np.pi * f * 1.2e-3))), rtol=1e-9)
    # a constant |Q| = 0.9 first meets it where |1/Delta| is smallest (f = 1/(2 Td))
    chk = im.check_q_filter(f, _delay_error_plant, _nominal, np.full(f.shape, 0.9 + 0j))
    assert chk.holds is False
    assert chk.f_closest == pytest.approx(1 / (2 * 1.2e-3), abs=0.02)
    assert chk.margin == pytest.approx(0.5 / 0.9, rel=1e-6)


def test_stability_check_passes_the_papers_q_and_flags_a_wide_one() -> None:
    ok = im.ImbdoParams(
        xa.PAPER_A,
        xa.PAPER_B,
        xa.PAPER_C,
        1e-4,
        cutoff_hz=90.0,
        model_delay=1.2e-3,
        delay_uncertainty=1.2e-3,
    )
    assert ok.stability.holds and ok.stability.margin > 1.2
    with pytest.raises(
        im.QFilterStabilityError,
        match=r"'cutoff_hz': expected a Q-filter below \|1/Delta\|.*150 Hz: "
        r"\|Q\| exceeds \|1/Delta\| by [0-9.]+ dB \(margin 0\.[0-9]+\) "
        r"at [0-9.]+ Hz",
    ):
        im.ImbdoParams(
            xa.PAPER_A, xa.PAPER_B, xa.PAPER_C, 1e-4, cutoff_hz=150.0, delay_uncertainty=1.2e-3
        )
    forced = im.ImbdoParams(
        xa.PAPER_A,
        xa.PAPER_B,
        xa.PAPER_C,
        1e-4,
        cutoff_hz=150.0,
        delay_uncertainty=1.2e-3,
        force=True,
    )
    assert not forced.stability.holds and forced.stability.margin < 1.0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"cutoff_hz": 6000.0}, r"'cutoff_hz': expected a frequency below Nyquist 5000 Hz"),
        ({"a": -1.0}, "'a': expected a finite value > 0"),
        ({"c": 0.0}, "'c': expected a finite value > 0"),
        ({"model_delay": -1e-3}, "'model_delay': expected a finite value >= 0"),
        ({"numerator_order": 2}, r"'numerator_order': expected <= order - 2"),
        ({"numerator_order": 3}, r"'numerator_order': expected an integer in \[0, 2\]"),
    ],
)
def test_imbdo_rejects_bad_parameters(kwargs: dict[str, float], match: str) -> None:
    base: dict[str, float] = {
        "a": xa.PAPER_A,
        "b": xa.PAPER_B,
        "c": xa.PAPER_C,
        "sample_time": 1e-4,
    }
    base.update(kwargs)
    with pytest.raises(EParameterError, match=match):
        im.ImbdoParams(**base)  # type: ignore[arg-type]


def _multisine(
    t: np.ndarray,
    freqs: tuple[float, ...],
    amps: tuple[float, ...],
    phases: tuple[float, ...],
    gain: np.ndarray | None = None,
) -> np.ndarray:
    y = np.zeros_like(t)
    for i, (f, a, p) in enumerate(zip(freqs, amps, phases, strict=True)):
        g = 1.0 + 0j if gain is None else gain[i]
        y += a * abs(g) * np.sin(2 * np.pi * f * t + p + np.angle(g))
    return y


FREQS = (100.0, 200.0, 300.0)
AMPS = (30.0, 12.0, 5.0)
PHASES = (0.4, -1.9, 2.8)


def _check_recovery(rec: dfo.DfoRecord) -> None:
    np.testing.assert_allclose(rec.amplitude[-1], AMPS, rtol=0.01)
    dph = np.angle(np.exp(1j * (rec.phase[-1] - np.asarray(PHASES))))
    assert np.all(np.abs(dph) < 0.01)


def test_dfo_recovers_a_multisine_directly() -> None:
    ts = 4e-4
    p = dfo.DfoParams(FREQS, ts)
    t = np.arange(2500) * ts
    _, rec = dfo.Dfo(p).step(dfo.Dfo(p).initial_state(), _multisine(t, FREQS, AMPS, PHASES))
    _check_recovery(rec)


def test_dfo_undoes_a_q_filter() -> None:
    ts = 4e-4
    wc = 2 * np.pi * 80.0
    num, den = (wc**2,), (1.0, 2 * wc, wc**2)  # Q(s) = wc^2 / (s + wc)^2
    p = dfo.DfoParams(FREQS, ts, channel_num=num, channel_den=den)
    q = im.continuous_response(num, den, np.asarray(FREQS))
    t = np.arange(5000) * ts
    y = _multisine(t, FREQS, AMPS, PHASES, q)  # the filter's steady-state output
    stt = dfo.Dfo(p).initial_state()
    for k0 in range(0, t.size, 100):  # block by block gives the same as one call
        stt, rec = dfo.Dfo(p).step(stt, y[k0 : k0 + 100])
    _check_recovery(rec)
    truth = _multisine(t[-100:], FREQS, AMPS, PHASES)
    assert np.max(np.abs(rec.d_hat - truth)) < 0.01 * max(AMPS)


def test_dfo_on_the_axis_with_a_delayed_input() -> None:
    axis = xa.XYAxisParams()
    p = dfo.DfoParams(
        (26.0, 52.0, 78.0),
        axis.sample_time,
        (axis.a,),
        (1.0, axis.b, axis.c),
        input_delay=axis.delay,
        uses_input=True,
    )
    rng = np.random.default_rng(5)
    n = 36000
    t = np.arange(n) * axis.sample_time
    force = xa.HarmonicForce((26.0, 52.0, 78.0), (0.005, 0.001, 0.001), (0.3, 1.0, -2.0))
    d = force(t + axis.sample_time / 2)
    u = np.repeat(rng.normal(0.0, 0.002, n // 12), 12)
    stt, dst = xa.initial_state(axis), dfo.Dfo(p).initial_state()
    blk = axis.delay_samples
    for k0 in range(0, n, blk):
        stt, z = xa.step(axis, stt, d[k0 : k0 + blk])
        dst, rec = dfo.Dfo(p).step(dst, z)
        stt = xa.apply(axis, stt, u[k0 : k0 + blk])
        dst = dfo.Dfo(p).apply(dst, u[k0 : k0 + blk])
    # held at each interval's midpoint, the force acts like the continuous one (no lag)
    np.testing.assert_allclose(rec.amplitude[-1], force.amplitudes, rtol=0.01)
    dph = np.angle(np.exp(1j * (rec.phase[-1] - np.asarray(force.phases))))
    assert np.all(np.abs(dph) < 0.01)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(1.0, 900.0), min_size=1, max_size=4, unique=True), st.floats(5.0, 60.0))
def test_dfo_error_poles_are_the_placed_ones(freqs: list[float], decay: float) -> None:
    fs = sorted(freqs)
    assume(all(b - a >= 2.0 for a, b in itertools.pairwise(fs)))
    ts = 5e-4
    p = dfo.DfoParams(
        tuple(fs), ts, channel_num=(1.0,), channel_den=(1e-3, 1.0), harmonic_decay=decay
    )
    w = 2 * np.pi * np.asarray(fs)
    want = np.exp(np.concatenate([[-2 * np.pi * 100.0], -decay + 1j * w, -decay - 1j * w]) * ts)
    got = p.error_poles()
    for z in want:
        assert np.min(np.abs(got - z)) < 1e-6
    assert np.all(np.abs(got) < 1.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (
            {"frequencies": (26.0, 1250.0)},
            r"'frequencies': expected frequencies in \(0, 1250\) "
            r"Hz \(Nyquist\), got 1250",
        ),
        ({"frequencies": (26.0, 3000.0)}, r"'frequencies'.*Nyquist.*got 3000"),
        ({"frequencies": (26.0, 52.0, 26.0)}, "'frequencies': expected distinct frequencies"),
        ({"frequencies": (-5.0,)}, r"'frequencies'.*got -5"),
        ({"frequencies": ()}, "'frequencies': expected at least one frequency"),
        ({"channel_num": (1.0, 0.0), "channel_den": (1.0, 5.0)}, "'channel_num': expected degree"),
        ({"uses_input": True}, "'uses_input': expected False for a static-gain channel"),
        ({"input_delay": -1.0}, "'input_delay': expected a finite value >= 0"),
        ({"harmonic_decay": 0.0}, "'harmonic_decay': expected a finite value > 0"),
    ],
)
def test_dfo_rejects_bad_parameters(kwargs: dict[str, object], match: str) -> None:
    base: dict[str, object] = {"frequencies": (26.0,), "sample_time": 4e-4}
    base.update(kwargs)
    with pytest.raises(EParameterError, match=match):
        dfo.DfoParams(**base)  # type: ignore[arg-type]


def test_dfo_block_protocol_errors() -> None:
    axis = xa.XYAxisParams()
    p = dfo.DfoParams(
        (26.0,),
        axis.sample_time,
        (axis.a,),
        (1.0, axis.b, axis.c),
        input_delay=axis.delay,
        uses_input=True,
    )
    s0 = dfo.Dfo(p).initial_state()
    with pytest.raises(EParameterError, match="'y': expected a block of at most 13 samples"):
        dfo.Dfo(p).step(s0, np.zeros(14))
    s1, _ = dfo.Dfo(p).step(s0, np.zeros(12))
    with pytest.raises(EParameterError, match="previous block's commands applied first"):
        dfo.Dfo(p).step(s1, np.zeros(12))
    with pytest.raises(EParameterError, match="'commands': expected a 1-D block of 12"):
        dfo.Dfo(p).apply(s1, np.zeros(5))
    q = dfo.DfoParams((26.0,), 4e-4)
    with pytest.raises(EParameterError, match="'commands': expected no commands"):
        dfo.Dfo(q).apply(dfo.Dfo(q).initial_state(), np.zeros(1))
    with pytest.raises(EParameterError, match="'y': expected a non-empty 1-D block"):
        dfo.Dfo(q).step(dfo.Dfo(q).initial_state(), np.zeros(0))


def test_dfo_retunes_to_new_frequencies_and_reconverges() -> None:
    ts = 4e-4
    p = dfo.DfoParams(FREQS, ts)
    t = np.arange(2500) * ts
    stt, _ = dfo.Dfo(p).step(dfo.Dfo(p).initial_state(), _multisine(t, FREQS, AMPS, PHASES))
    new = tuple(0.8 * f for f in FREQS)
    p2 = p.with_frequencies(new)
    t2 = np.arange(2500, 5000) * ts
    _, rec = dfo.Dfo(p2).step(stt, _multisine(t2, new, AMPS, PHASES))
    np.testing.assert_allclose(rec.amplitude[-1], AMPS, rtol=0.01)
