"""ESC (seed 003 eq. 8-16), the fast tuner, the loop and the reproduction."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimators.errors import ParameterError
from estimators.esc import (
    EscParams,
    ExtremumSeekingController,
    harmonic_cost,
    positive_polar,
    spindle_harmonic,
)
from estimators.fast_tuner import FastTuner, FastTunerParams
from harness.eccentricity_loop import EccentricityLoop
from server.cli.main import main


@settings(max_examples=40, deadline=None)
@given(
    amp=st.floats(1e-3, 1e3),
    phase=st.floats(-math.pi, math.pi),
    samples=st.integers(8, 600),
    offset=st.floats(-1e3, 1e3),
    psi0=st.floats(0, 100),
)
def test_cost_of_a_pure_spindle_sinusoid_is_its_amplitude(
    amp: float, phase: float, samples: int, offset: float, psi0: float
) -> None:
    psi = psi0 + 2 * np.pi * np.arange(samples) / samples
    f = offset + amp * np.cos(psi + phase)
    assert harmonic_cost(f, psi) == pytest.approx(amp, rel=1e-9, abs=1e-9)
    assert np.angle(spindle_harmonic(f, psi) * np.exp(-1j * phase)) == pytest.approx(0.0, abs=1e-7)


def test_cost_ignores_the_tooth_harmonics() -> None:
    psi = 2 * np.pi * np.arange(250) / 250
    f = 50 + 30 * np.cos(4 * psi) + 10 * np.cos(8 * psi + 1) + 2 * np.sin(psi)
    assert harmonic_cost(f, psi) == pytest.approx(2.0, rel=1e-12)


@pytest.mark.parametrize("rpm", [1800.0, 1500.0, 1234.5])
def test_cost_over_a_non_integer_revolution(rpm: float) -> None:
    """166.7 samples per revolution (1800 rpm at 5 kHz): the big mean and tooth harmonic
    must not leak into the 1x bin, whichever 166 or 167 samples the revolution holds."""
    ts = 2e-4
    w = 2 * np.pi * rpm / 60
    t = np.arange(20000) * ts
    psi = w * t
    f = 80 + 40 * np.cos(4 * psi + 0.3) + 10 * np.cos(8 * psi) + 2.0 * np.cos(psi + 1.0)
    k = np.floor(psi / (2 * np.pi))
    for rev in range(3, 9):
        m = k == rev
        assert harmonic_cost(f[m], psi[m]) == pytest.approx(2.0, abs=0.02)


def test_esc_step_with_the_cost_given_equals_computing_it() -> None:
    psi = 2 * np.pi * np.arange(250) / 250
    esc = ExtremumSeekingController(EscParams())
    a = b = esc.initial_state(cost_ref=3.0)
    for k in range(12):
        f = 50 + (3.0 - 0.1 * k) * np.cos(psi + 0.2 * k)
        a, ra = esc.step(a, f, psi, 0.05)
        b, rb = esc.step(b, f, psi, 0.05, cost=harmonic_cost(f, psi))
        assert (ra.a_um, ra.theta_deg, ra.cost) == (rb.a_um, rb.theta_deg, rb.cost)
    assert a.a_um != 0.0  # it did move


def _synthetic_force(y: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """Forces (X, Y) whose 1x phasors are y = [re x, im x, re y, im y]."""
    return np.vstack(
        [
            np.real((y[0] + 1j * y[1]) * np.exp(1j * psi)),
            np.real((y[2] + 1j * y[3]) * np.exp(1j * psi)),
        ]
    )


def _run_esc_on_cone(
    esc: ExtremumSeekingController, u_star: complex, revs: int, kappa: float = 0.6
) -> tuple[float, float]:
    """ESC against a static cone J = kappa |u - u*| (um), once per 0.05 s revolution."""
    s = esc.initial_state()
    psi = 2 * np.pi * np.arange(250) / 250
    for _ in range(revs):
        u = s.a_um * np.exp(1j * math.radians(s.theta_deg))
        f = kappa * abs(u - u_star) * np.cos(psi)
        s, _rec = esc.step(s, f, psi, 0.05)
    return s.a_n_um, s.theta_n_deg


def test_esc_finds_the_minimum_of_a_cone() -> None:
    u_star = 15.0 * np.exp(1j * math.radians(235.0))
    esc = ExtremumSeekingController(EscParams(freeze_revs=40))
    a, th = _run_esc_on_cone(esc, u_star, 1200)
    u = a * np.exp(1j * math.radians(th))
    assert abs(u - u_star) < 0.02 * abs(u_star)


def test_esc_stops_its_dither_and_restarts_when_the_optimum_moves() -> None:
    esc = ExtremumSeekingController(EscParams(freeze_revs=40))
    psi = 2 * np.pi * np.arange(250) / 250
    # start near the optimum; the normaliser is the cost without modulation
    s = esc.initial_state(a_um=-14.0, theta_deg=50.0, cost_ref=0.6 * 15.0)
    u_star = 15.0 * np.exp(1j * math.radians(235.0))
    frozen_at = None
    for k in range(1500):
        if k == 700:
            assert s.frozen  # converged and the dither stopped
            frozen_at = (s.a_n_um, s.theta_n_deg)
            u_star = 15.0 * np.exp(1j * math.radians(245.0))  # e.g. a speed change
        u = s.a_um * np.exp(1j * math.radians(s.theta_deg))
        s, _rec = esc.step(s, 0.6 * abs(u - u_star) * np.cos(psi), psi, 0.05)
    assert frozen_at is not None
    u = s.a_n_um * np.exp(1j * math.radians(s.theta_n_deg))
    assert (s.a_n_um, s.theta_n_deg) != frozen_at
    assert abs(u - u_star) < 0.03 * abs(u_star)


def test_esc_demodulation_gives_the_gradient_sign() -> None:
    """Eq. (13)-(15): the demodulated cost has the sign of the gradient."""
    esc = ExtremumSeekingController(EscParams(k_a=0.0, k_theta=0.0))
    s = esc.initial_state(a_um=5.0, theta_deg=0.0)
    psi = 2 * np.pi * np.arange(100) / 100
    ga = []
    for _ in range(40):
        # J = a (cost grows with the radius): the gradient in a is positive
        f = max(s.a_um, 0.0) * np.cos(psi)
        s, rec = esc.step(s, f, psi, 0.05)
        ga.append(rec.grad_a)
    assert np.mean(ga[8:]) > 0
    assert s.a_n_um == 5.0  # zero gains: nothing moves


def test_esc_clamps_and_reports() -> None:
    esc = ExtremumSeekingController(EscParams(a_max_um=10.0, k_a=1e5))
    s = esc.initial_state(a_um=9.0)
    psi = 2 * np.pi * np.arange(100) / 100
    sat = False
    for _ in range(12):
        # the cost falls with a growing radius: the ESC pushes a_m to its limit
        f = max(30.0 - s.a_um, 0.0) * np.cos(psi)
        s, rec = esc.step(s, f, psi, 0.05)
        sat = sat or rec.saturated
        assert abs(rec.a_n_um) <= 10.0 - 2.0 + 1e-12
    assert sat


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"psi_theta": 0.0}, "psi_theta"),  # same phase: D_23 does not vanish
        ({"psi_a": 0.3, "psi_theta": 0.3 + math.pi}, "psi_theta"),  # even multiple
        ({"amp_a_um": 0.0}, "amp_a_um"),
        ({"amp_a_um": 70.0}, "amp_a_um"),
        ({"amp_theta_deg": 120.0}, "amp_theta_deg"),
        ({"k_a": -1.0}, "k_a"),
        ({"period_revs": 2}, "period_revs"),
        ({"hpf_cycles_per_rev": 0.3}, "hpf_cycles_per_rev"),
        ({"a_max_um": 0.0}, "a_max_um"),
        ({"freeze_revs": -1}, "freeze_revs"),
        ({"resume_ratio": 1.0}, "resume_ratio"),
        ({"demod_phase": float("nan")}, "demod_phase"),
        ({"demod_phase_theta": float("inf")}, "demod_phase_theta"),
    ],
)
def test_bad_esc_parameters_are_named(kw: dict[str, float], match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        EscParams(**kw)  # type: ignore[arg-type]


def test_decoupled_phases_are_accepted() -> None:
    EscParams(psi_a=0.0, psi_theta=-math.pi / 2)
    EscParams(psi_a=1.0, psi_theta=1.0 + 3 * math.pi / 2)


def test_bad_esc_inputs_are_named() -> None:
    esc = ExtremumSeekingController()
    with pytest.raises(ParameterError, match="a_um"):
        esc.initial_state(a_um=1e3)
    with pytest.raises(ParameterError, match="cost_ref"):
        esc.initial_state(cost_ref=0.0)
    s = esc.initial_state()
    with pytest.raises(ParameterError, match="force/angle"):
        esc.step(s, np.ones(10), np.ones(9), 0.05)
    with pytest.raises(ParameterError, match="rev_time"):
        esc.step(s, np.ones(10), np.ones(10), 0.0)


def test_positive_polar() -> None:
    assert positive_polar(-3.0, 10.0) == (3.0, 190.0)
    assert positive_polar(3.0, 370.0) == (3.0, 10.0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), ellipse=st.booleans())
def test_fast_tuner_solves_an_affine_response(seed: int, ellipse: bool) -> None:
    """On an exactly affine 1x response the tuner lands on its zero in one solve."""
    rng = np.random.default_rng(seed)
    d = 4 if ellipse else 2
    m = rng.normal(size=(4, d)) + 2.0 * np.eye(4, d)
    u_star = rng.uniform(-10, 10, size=d)
    f0 = -m @ u_star
    tuner = FastTuner(FastTunerParams(settle_revs=0, ellipse=ellipse))
    s = tuner.initial_state()
    psi = 2 * np.pi * np.arange(64) / 64
    for _ in range(d + 4):
        y = f0 + m @ np.array(s.u)
        s, rec = tuner.step(s, _synthetic_force(y, psi), psi, 0.05)
    assert np.linalg.norm(np.array(s.u) - u_star) < 1e-6
    assert rec.mode == "hold"
    assert rec.iterations <= 2


def test_fast_tuner_fit_rejects_collinear_points() -> None:
    t = FastTuner()
    with pytest.raises(ParameterError, match="one line"):
        t.fit([[0, 0], [1, 1], [2, 2]], np.zeros((3, 4)))
    with pytest.raises(ParameterError, match="3 points"):
        t.fit([[0, 0], [1, 1]], np.zeros((2, 4)))


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"probe_um": 0.0}, "probe_um"),
        ({"probe_um": 80.0}, "probe_um"),
        ({"measure_revs": 0}, "measure_revs"),
        ({"settle_revs": -1}, "settle_revs"),
        ({"max_points": 2}, "max_points"),
        ({"rise_ratio": 0.5}, "rise_ratio"),
        ({"ellipse": True, "max_points": 4}, "max_points"),
    ],
)
def test_bad_fast_tuner_parameters_are_named(kw: dict[str, float], match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        FastTunerParams(**kw)  # type: ignore[arg-type]


def test_fast_tuner_bad_inputs_are_named() -> None:
    t = FastTuner()
    with pytest.raises(ParameterError, match="a_um"):
        t.initial_state(a_um=59.0)
    with pytest.raises(ParameterError, match="forces"):
        t.step(t.initial_state(), np.ones((3, 10)), np.ones(10), 0.05)


def test_loop_block_steps_any_chunking() -> None:
    """The live API: step(n) in odd chunks equals whole revolutions."""
    a = EccentricityLoop(tuner="fast", adapt_start_s=0.1)
    b = EccentricityLoop(tuner="fast", adapt_start_s=0.1)
    a.run_revolutions(16)
    n = a.machine._s.k
    outs = []
    while b.machine._s.k < n:
        outs.append(b.step(min(37, n - b.machine._s.k)))
    assert np.allclose(a.log.arrays()["cost"], b.log.arrays()["cost"])
    fx = np.concatenate([o["fx"] for o in outs])
    assert fx.size == n
    assert set(outs[0]) >= {"t", "fx", "fy", "a_m_um", "theta_m_deg", "cost"}
    st_ = b.state()
    assert st_["mode"] == "fast:hold" and st_["adapting"] is True
    assert st_["a_n_um"] == pytest.approx(st_["true.cancelling_a_um"], rel=0.1)


def test_observer_source_needs_a_seeded_rng_for_noise() -> None:
    from harness.eccentricity_loop import ObserverForceSource
    from machine.milling import MillingMachine

    with pytest.raises(ParameterError, match="rng"):
        ObserverForceSource(MillingMachine().drives.params, current_noise=0.1)
    with pytest.raises(ParameterError, match="current_noise"):
        ObserverForceSource(MillingMachine().drives.params, current_noise=-1.0)


def test_loop_rejects_unknown_tuner() -> None:
    with pytest.raises(ParameterError, match="tuner"):
        EccentricityLoop(tuner="magic")
    with pytest.raises(ParameterError, match="cost_axis"):
        EccentricityLoop(cost_axis="z")


@pytest.fixture(scope="module")
def reproduction() -> dict[str, object]:
    from server.experiments.reproductions import seed003_eccentricity as eccentricity

    return eccentricity.run(quick=True, progress=False).to_json()


def _rows(rep: dict[str, object]) -> dict[str, float]:
    return {r["name"]: r["ours"] for r in rep["rows"]}  # type: ignore[index, union-attr]


def _checks(rep: dict[str, object]) -> dict[str, bool]:
    return {c["name"]: c["holds"] for c in rep["checks"]}  # type: ignore[index, union-attr]


@pytest.mark.slow
def test_reproduction_has_the_issue_rows(reproduction: dict[str, object]) -> None:
    rows = _rows(reproduction)
    for c in (1, 2):
        for r in (
            "converge_time_s",
            "cost_reduction",
            "a_m_um",
            "theta_m_deg",
            "fast_tuner.revolutions",
            "fast_tuner.cost_reduction",
        ):
            assert f"case{c}.{r}" in rows
    for r in (
        "case1.force_pp.before",
        "case1.force_pp.after",
        "case1.estimated_force.converge_time_s",
        "case1.estimated_force.cost_reduction",
    ):
        assert r in rows


@pytest.mark.slow
def test_esc_converges_to_the_cancelling_modulation(reproduction: dict[str, object]) -> None:
    rows = _rows(reproduction)
    for c in (1, 2):
        assert rows[f"case{c}.param_error"] < 0.1
        assert rows[f"case{c}.cost_reduction"] < 0.1
        assert rows[f"case{c}.force_pp.after"] < 0.1 * rows[f"case{c}.force_pp.before"]


@pytest.mark.xfail(
    strict=True,
    reason="with Table 1 step sizes (our unit reading) the ESC "
    "needs 17.6 s (case 1) and 15.4 s (case 2): a true gradient would need ~40/35 s (the "
    "2 deg phase dither is small tangentially) and the revolution-boundary transient "
    "scrambles the estimate; no reading or lag compensation tried reaches 15 s in both "
    "cases. See docs/reproductions/seed003-eccentricity.md, 'Why the ESC is slower than the paper'",
)
@pytest.mark.slow
def test_esc_converges_within_15_s(reproduction: dict[str, object]) -> None:
    checks = _checks(reproduction)
    assert checks["case1.esc_within_10pct_of_cancelling_by_15s"]
    assert checks["case2.esc_within_10pct_of_cancelling_by_15s"]


@pytest.mark.slow
def test_fast_tuner_beats_esc(reproduction: dict[str, object]) -> None:
    checks = _checks(reproduction)
    rows = _rows(reproduction)
    for c in (1, 2):
        assert checks[f"case{c}.fast_tuner_fewer_revolutions_than_esc"]
        assert checks[f"case{c}.fast_tuner_cost_below_10pct"]
        assert rows[f"case{c}.fast_tuner.revolutions"] <= 15
    assert checks["case1.fast_tuner_recovers_after_speed_change"]
    # the best published tuner: flute peak spread 101 N -> 14 N
    for c in (1, 2):
        assert rows[f"case{c}.fast_tuner.flute_peak_spread.ratio"] < 14.0 / 101.0


@pytest.mark.slow
def test_ellipse_undoes_mismatched_axes(reproduction: dict[str, object]) -> None:
    checks = _checks(reproduction)
    assert checks["case1.mismatch.ellipse_beats_circle"]
    assert checks["case2.mismatch.ellipse_beats_circle"]
    assert _rows(reproduction)["case1.mismatch.fast_tuner_ellipse.revolutions"] <= 15


@pytest.mark.slow
def test_estimated_force_drives_the_esc(reproduction: dict[str, object]) -> None:
    assert _checks(reproduction)["case1.estimated_force_esc_cost_below_10pct"]


@pytest.mark.slow
def test_cli_lists_and_prints_json(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["reproduce", "--list"]) == 0
    out = capsys.readouterr().out
    assert "eccentricity" in out and "case<1|2>.converge_time_s" in out
    rc = main(["bench", "eccentricity", "--quick", "--repeats", "1", "--json"])
    assert rc == 0
    res = json.loads(capsys.readouterr().out)
    assert res["eccentricity"]["esc_loop_realtime_factor"] > 0


def test_demodulation_delays_each_channel_by_its_phase() -> None:
    esc = ExtremumSeekingController(EscParams(demod_phase=0.7, demod_phase_theta=-0.2))
    for k in range(6):
        assert esc.demodulation(k)[0] == pytest.approx(esc.perturbation(k, lag=0.7)[0])
        assert esc.demodulation(k)[1] == pytest.approx(esc.perturbation(k, lag=-0.2)[1])
    plain = ExtremumSeekingController(EscParams())
    assert all(plain.demodulation(k) == plain.perturbation(k) for k in range(6))
    same = ExtremumSeekingController(EscParams(demod_phase=0.4))
    assert same.demodulation(3)[1] == pytest.approx(same.perturbation(3, lag=0.4)[1])


def test_dither_lag_of_a_one_revolution_delay_is_a_quarter_period() -> None:
    from server.experiments.reproductions._seed003_esc_ablations import dither_lag

    assert dither_lag(1.0, 4) == pytest.approx(0.0, abs=1e-12)
    assert dither_lag(0.0, 4) == pytest.approx(math.pi / 2)
    assert dither_lag(0.5, 4) == pytest.approx(math.pi / 4)
    assert dither_lag(0.0, 8) == pytest.approx(math.pi / 4)


def test_a_radius_step_shows_in_the_cost_mostly_one_revolution_late() -> None:
    """The mechanism behind the slow ESC (docs/reproductions/seed003-eccentricity.md):
    in case 1 a radius step of the dither
    shows in the cost of its own revolution only partly (drive transient and the
    previous tooth's surface, eq. 4), a phase step almost fully."""
    from machine.milling import MillingMachine
    from server.experiments.reproductions._seed003_cut import case_params
    from server.experiments.reproductions._seed003_esc_ablations import (
        first_revolution_response,
    )

    mp = case_params(1)
    a_s, th_s = MillingMachine(mp).cancelling_modulation()
    a, th = 0.5 * a_s * 1e6, math.degrees(th_s) - 30.0
    assert first_revolution_response(mp, a, th, 1.0, 0.0) < 0.5
    assert first_revolution_response(mp, a, th, 0.0, 1.0) > 0.8


def test_table1_gains_on_a_static_cone_need_far_more_than_10_s() -> None:
    """With a true gradient (no plant dynamics) Table 1's step sizes under our unit reading
    are slow because the 2 deg phase dither moves the circle only a * 0.035 um."""
    from server.experiments.reproductions._seed003_cut import ESC_TABLE1
    from server.experiments.reproductions._seed003_esc_ablations import static_cone_time

    u_star = 15.55 * np.exp(1j * math.radians(234.7))
    t = static_cone_time(ESC_TABLE1, 12.18, u_star, 0.05, 60.0)
    assert 30.0 < t < 60.0
    fast = EscParams(k_a=4 * 45.0, k_theta=4 * 50.0, freeze_revs=40)
    assert static_cone_time(fast, 12.18, u_star, 0.05, 60.0) < 15.0


# ---------------------------------------------------------------- item 7: mass error


def _identifier(order: float = 4.125, **kw: float) -> object:
    from estimators.axis_mass import AxisMassIdentifier, AxisMassParams

    p = {"mass0": 100.0, "viscous": 300.0, "order": order, "window_revs": 8, "windows": 5}
    p.update(kw)
    return AxisMassIdentifier(AxisMassParams(**p))  # type: ignore[arg-type]


@pytest.mark.parametrize("samples_per_rev", [250, 312.5])
def test_mass_identifier_ignores_every_spindle_harmonic(samples_per_rev: float) -> None:
    """Motor force = m x'' + b x' + a cut force with a mean, 1x, 4x and 8x 100-1000 times
    the inertial force at the excitation order: the mass comes out exact."""
    from estimators.axis_mass import AxisMassIdentifier

    m, b, nu = 150.0, 300.0, 4.125
    psi = 2 * np.pi * np.arange(int(64 * samples_per_rev)) / samples_per_rev
    w = 2 * np.pi * 20.0  # rad/s of the spindle
    x = 0.3e-6 * np.cos(nu * psi + 0.4)  # identification circle's X motion [m]
    acc = -((nu * w) ** 2) * x
    vel = -0.3e-6 * nu * w * np.sin(nu * psi + 0.4)
    cut = 400.0 + 12.0 * np.cos(psi + 0.7) + 60.0 * np.cos(4 * psi) + 9.0 * np.sin(8 * psi)
    force = m * acc + b * vel + cut
    idf = _identifier()
    assert isinstance(idf, AxisMassIdentifier)
    st = idf.initial_state()
    for i0 in range(0, psi.size, 97):  # odd block lengths
        sl = slice(i0, i0 + 97)
        st, rec = idf.step(st, acc[sl], vel[sl], force[sl], psi[sl])
    assert st.updates == 6  # 8 windows, the first (start-up) one discarded, the last open
    assert st.mass == pytest.approx(m, rel=1e-9)
    assert np.all(rec.mass == st.mass) or rec.mass[-1] == st.mass


def test_mass_identifier_does_not_update_without_excitation() -> None:
    """seed 000's PE condition: no circle, no update (the mass stays at its start)."""
    from estimators.axis_mass import AxisMassIdentifier

    psi = 2 * np.pi * np.arange(250 * 40) / 250
    cut = 400.0 + 12.0 * np.cos(psi + 0.7)
    idf = _identifier(acc_min=1e-3)
    assert isinstance(idf, AxisMassIdentifier)
    st, rec = idf.step(idf.initial_state(), 0 * psi, 0 * psi, cut, psi)
    assert st.updates == 0 and st.mass == 100.0
    assert np.all(rec.mass == 100.0)


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"order": 4.0}, "order"),
        ({"order": 4.1}, "order"),
        ({"windows": 0}, "windows"),
        ({"mass0": -1.0}, "mass0"),
        ({"mass_min": 200.0, "mass_max": 300.0}, "mass0"),
    ],
)
def test_bad_mass_identifier_parameters_are_named(kw: dict[str, float], match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        _identifier(**kw)


def test_excitation_is_refused_beyond_the_axis_limit() -> None:
    from machine.milling import MillingMachine

    with pytest.raises(ParameterError, match="amplitude"):
        MillingMachine().set_excitation(1e-3, 4.125)
    with pytest.raises(ParameterError, match="order"):
        MillingMachine().set_excitation(1e-6, 0.0)


def _inf(v: object) -> float:
    return math.inf if v is None else float(v)  # type: ignore[arg-type]


def test_a_3pct_mass_error_leaks_into_the_1x_force(reproduction: dict[str, object]) -> None:
    """The cause, measured: 3 % of m w^2 times the carriage circle, ~12 % of the
    eccentricity's 1x force, predicts the fixed observer's modulation error."""
    rows = _rows(reproduction)
    p = "case1.estimated_force.mass_error_3pct"
    w = 2 * np.pi * 20.0
    assert rows[f"{p}.leak_1x_N"] == pytest.approx(0.03 * 150.0 * w**2 * 20e-6, rel=0.01)
    assert 0.1 < rows[f"{p}.leak_ratio"] < 0.13
    assert rows[f"{p}.predicted_param_error"] == pytest.approx(rows[f"{p}.param_error"], rel=0.1)


def test_adaptive_observer_converges_with_a_3pct_mass_error(
    reproduction: dict[str, object],
) -> None:
    """The fixed observer with +-3 % never converges; the adaptive one does within 1.5x
    the exact-mass time, at Table 1's eccentricity phase and at 0 / 315 deg."""
    rows = _rows(reproduction)
    checks = _checks(reproduction)
    e = "case1.estimated_force"
    t_exact = rows[f"{e}.converge_time_s"]
    for label in ("mass_error_3pct", "mass_error_minus3pct"):
        assert _inf(rows[f"{e}.{label}.converge_time_s"]) == math.inf
        assert rows[f"{e}.{label}.cost_reduction"] > 0.1
        a = f"{e}.{label}.adaptive_mass"
        assert _inf(rows[f"{a}.converge_time_s"]) <= 1.5 * t_exact
        assert rows[f"{a}.cost_reduction"] < 0.1
        assert rows[f"{a}.param_error"] < 0.05
        assert abs(rows[f"{a}.mass_error_x"]) < 0.005
        assert abs(rows[f"{a}.mass_error_y"]) < 0.005
        assert checks[f"{e}.{label}.adaptive_converges_within_1.5x_exact"]
    for deg in (0, 315):
        p = f"{e}.ecc_{deg}deg"
        assert _inf(rows[f"{p}.mass_error_3pct.converge_time_s"]) == math.inf
        assert _inf(rows[f"{p}.adaptive_mass.converge_time_s"]) <= 1.5 * _inf(
            rows[f"{p}.exact.converge_time_s"]
        )
    assert rows[f"{e}.mass_error_3pct.adaptive_mass.mass_time_s"] < 1.0


def test_adaptive_observer_under_current_noise_matches_the_exact_mass(
    reproduction: dict[str, object],
) -> None:
    """8 seeds of 0.05 A current noise: the adaptive observer (+3 % nominal) reaches the
    cancelling modulation as often and as fast as the exact-mass fixed one."""
    rows = _rows(reproduction)
    p = "case1.estimated_force.mass_error_3pct.adaptive_mass.current_noise"
    assert rows[f"{p}.adaptive.param_converged"] == 8.0
    assert rows[f"{p}.adaptive.param_converged"] >= rows[f"{p}.exact_fixed.param_converged"]
    assert rows[f"{p}.adaptive.param_converge_time_s_median"] <= 1.1 * _inf(
        rows[f"{p}.exact_fixed.param_converge_time_s_median"]
    )
    assert rows[f"{p}.adaptive.converged"] >= rows[f"{p}.exact_fixed.converged"]
