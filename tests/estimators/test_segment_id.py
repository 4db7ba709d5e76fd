"""The gated segment identifier: exact on noise-free reversals, calibrated intervals on
noisy ones, known changes, and its parameter checks."""

from __future__ import annotations

import numpy as np
import pytest

from estimators.errors import ParameterError
from estimators.segment_id import (
    SegmentIdentifier,
    SegmentIdentifierParams,
    _effective_samples,
    mark_disturbance,
    restart,
)

TS = 4e-4
TRUE = np.array([5.0e-4, 2.0e-3, 0.15])
NOMINAL = (2.8e-4, 2e-3, 0.15)


def reciprocate(seconds: float, half_period: float = 2.0, speed: float = 30.0, ramp: float = 0.1):
    """Velocity plateaus of alternating sign joined by linear ramps (as machine.stage)."""
    t = np.arange(int(round(seconds / TS))) * TS
    m = np.round(t / half_period)
    d = t - m * half_period
    w = np.where(np.floor(t / half_period) % 2 == 0, speed, -speed)
    inramp = (m >= 1) & (np.abs(d) < ramp / 2)
    sign_before = np.where((m - 1) % 2 == 0, 1.0, -1.0)
    w = np.where(inramp, sign_before * speed * (-2 * d / ramp), w)
    acc = np.gradient(w, TS)
    return t, w, acc


def torque(t, w, acc, theta=TRUE, dc=None, noise=0.0, seed=0):
    """T_s of the load: J a + B w + F sgn w + a cutting DC (changing every plateau)."""
    if dc is None:
        dc = 4.0 + 0.3 * np.sin(0.7 * np.floor(t / 2.0 + 0.5))  # new DC every plateau
    rng = np.random.default_rng(seed)
    return (
        theta[0] * acc + theta[1] * w + theta[2] * np.sign(w) + dc + noise * rng.normal(size=len(t))
    )


def run(ident, state, t, ts, w, acc, block=125):
    recs = []
    for k in range(0, len(t), block):
        s = slice(k, k + block)
        state, r = ident.step(state, t[s], ts[s], acc[s], w[s], np.sign(w[s]))
        recs.append(r)
    return state, recs


def test_noise_free_reversals_identify_every_parameter_despite_a_changing_dc() -> None:
    t, w, acc = reciprocate(9.0)
    ident = SegmentIdentifier(SegmentIdentifierParams(nominal=NOMINAL, model_error=(0, 0, 0)))
    _, recs = run(ident, ident.initial_state(), t, torque(t, w, acc), w, acc)
    first = recs[0]
    # before the first reversal: the prior, flagged not excited
    assert not first.excited.any()
    np.testing.assert_allclose(first.theta[0], NOMINAL)
    last = recs[-1]
    assert last.segments == 4 and last.discarded == 0
    np.testing.assert_allclose(last.theta[-1], TRUE, rtol=2e-3)
    assert last.excited[-1].all()
    assert np.all(last.lower[-1] <= TRUE) and np.all(TRUE <= last.upper[-1])


def test_segment_interval_is_calibrated_on_low_passed_noise() -> None:
    # white torque noise, low-passed by Q_RLS inside: strongly autocorrelated residuals.
    # Without the effective-sample correction the interval would be ~5x too narrow.
    t, w, acc = reciprocate(3.0, half_period=1.5)
    ident = SegmentIdentifier(SegmentIdentifierParams(nominal=NOMINAL, model_error=(0, 0, 0)))
    hits = np.zeros(3)
    trials = 120
    for seed in range(trials):
        y = torque(t, w, acc, noise=0.2, seed=seed)
        st = ident.initial_state()
        for k in range(0, len(t), 125):
            s = slice(k, k + 125)
            st, _ = ident.step(st, t[s], y[s], acc[s], w[s], np.sign(w[s]))
        seg = st.hist
        m = (seg[:, 0] > 1.1) & (seg[:, 0] < 2.2)
        th, cov, reversal = ident.fit_segment(seg[m])
        assert reversal
        z = (th * np.array(NOMINAL) - TRUE) / (np.sqrt(np.diag(cov)) * np.array(NOMINAL))
        hits += np.abs(z) <= 1.96
    cover = hits / trials
    assert np.all(cover >= 0.88), cover
    assert np.all(cover <= 1.0)


def test_effective_samples_of_white_and_ar1_noise() -> None:
    rng = np.random.default_rng(1)
    e = rng.normal(size=20000)
    assert _effective_samples(e) == pytest.approx(20000, rel=0.1)
    rho = 0.9
    x = np.empty_like(e)
    x[0] = e[0]
    for k in range(1, len(e)):
        x[k] = rho * x[k - 1] + e[k]
    # AR(1): n (1 - rho) / (1 + rho)
    assert _effective_samples(x) == pytest.approx(20000 * 0.1 / 1.9, rel=0.25)


def test_known_change_inside_a_segment_discards_it() -> None:
    t, w, acc = reciprocate(3.5)
    dc = np.where(t >= 2.0, 5.0, 4.0)  # the DC steps at the reversal's centre
    y = torque(t, w, acc, dc=dc)
    p = SegmentIdentifierParams(nominal=NOMINAL, model_error=(0, 0, 0))
    ident = SegmentIdentifier(p)
    # unknown: the DC step reads as Coulomb friction (0.5 N m against 0.15)
    st, recs = run(ident, ident.initial_state(), t, y, w, acc)
    assert recs[-1].segments == 1
    assert abs(recs[-1].theta[-1, 2] / TRUE[2] - 1) > 0.5
    # known (a spindle step the CNC commanded): the segment is discarded, nothing claimed
    st = mark_disturbance(ident.initial_state(), 2.0)
    st, recs = run(ident, st, t, y, w, acc)
    assert recs[-1].discarded == 1 and recs[-1].segments == 0
    assert not recs[-1].excited.any()
    np.testing.assert_allclose(recs[-1].theta[-1], NOMINAL)


def test_restart_flags_not_excited_until_the_next_segment() -> None:
    t, w, acc = reciprocate(5.0)
    y = torque(t, w, acc)
    ident = SegmentIdentifier(SegmentIdentifierParams(nominal=NOMINAL))
    k = int(round(3.0 / TS))
    st, _ = run(ident, ident.initial_state(), t[:k], y[:k], w[:k], acc[:k])
    st = restart(st, (True, False, False))
    st, recs = run(ident, st, t[k:], y[k:], w[k:], acc[k:])
    assert not recs[0].excited[0, 0] and recs[0].excited[0, 1:].all()
    assert recs[0].theta[0, 0] == pytest.approx(NOMINAL[0])
    assert recs[-1].excited[-1, 0]  # the reversal at 4 s identified it again
    assert recs[-1].theta[-1, 0] == pytest.approx(TRUE[0], rel=0.02)


def test_interval_widens_with_the_time_since_the_last_segment() -> None:
    t, w, acc = reciprocate(3.9)
    ident = SegmentIdentifier(SegmentIdentifierParams(nominal=NOMINAL))
    _, recs = run(ident, ident.initial_state(), t, torque(t, w, acc), w, acc)
    width = [r.upper[-1] - r.lower[-1] for r in recs[-20:]]
    assert np.all(np.diff(np.array(width), axis=0) >= -1e-15)
    assert width[-1][1] > width[0][1]


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"nominal": (1.0, 2.0)}, "nominal"),
        ({"nominal": (0.0, 2.0, 1.0)}, "nominal"),
        ({"q_rls_hz": 2000.0}, "q_rls_hz"),
        ({"level": 1.5}, "level"),
        ({"walk": (1.0,)}, "walk"),
        ({"excited_rel": (0.1, 0.2)}, "excited_rel"),
        ({"model_error": (0.1, 0.2, 1.5)}, "model_error"),
        ({"decimation": -1}, "decimation"),  # 0: designed from the rate
        ({"pre": -1.0}, "pre"),
    ],
)
def test_bad_parameters_are_named(kw: dict[str, object], match: str) -> None:
    args: dict[str, object] = {"nominal": NOMINAL, **kw}
    with pytest.raises(ParameterError, match=match):
        SegmentIdentifierParams(**args)  # type: ignore[arg-type]


def test_block_of_unequal_lengths_is_rejected() -> None:
    ident = SegmentIdentifier(SegmentIdentifierParams(nominal=NOMINAL))
    with pytest.raises(ParameterError, match="equal length"):
        ident.step(
            ident.initial_state(), np.zeros(3), np.zeros(3), np.zeros(2), np.zeros(3), np.zeros(3)
        )
