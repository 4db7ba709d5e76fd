"""Extremum seeking cancellation of the eccentricity (``estimators/esc.py``, seed003
(8)-(16)) on its own: the 1x harmonic, the perturbation and demodulation, the gradient it
estimates, convergence on a static cost map, the clamp, freezing and resuming.

The plant here is the static map the ESC assumes (seed003 (6)-(8)): the spindle-frequency
force is proportional to the phasor left between the eccentricity ``E`` and the
modulation ``M = a_m e^{j theta_m}``, ``F_1 = g (E - M)``, on top of a mean force, a
tooth-passing harmonic and noise. No drives and no chip memory: those are the harness's
(``harness/eccentricity_loop.py``) and the reproduction's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from estimators.errors import ParameterError
from estimators.esc import (
    EscParams,
    EscRecord,
    EscState,
    ExtremumSeekingController,
    harmonic_cost,
    positive_polar,
    spindle_harmonic,
)

RPM = 1800.0
REV_S = 60.0 / RPM
GAIN = 4.0  # N of 1x force per um of phasor left (E - M)


def _rev_force(
    rng: np.random.Generator, e: complex, m: complex, psi0: float, n: int, noise: float
) -> tuple[np.ndarray, np.ndarray]:
    """One revolution of force [N] and spindle angle [rad] from the static map."""
    psi = psi0 + 2.0 * math.pi * np.arange(n) / n
    d = e - m
    f = (
        300.0
        + GAIN * abs(d) * np.cos(psi + np.angle(d))
        + 50.0 * np.cos(4.0 * psi)  # 4 flutes: the tooth-passing harmonic
        + noise * rng.standard_normal(n)
    )
    return f, psi


def _phasor(a_um: float, theta_deg: float) -> complex:
    return a_um * complex(math.cos(math.radians(theta_deg)), math.sin(math.radians(theta_deg)))


@dataclass
class Run:
    e: complex
    state: EscState
    records: list[EscRecord]

    def left_um(self) -> float:
        """|E - M_nominal| after the last revolution [um]."""
        r = self.records[-1]
        return abs(self.e - _phasor(r.a_n_um, r.theta_n_deg))


def _run(
    esc: ExtremumSeekingController,
    state: EscState,
    e: complex,
    revs: int,
    rng: np.random.Generator,
    *,
    n: int = 167,
    noise: float = 0.5,
) -> Run:
    """``revs`` revolutions of the static map (167 samples: 1800 rpm at 5 kHz, L = 166.7
    rounded), the ESC's modulation applied each revolution."""
    psi0 = float(rng.uniform(0.0, 2.0 * math.pi))
    recs = []
    for _ in range(revs):
        f, psi = _rev_force(rng, e, _phasor(state.a_um, state.theta_deg), psi0, n, noise)
        state, rec = esc.step(state, f, psi, REV_S)
        recs.append(rec)
        psi0 += 2.0 * math.pi
    return Run(e, state, recs)


# ------------------------------------------------------------------ the 1x harmonic


@pytest.mark.parametrize("n", [64, 166, 167, 200])
@pytest.mark.parametrize("phase", [0.0, 1.0, -2.5])
def test_the_harmonic_is_the_1x_phasor_with_the_mean_and_tooth_harmonic_removed(
    n: int, phase: float
) -> None:
    # seed003 (8): F = c + A cos(psi + phi) + B cos(4 psi) -> F_1 = A e^{j phi}; for L not
    # an integer (n samples over slightly less than a turn) the weighting keeps it so
    step = 2.0 * math.pi / (n - 0.3) if n in (166, 167) else 2.0 * math.pi / n
    psi = 0.7 + step * np.arange(n)
    f = 500.0 + 12.0 * np.cos(psi + phase) + 80.0 * np.cos(4.0 * psi)
    h = spindle_harmonic(f, psi)
    want = 12.0 * complex(math.cos(phase), math.sin(phase))
    tol = 1e-9 if step == 2.0 * math.pi / n else 0.05  # the rectangle rule, not exact
    assert abs(h - want) < tol * 12.0, (h, want)
    assert harmonic_cost(f, psi) == pytest.approx(abs(h))


def test_the_harmonic_refuses_mismatched_or_short_arrays() -> None:
    with pytest.raises(ParameterError, match="force/angle"):
        spindle_harmonic(np.zeros(10), np.zeros(9))
    with pytest.raises(ParameterError, match="force/angle"):
        spindle_harmonic(np.zeros(3), np.zeros(3))


# ------------------------------------------------------------------ parameters


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"psi_theta": 1.0}, "psi_theta"),  # perturbations that do not decouple, (14)
        ({"period_revs": 2}, "period_revs"),
        ({"amp_a_um": 70.0}, "amp_a_um"),  # above a_max_um
        ({"hpf_cycles_per_rev": 0.3}, "hpf_cycles_per_rev"),  # above 1 / period_revs
        ({"amp_theta_deg": 0.0}, "amp_theta_deg"),
        ({"resume_ratio": 1.0}, "resume_ratio"),
        ({"demod_phase": math.nan}, "demod_phase"),
    ],
)
def test_bad_parameters_name_their_field(kw: dict[str, float], field: str) -> None:
    with pytest.raises(ParameterError) as err:
        EscParams(**kw)
    assert err.value.name == field


def test_an_initial_radius_beyond_the_clamp_is_refused() -> None:
    esc = ExtremumSeekingController()
    with pytest.raises(ParameterError) as err:
        esc.initial_state(a_um=61.0)
    assert err.value.name == "a_um"


# ------------------------------------------------------------------ perturbation, filter


def test_the_perturbations_are_a_quarter_period_apart_and_demodulate_themselves() -> None:
    # seed003 (10)/(16): A sin(w_p k + Psi), w_p = 2 pi / 4 per revolution, Psi_theta =
    # Psi_a + pi/2; seed003 (13) with demod_phase = 0: the perturbation itself
    esc = ExtremumSeekingController()
    p = esc.params
    ks = range(4 * p.period_revs)
    pa = np.array([esc.perturbation(k)[0] for k in ks])
    pt = np.array([esc.perturbation(k)[1] for k in ks])
    np.testing.assert_allclose(np.roll(pt, 1) / p.amp_theta_deg, pa / p.amp_a_um, atol=1e-12)
    assert float(pa @ pt) == pytest.approx(0.0, abs=1e-9)  # D_{2,3} of (14) vanishes
    for k in ks:
        assert esc.demodulation(k) == esc.perturbation(k)
    lagged = ExtremumSeekingController(EscParams(demod_phase=0.3, demod_phase_theta=0.7))
    assert lagged.demodulation(5) == (
        lagged.perturbation(5, lag=0.3)[0],
        lagged.perturbation(5, lag=0.7)[1],
    )


def test_the_once_per_revolution_high_pass_is_the_filter_module_s() -> None:
    # seed003 (12): the Python one-sample step does what estimators.filters' kernel does
    esc = ExtremumSeekingController()
    filt = esc.params.hpf()
    x = np.random.default_rng(4).standard_normal(200) + 3.0
    want, _ = filt.run(x, filt.initial_state(float(x[0])))
    esc_state = esc.initial_state(cost_ref=1.0)
    got = []
    rng = np.random.default_rng(0)
    for xi in x:
        f = np.full(8, 0.0)
        esc_state, rec = esc.step(esc_state, f, rng.uniform(size=8), REV_S, cost=float(xi))
        got.append(rec.cost_hp)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


# ------------------------------------------------------------------ the gradient


def test_with_the_nominal_held_the_demodulated_gradient_is_the_cost_s_slope() -> None:
    # seed003 (13)-(15): xi ~ diag(A^2 / 2) grad j, j = J / J_0, up to the high-pass's
    # response at the perturbation frequency (seed003 (12)): a gain and a phase lead that
    # couple the two channels. K = 0 holds the nominal at (a, theta); the mean of xi over
    # whole perturbation periods is then, with H the high-pass at w_p and the phasors
    # d_a = A_a, d_theta = j A_theta of the two perturbations, 1/2 Re{H (dj . d) conj(d_i)}
    p = EscParams(k_a=0.0, k_theta=0.0, amp_a_um=0.5, amp_theta_deg=0.5)
    esc = ExtremumSeekingController(p)
    e = _phasor(20.0, 40.0)
    a, th = 8.0, 10.0
    j0 = GAIN * abs(e)
    state = esc.initial_state(a, th, cost_ref=j0)
    run = _run(esc, state, e, 400, np.random.default_rng(1), n=200, noise=0.0)
    late = run.records[-320:]  # past the high-pass's start
    ga = float(np.mean([r.grad_a for r in late]))
    gt = float(np.mean([r.grad_theta for r in late]))

    def j(a_: float, th_: float) -> float:
        return GAIN * abs(e - _phasor(a_, th_)) / j0

    h = 1e-4
    dja = (j(a + h, th) - j(a - h, th)) / (2 * h)
    djt = (j(a, th + h) - j(a, th - h)) / (2 * h)
    big_h = complex(p.hpf().response([1.0 / p.period_revs])[0])
    da, dt = complex(p.amp_a_um), 1j * p.amp_theta_deg  # Psi_theta = Psi_a + pi/2
    seen = big_h * (dja * da + djt * dt)
    assert ga == pytest.approx(0.5 * (seen * da.conjugate()).real, rel=0.01)
    assert gt == pytest.approx(0.5 * (seen * dt.conjugate()).real, rel=0.01)
    # the coupling is the high-pass's phase only: without it, A^2 / 2 times the slope
    assert abs(big_h) == pytest.approx(1.0, abs=0.02)
    assert all(r.a_n_um == a and r.theta_n_deg == th for r in run.records)


# ------------------------------------------------------------------ convergence


def test_from_within_45_degrees_the_modulation_converges_on_the_eccentricity() -> None:
    # 20 cases: eccentricity 8-30 um at any phase, the adaptation starting at a_m = 0 with
    # a phase within 45 degrees of it (a_m = 0 at 90 degrees off is a saddle of the polar
    # coordinates: no gradient on either), 0.5 N of noise, 40 s at 1800 rpm. Measured: 40
    # of 40 cases (seeds 0-39) end within 0.2 um; under 1 um is asked of every case here
    misses = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        e = _phasor(rng.uniform(8.0, 30.0), rng.uniform(0.0, 360.0))
        esc = ExtremumSeekingController()
        start = math.degrees(np.angle(e)) + rng.uniform(-45.0, 45.0)
        run = _run(esc, esc.initial_state(0.0, start), e, 1200, rng)
        if run.left_um() >= 1.0:
            misses.append((seed, run.left_um()))
        # the cost it sees falls to what the dither itself leaves (A_a, and A_theta at |E|)
        dither = esc.params.amp_a_um + abs(e) * math.radians(esc.params.amp_theta_deg)
        assert run.records[-1].cost < GAIN * (dither + 1.0) < 0.5 * run.records[0].cost
    assert not misses


def test_an_optimum_beyond_the_largest_radius_is_clamped_and_reported() -> None:
    esc = ExtremumSeekingController(EscParams(a_max_um=10.0))
    e = _phasor(20.0, 0.0)
    run = _run(esc, esc.initial_state(0.0, 0.0), e, 600, np.random.default_rng(2))
    last = run.records[-1]
    assert last.saturated
    assert abs(last.a_n_um) == pytest.approx(10.0 - esc.params.amp_a_um)
    assert all(abs(r.a_n_um) <= 10.0 - esc.params.amp_a_um + 1e-12 for r in run.records)


def test_the_dither_stops_when_still_and_restarts_when_the_cost_rises() -> None:
    esc = ExtremumSeekingController(EscParams(freeze_revs=40))
    rng = np.random.default_rng(3)
    e = _phasor(15.0, 20.0)
    run = _run(esc, esc.initial_state(0.0, 0.0), e, 1500, rng)
    last = run.records[-1]
    assert last.frozen
    # frozen: the nominal is applied as it is, no perturbation
    assert (last.a_um, last.theta_deg) == (last.a_n_um, last.theta_n_deg)
    assert run.left_um() < 1.0
    # a new tool: the eccentricity moves; the cost rises above resume_ratio x, the
    # dither restarts and the modulation follows
    e2 = _phasor(25.0, 50.0)
    run2 = _run(esc, run.state, e2, 1500, rng)
    resumed = [k for k, r in enumerate(run2.records) if not r.frozen]
    assert resumed and resumed[0] < 2 * esc.params.period_revs
    assert run2.left_um() < 1.0


def test_positive_polar_turns_a_negative_radius_half_a_turn() -> None:
    assert positive_polar(-3.0, 10.0) == (3.0, 190.0)
    assert positive_polar(3.0, -10.0) == (3.0, 350.0)
    a, th = positive_polar(-2.0, 300.0)
    assert _phasor(a, th) == pytest.approx(_phasor(-2.0, 300.0))
