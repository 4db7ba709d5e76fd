"""The simulated stage and the cutting force observer on it."""

import math

import numpy as np
import pytest

from estimators.errors import ParameterError as EstParameterError
from estimators.filters import lowpass
from estimators.force_observer import (
    LoadParams,
    ObserverParams,
    TorsionEstimator,
    TorsionRecord,
    cutting_force,
    cutting_force_lagged,
)
from machine.effects import EFFECT_NAMES, PlantEffects
from machine.errors import ParameterError
from machine.stage import StageConfig, StageSim, Trajectory
from machine.stage_params import ADDED_WEIGHT_INERTIA, StageParams, preset


def test_presets_have_their_first_resonance_at_a_few_hundred_hz() -> None:
    for name in ("seed000", "seed001"):
        p = preset(name)
        assert 300 < p.resonance_hz < 500
        assert p.antiresonance_hz < p.resonance_hz


def test_encoders_are_20_bit_quantised_and_current_gives_torque() -> None:
    sim = StageSim()
    m, _ = sim.step(500)
    q = 2 * math.pi / 2**20
    np.testing.assert_allclose(m.q_m / q, np.round(m.q_m / q), atol=1e-6)
    np.testing.assert_allclose(m.q_l / q, np.round(m.q_l / q), atol=1e-6)
    np.testing.assert_allclose(m.tau_m, 0.5710 * m.i_m)


def test_velocity_loop_follows_the_reciprocating_trajectory() -> None:
    sim = StageSim()
    meas, truth = sim.step(int(3.0 / 4e-4))
    # mean load velocity over the plateau (the 100/200 Hz force shakes it around it)
    m = (meas.t > 1.0) & (meas.t < 3.0)
    assert abs(truth.omega_l[m].mean() - 30.0) < 1.0
    tr = Trajectory()
    assert tr(np.array([2.0]))[0] == 30.0
    assert tr(np.array([6.0]))[0] == -30.0
    assert tr(np.array([4.0]))[0] == pytest.approx(0.0, abs=1e-9)


def test_blocks_can_be_split_anywhere_without_changing_the_run() -> None:
    a, b = StageSim(), StageSim()
    ma, _ = a.step(1000)
    parts = [b.step(n)[0] for n in (1, 124, 375, 500)]
    np.testing.assert_array_equal(ma.q_l, np.concatenate([p.q_l for p in parts]))
    np.testing.assert_array_equal(ma.i_m, np.concatenate([p.i_m for p in parts]))


def test_weight_changes_the_true_inertia_only() -> None:
    sim = StageSim()
    sim.step(10)
    sim.set_weight(True)
    _, tr = sim.step(10)
    assert tr.J_L[0] == pytest.approx(preset("seed000").J_L + ADDED_WEIGHT_INERTIA)
    assert sim.config.params.J_L == preset("seed000").J_L  # nominal untouched


def _observer_error(cfg: StageConfig, seconds: float = 3.0) -> tuple[float, float]:
    sim = StageSim(cfg)
    nom = cfg.nominal or cfg.params  # the observer knows the nominal motor side only
    ts, res = cfg.sample_time, cfg.encoder_resolution
    fe = TorsionEstimator(ObserverParams(nom.J_M, nom.B_M, nom.F_CM, nom.K, ts, res))
    st = fe.initial_state()
    p = cfg.true_params
    est, true = [], []
    for _ in range(int(seconds / 0.05)):
        m, tr = sim.step(125)
        st, rec = fe.step(st, m.tau_m, m.q_m, m.q_l)
        est.append(cutting_force(rec, p.J_L, p.B_L, p.F_CL))
        true.append(tr.f_cut)
    f_hat = np.concatenate(est)
    f = np.concatenate(true)
    qf, _ = lowpass(250.0, cfg.sample_time, 1).run(f)
    sl = slice(int(1.0 / cfg.sample_time), None)  # after the start-up
    # the estimate at sample k refers to t[k-1]
    e = f_hat[1:][sl] - qf[:-1][sl]
    return float(np.sqrt(np.mean(e**2))), float(np.sqrt(np.mean(f[sl] ** 2)))


def test_observer_with_exact_parameters_recovers_q_of_the_true_force() -> None:
    err, f_rms = _observer_error(StageConfig())
    # measured 0.047 N m on a 5.66 N m rms force: quantisation (q/ts^2 = 37 rad/s^2 on
    # the acceleration) plus the sampling of the 200 Hz motion within 0.4 ms
    assert f_rms == pytest.approx(math.sqrt(4**2 + 8 + 8), rel=1e-3)
    assert err < 0.01 * f_rms


def test_an_undeclared_plant_effect_shows_up_in_the_estimate() -> None:
    base, _ = _observer_error(StageConfig())
    eff = PlantEffects().with_enabled("offset")
    with_offset, _ = _observer_error(StageConfig(effects=eff))
    # the estimators are not told: the constant load torque appears as force error
    assert with_offset > base + 0.25


@pytest.mark.parametrize(
    ("factory", "match"),
    [
        (
            lambda: StageParams(J_M=-1, J_L=1, K=1, K_t=1, B_M=0, B_L=0, F_CM=0, F_CL=0),
            "J_M.*> 0.*-1",
        ),
        (lambda: StageParams(J_M=1, J_L=0.0, K=1, K_t=1, B_M=0, B_L=0, F_CM=0, F_CL=0), "J_L.*> 0"),
        (
            lambda: StageParams(J_M=1, J_L=1, K=float("nan"), K_t=1, B_M=0, B_L=0, F_CM=0, F_CL=0),
            "K",
        ),
        (lambda: preset("seed999"), "preset.*seed000.*seed999"),
        (lambda: PlantEffects(enabled=frozenset({"gravity"})), "effects.*gravity"),
        (lambda: PlantEffects().toggled("nope", True), "effect.*nope"),
        (lambda: StageConfig(substeps=0), "substeps"),
    ],
)
def test_bad_machine_input_is_named(factory, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        factory()


@pytest.mark.parametrize(
    ("factory", "match"),
    [
        (lambda: ObserverParams(J_M=0.0, B_M=0, F_CM=0, K=1), "J_M"),
        (lambda: ObserverParams(J_M=1, B_M=0, F_CM=0, K=1, q_hz=1300.0), "q_hz.*Nyquist"),
        (lambda: LoadParams(J_L=float("nan"), B_L=0, F_CL=0), "J_L"),
    ],
)
def test_bad_observer_input_is_named(factory, match: str) -> None:
    with pytest.raises(EstParameterError, match=match):
        factory()


def test_every_canonical_effect_runs_and_stays_bounded() -> None:
    for name in EFFECT_NAMES:
        sim = StageSim(StageConfig(effects=PlantEffects().with_enabled(name)))
        m, tr = sim.step(5000)
        assert np.all(np.isfinite(m.q_l)), name
        assert np.abs(tr.omega_l).max() < 200, name


def test_small_expm_agrees_with_scipy() -> None:
    import scipy.linalg

    from common.linalg import expm

    rng = np.random.default_rng(2)
    for scale in (1e-3, 0.3, 5.0, 300.0):
        m = rng.normal(size=(6, 6)) * scale
        m[4:, :] = 0.0  # the augmented form used for ZOH
        ref = scipy.linalg.expm(m)
        np.testing.assert_allclose(expm(m), ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())


def test_trajectory_dwell_and_levels() -> None:
    tr = Trajectory(half_period=2.0, dwell=0.4, levels=(1.0, 0.5))
    assert tr(np.array([1.0]))[0] == 30.0
    assert tr(np.array([2.0, 2.15]))[0] == 0.0 and tr(np.array([2.15]))[0] == 0.0  # at rest
    assert tr(np.array([3.0]))[0] == -15.0  # second plateau: half speed, reversed
    assert tr(np.array([5.0]))[0] == 30.0
    # without the options, the papers' shape: a straight ramp through zero
    assert Trajectory()(np.array([4.025]))[0] == pytest.approx(-15.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"dwell": -1.0}, "dwell.*>= 0"),
        ({"dwell": 4.0}, "dwell.*half_period"),
        ({"levels": (1.0, 1.5)}, r"levels.*\(0, 1\]"),
        ({"levels": ()}, "levels"),
        ({"speed": 0.0}, "speed"),
    ],
)
def test_bad_trajectory_is_named(kwargs: dict, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        Trajectory(**kwargs)


def test_cutting_force_lagged_is_eq2_with_the_previous_samples_parameters() -> None:
    rng = np.random.default_rng(5)
    n = 37
    rec = TorsionRecord(*(rng.normal(size=n) for _ in range(8)))
    theta0 = np.array([2.8e-4, 2e-3, 0.15, 0.3])
    theta = theta0 * (1.0 + 0.1 * rng.normal(size=(n, 4)))
    th = np.vstack([theta0, theta[:-1]])
    want = cutting_force(rec, th[:, 0], th[:, 1], th[:, 2])
    # the same operations per sample: equal, not only close
    assert np.array_equal(cutting_force_lagged(rec, theta0, theta), want)
    assert cutting_force_lagged(rec, theta0, theta)[0] == cutting_force(rec, *theta0[:3])[0]
    with pytest.raises(EstParameterError, match="theta0/theta"):
        cutting_force_lagged(rec, theta0, theta[:-1])
    with pytest.raises(EstParameterError, match="theta0/theta"):
        cutting_force_lagged(rec, theta0[:2], theta[:, :2])
