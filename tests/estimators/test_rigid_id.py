"""The live rigid identifier on a simulated rigid axis (machine/rigid_axis.py): exact on
clean data, designed from the rate, forgetting, the process force, identifiability."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from estimators.errors import ParameterError
from estimators.rigid_id import (
    LiveEffect,
    RigidIdentifier,
    RigidIdParams,
    RigidIdRecord,
    RigidIdState,
    rigid_design,
)
from machine.rigid_axis import RigidAxisParams, simulate_rigid_axis

CLEAN = RigidAxisParams(ripple=0.0, position_friction=0.0, noise_rms=0.0)


def run(
    params: RigidIdParams,
    rec: dict[str, np.ndarray],
    block: int = 50,
    learn: np.ndarray | None = None,
    given: bool = False,
) -> tuple[RigidIdState, list[RigidIdRecord]]:
    ident = RigidIdentifier(params)
    st = ident.initial_state()
    out = []
    n = len(rec["t"])
    for a in range(0, n, block):
        b = min(n, a + block)
        kw = {"qd": rec["qd"][a:b], "qdd": rec["qdd"][a:b]} if given else {}
        lm = None if learn is None else learn[a:b]
        st, r = ident.step(st, rec["t"][a:b], rec["q_m"][a:b], rec["tau_m"][a:b], learn=lm, **kw)
        out.append(r)
    return st, out


def test_clean_data_gives_the_parameters() -> None:
    rec = simulate_rigid_axis(CLEAN, 30.0, np.random.default_rng(3))
    params, reasons = rigid_design(CLEAN.sample_time)
    assert reasons == {}
    _, recs = run(params, rec)
    th = recs[-1].theta
    np.testing.assert_allclose(th, [95.0, 200.0, 20.0, -3.0], rtol=2e-3, atol=5e-3)
    assert recs[-1].excited.all() and recs[-1].reversals >= 4


@pytest.mark.parametrize(
    ("rate", "filter_hz", "decimation"),
    [(10_000, 100.0, 100), (2_500, 100.0, 25), (1_000, 100.0, 10), (500, 50.0, 5), (100, 10.0, 1)],
)
def test_the_design_follows_the_rate(rate: float, filter_hz: float, decimation: int) -> None:
    p, reasons = rigid_design(1.0 / rate)
    assert (p.filter_hz, p.decimation, p.acceleration, reasons) == (
        pytest.approx(filter_hz),
        decimation,
        "differenced",
        {},
    )


def test_below_100_hz_the_mass_needs_the_cncs_acceleration() -> None:
    p, reasons = rigid_design(0.1)
    assert math.isnan(p.filter_hz) and p.acceleration == "none" and p.names()[0] == "Fv"
    assert "M" in reasons and "acceleration" in reasons["M"]
    p2, reasons2 = rigid_design(0.1, velocity_given=True, acceleration_given=True)
    assert p2.names()[0] == "M" and reasons2 == {} and p2.velocity == "given"
    effects = [
        LiveEffect.of("position_harmonics", {"period": 2.5e-3, "harmonics": 2.0}),
        LiveEffect.of("stribeck", {"v_s": 0.005}),
        LiveEffect.of("delay", {"delay_s": 1e-3}),
    ]
    p3, reasons3 = rigid_design(0.1, velocity_given=True, effects=effects)
    assert [e.name for e in p3.effects] == ["stribeck"]
    assert set(reasons3) == {"M", "position_harmonics", "delay"}


def test_at_10_hz_friction_from_the_cncs_velocity_and_acceleration() -> None:
    rec = simulate_rigid_axis(dataclasses.replace(CLEAN, noise_rms=0.5), 120.0,
                              np.random.default_rng(5))  # fmt: skip
    sub = {k: v[::100] for k, v in rec.items()}  # a CNC's 10 Hz export: a point sample
    p, _ = rigid_design(0.1, velocity_given=True, acceleration_given=True)
    _, recs = run(p, sub, block=5, given=True)
    th = recs[-1].theta
    assert abs(th[1] / 200.0 - 1) < 0.05 and abs(th[2] / 20.0 - 1) < 0.05, th
    assert abs(th[0] / 95.0 - 1) < 0.1, th


def test_forgetting_follows_a_change_of_mass() -> None:
    """The table is loaded at 40 s (+30 % mass): within three memories of motion the
    estimate has moved to the new mass; a growing window would still be between."""
    rng = np.random.default_rng(7)
    a = simulate_rigid_axis(CLEAN, 40.0, rng)
    b = simulate_rigid_axis(dataclasses.replace(CLEAN, M=123.5), 45.0, rng)
    rec = {k: np.concatenate([a[k], b[k] + (a[k][-1] - b[k][0] if k == "q_m" else 0)])
           for k in ("q_m", "tau_m", "qd", "qdd")}  # fmt: skip
    rec["t"] = np.arange(len(rec["q_m"])) * CLEAN.sample_time
    p, _ = rigid_design(CLEAN.sample_time)
    _, recs = run(p, rec)
    assert abs(recs[-1].theta[0] / 123.5 - 1) < 0.02, recs[-1].theta
    p_long = dataclasses.replace(p, memory_s=1e6, keep_memories=1e-3)
    _, recs_long = run(p_long, rec)
    assert recs_long[-1].theta[0] < 115.0  # the growing window averages the two masses


def test_the_process_force_is_what_the_model_does_not_explain() -> None:
    """A process force of 40 N during 8-12 s (not learnt from: ``learn`` is False there)
    comes out as the process force; elsewhere the force is near zero."""
    rec = simulate_rigid_axis(dataclasses.replace(CLEAN, noise_rms=0.3), 30.0,
                              np.random.default_rng(11))  # fmt: skip
    t = rec["t"]
    cut = (t >= 8.0) & (t < 12.0)
    rec["tau_m"] = rec["tau_m"] + 40.0 * cut
    p, _ = rigid_design(CLEAN.sample_time)
    _, recs = run(p, rec, learn=~cut)
    tt = np.concatenate([r.t for r in recs])
    f = np.concatenate([r.force for r in recs])
    sd = np.concatenate([r.force_sd for r in recs])
    inside = (tt > 8.2) & (tt < 11.9)
    outside = (tt > 14.0) & np.isfinite(f)
    assert abs(np.median(f[inside]) - 40.0) < 1.0
    assert np.sqrt(np.mean(f[outside] ** 2)) < 2.0
    assert 0 < np.median(sd[outside]) < 2.0


def test_a_column_the_others_span_is_left_out() -> None:
    """coulomb_asymmetry's dir_pos is 1[v > 0] = (sign + 1)/2 on moving rows: spanned by
    Fc and the offset; its coefficient is NaN, abs_v (Fv by direction) is identified."""
    p = dataclasses.replace(
        rigid_design(CLEAN.sample_time)[0],
        effects=(LiveEffect.of("coulomb_asymmetry", {}),),
    )
    rec = simulate_rigid_axis(CLEAN, 30.0, np.random.default_rng(2))
    _, recs = run(p, rec)
    names = p.names()
    th = recs[-1].theta
    assert names[4:] == ("coulomb_asymmetry.dir_pos", "coulomb_asymmetry.abs_v")
    assert math.isnan(th[4]) and abs(th[5]) < 1.0
    np.testing.assert_allclose(th[:4], [95.0, 200.0, 20.0, -3.0], rtol=5e-3, atol=0.05)
    d = recs[-1].directions
    assert d["Fc_pos"][0] == pytest.approx(17.0, abs=0.1)
    assert d["Fc_neg"][0] == pytest.approx(23.0, abs=0.1)
    assert recs[-1].direction_differs  # an offset of -3 N: the levels differ by 6 N
    sym = simulate_rigid_axis(dataclasses.replace(CLEAN, offset=0.0, noise_rms=0.5), 30.0,
                              np.random.default_rng(2))  # fmt: skip
    _, recs0 = run(rigid_design(CLEAN.sample_time)[0], sym)
    assert not recs0[-1].direction_differs


def test_blocks_of_any_size_give_the_same_estimate() -> None:
    rec = simulate_rigid_axis(RigidAxisParams(), 20.0, np.random.default_rng(4))
    p, _ = rigid_design(1e-3)
    _, a = run(p, rec, block=50)
    _, b = run(p, rec, block=37)
    np.testing.assert_allclose(a[-1].theta, b[-1].theta, rtol=1e-6)
    fa = np.concatenate([r.force for r in a])
    fb = np.concatenate([r.force for r in b])
    assert fa.shape == fb.shape


def test_bad_parameters_are_named() -> None:
    with pytest.raises(ParameterError, match="filter_hz"):
        RigidIdParams(sample_time=1e-3, filter_hz=600.0)
    with pytest.raises(ParameterError, match="acceleration"):
        RigidIdParams(sample_time=1e-3, acceleration="guessed")
    with pytest.raises(ParameterError, match="effects"):
        RigidIdParams(sample_time=1e-3, effects=(LiveEffect.of("delay", {"delay_s": 1e-3}),))
    p, _ = rigid_design(0.1, velocity_given=True, acceleration_given=True)
    ident = RigidIdentifier(p)
    with pytest.raises(ParameterError, match="qd"):
        ident.step(ident.initial_state(), np.zeros(3), np.zeros(3), np.zeros(3))


def test_a_rate_change_keeps_what_was_identified() -> None:
    """1 kHz for 20 s, then the feed drops to 500 Hz: the 500 Hz identifier adopts the
    state (parameters, information, rows), restarts its filters and goes on; at 10 Hz
    without an acceleration the mass column is dropped, the friction kept."""
    rec = simulate_rigid_axis(dataclasses.replace(CLEAN, noise_rms=0.5), 40.0,
                              np.random.default_rng(9))  # fmt: skip
    p1, _ = rigid_design(1e-3)
    a, _ = run(p1, {k: v[:20_000] for k, v in rec.items()})
    p2, _ = rigid_design(2e-3)
    i2 = RigidIdentifier(p2)
    st = i2.adopt(a, p1.names())
    np.testing.assert_array_equal(st.theta, a.theta)
    assert st.prev[-1] == 0.0  # the filters start again
    half = {k: v[20_000::2] for k, v in rec.items()}
    for k in range(0, len(half["t"]), 25):
        st, r = i2.step(st, half["t"][k : k + 25], half["q_m"][k : k + 25],
                        half["tau_m"][k : k + 25])  # fmt: skip
        assert np.all(np.isfinite(r.theta[:4]))
    np.testing.assert_allclose(r.theta[:4], [95.0, 200.0, 20.0, -3.0], rtol=0.02, atol=0.1)
    p3, _ = rigid_design(0.1)
    st3 = RigidIdentifier(p3).adopt(st, p2.names())
    assert p3.names() == ("Fv", "Fc", "offset")
    np.testing.assert_allclose(st3.theta, st.theta[1:4])
