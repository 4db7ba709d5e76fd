"""Tool wear (issue 7, seed 004): model, linearisation, U-D RLS, observers, monitor."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import cont2discrete, ss2tf

from estimators.errors import ParameterError as EstParameterError
from estimators.ud_rls import ForgettingRLS, ForgettingRLSParams
from estimators.wear.linear import (
    DiscreteModel,
    LinearModel,
    linearise_along_path,
    observer_form,
    observer_transform,
    transfer_function,
    zoh,
)
from estimators.wear.monitor import ToolLifeMonitor, ToolLifeParams
from estimators.wear.observer import (
    AdaptiveWearObserver,
    WearConstraints,
    WearObserverParams,
    deadbeat_observer_step,
)
from machine.errors import ParameterError as MachParameterError
from machine.tool_wear import (
    CuttingCondition,
    ToolWearModel,
    WearModelParams,
)

# ---------------------------------------------------------------- U-D RLS vs plain RLS


def _run_rls(method: str, phi: np.ndarray, y: np.ndarray, beta: float):
    p = ForgettingRLSParams(n=phi.shape[1], forgetting=beta, p0=100.0, method=method)  # type: ignore[arg-type]
    est = ForgettingRLS(p)
    return est.step(est.initial_state(), phi, y)


@pytest.mark.parametrize("beta", [1.0, 0.95])
def test_ud_rls_equals_plain_rls_on_well_conditioned_data(beta: float) -> None:
    rng = np.random.default_rng(3)
    phi = rng.standard_normal((400, 6))
    theta = np.array([-3.0, 3.0, -1.0, 15.0, -30.0, 15.0])
    y = phi @ theta + 0.01 * rng.standard_normal(400)
    s_ud, r_ud = _run_rls("ud", phi, y, beta)
    s_pl, r_pl = _run_rls("plain", phi, y, beta)
    np.testing.assert_allclose(r_ud.theta, r_pl.theta, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(s_ud.covariance(), s_pl.P, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(s_ud.theta, theta, atol=0.01)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), beta=st.floats(0.9, 1.0))
def test_ud_covariance_stays_symmetric_positive_definite(seed: int, beta: float) -> None:
    rng = np.random.default_rng(seed)
    phi = rng.standard_normal((60, 6)) * rng.uniform(0.1, 10.0, size=6)
    y = rng.standard_normal(60)
    s, _ = _run_rls("ud", phi, y, beta)
    P = s.covariance()
    np.testing.assert_allclose(P, P.T, atol=1e-12 * np.abs(P).max())
    assert np.all(s.D > 0)
    assert np.all(np.linalg.eigvalsh(P) > 0)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_rls_converges_on_rich_noise_free_data(seed: int) -> None:
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-5, 5, size=4)
    phi = rng.standard_normal((80, 4))
    s, _ = _run_rls("ud", phi, phi @ theta, 1.0)
    # with beta = 1 the RLS is exactly the least-squares fit with the prior P0 = 100 I
    # (a ridge of 1/100 towards 0): equal to that closed form, and close to theta
    ridge = np.linalg.solve(np.eye(4) / 100.0 + phi.T @ phi, phi.T @ (phi @ theta))
    np.testing.assert_allclose(s.theta, ridge, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(s.theta, theta, atol=5e-3)


def test_rls_params_reject_bad_forgetting_and_shapes() -> None:
    with pytest.raises(EstParameterError, match=r"forgetting.*\(0, 1\].*1\.5"):
        ForgettingRLSParams(n=3, forgetting=1.5)
    with pytest.raises(EstParameterError, match=r"forgetting.*\(0, 1\]"):
        ForgettingRLSParams(n=3, forgetting=0.0)
    with pytest.raises(EstParameterError, match="method"):
        ForgettingRLSParams(n=3, method="qr")  # type: ignore[arg-type]
    est = ForgettingRLS(ForgettingRLSParams(n=3))
    with pytest.raises(EstParameterError, match=r"phi.*\(2, 3\)"):
        est.step(est.initial_state(), np.zeros((2, 4)), np.zeros(2))


# ---------------------------------------------------------------- deadbeat observer


def _observer_form_system(a, b, x0, u):
    Ao, bo, co = observer_form(a, b)
    xs, ys = [], []
    x = np.asarray(x0, dtype=float)
    for uk in u:
        xs.append(x.copy())
        ys.append(float(co @ x))
        x = Ao @ x + bo * uk
    return np.array(xs), np.array(ys)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_deadbeat_observer_reaches_true_state_in_three_steps(seed: int) -> None:
    rng = np.random.default_rng(seed)
    # a known third-order system: poles inside/at the unit circle, arbitrary zeros
    poles = rng.uniform(-0.95, 1.0, size=3)
    a = np.poly(poles)[1:]
    b = rng.uniform(-20, 20, size=3)
    u = rng.uniform(0.05, 0.2, size=8)
    xs, ys = _observer_form_system(a, b, rng.uniform(-50, 50, size=3), u)
    xh = rng.uniform(-100, 100, size=3)  # wrong initial estimate
    est = [xh]
    for k in range(7):
        xh = deadbeat_observer_step(a, b, xh, u[k], ys[k])
        est.append(xh)
    assert np.max(np.abs(est[0] - xs[0])) > 1e-3
    for k in range(3, 8):
        np.testing.assert_allclose(est[k], xs[k], atol=1e-9 * (1 + np.abs(xs[k]).max()))


def test_adaptive_observer_kernel_matches_deadbeat_step_with_frozen_parameters() -> None:
    a = np.array([-2.9, 2.8, -0.9])
    b = np.array([12.0, -20.0, 9.0])
    u = np.full(30, 0.1)
    xs, ys = _observer_form_system(a, b, np.zeros(3), u)
    D = 4000.0
    p = WearObserverParams(theta0=np.concatenate([a, b]), p0=1e-300, constraints=None)
    obs = AdaptiveWearObserver(p)
    _, rec = obs.step(obs.initial_state(), ys + D * u, u)
    np.testing.assert_allclose(rec.static_gain, D)
    np.testing.assert_allclose(rec.dy, ys, atol=1e-9)
    np.testing.assert_allclose(rec.theta[-1], np.concatenate([a, b]), rtol=1e-9)
    np.testing.assert_allclose(rec.x0_hat[3:], xs[3:], atol=1e-8)


def test_static_gain_reestimated_on_feed_change_keeps_wear_force_continuous() -> None:
    n = 40
    u = np.where(np.arange(n) < 20, 0.1, 0.12)
    wear_force = np.linspace(0.0, 20.0, n)
    # static force affine in the feed: the ratio at the start differs from the slope
    y = 500.0 + 3000.0 * (u - 0.1) + wear_force
    obs = AdaptiveWearObserver(WearObserverParams(theta0=[-3, 3, -1, 10, -20, 10]))
    _, rec = obs.step(obs.initial_state(), y, u)
    assert rec.static_gain[0] == pytest.approx(5000.0)  # eq. (25): y(0)/u(0)
    # section 4.3.1: the change of output over the change of input (+ one step of wear)
    assert rec.static_gain[-1] == pytest.approx(3000.0 + (20.0 / (n - 1)) / 0.02, rel=1e-9)
    np.testing.assert_allclose(np.diff(rec.dy), np.diff(wear_force)[0], atol=2.0)


def test_observer_params_reject_bad_input() -> None:
    good = [-3.0, 3.0, -1.0, 10.0, -20.0, 10.0]
    with pytest.raises(EstParameterError, match=r"theta0.*inside the constraints.*a1"):
        WearObserverParams(theta0=[-2.5, 3.0, -1.0, 10.0, -20.0, 10.0])
    with pytest.raises(EstParameterError, match=r"b3/b1 in \[0.8, 1.2\]"):
        WearObserverParams(theta0=[-3.0, 3.0, -1.0, 10.0, -20.0, 15.0])
    with pytest.raises(EstParameterError, match=r"scale_output.*non-zero.*0\.0"):
        WearObserverParams(theta0=good, scale_output=0.0)
    with pytest.raises(EstParameterError, match=r"scale_input.*non-zero"):
        WearObserverParams(theta0=good, scale_input=0.0)
    with pytest.raises(EstParameterError, match=r"forgetting.*\(0, 1\].*1\.01"):
        WearObserverParams(theta0=good, forgetting=1.01)
    with pytest.raises(EstParameterError, match=r"forgetting.*\(0, 1\]"):
        WearObserverParams(theta0=good, forgetting=0.0)
    with pytest.raises(EstParameterError, match=r"a_bounds.*lo < hi"):
        WearConstraints(a_bounds=((-2.8, -3.2), (2.8, 3.2), (-1.2, -0.8)))
    obs = AdaptiveWearObserver(WearObserverParams(theta0=good))
    with pytest.raises(EstParameterError, match=r"feed.*> 0 mm/rev during the cut"):
        obs.step(obs.initial_state(), [500.0, 510.0], [0.1, 0.0])


# ---------------------------------------------------------------- linear models


def test_jacobians_agree_with_finite_differences() -> None:
    rng = np.random.default_rng(5)
    for cond in (CuttingCondition(150.0, 2.0), CuttingCondition(220.0, 3.0)):
        m = ToolWearModel(condition=cond)
        for _ in range(5):
            x = rng.uniform([0.01, 0.01, 0.005], [0.25, 0.2, 0.1])
            f = float(rng.uniform(0.08, 0.2))
            dfdx, dfdu, dgdx, dgdu = m.jacobians(x, f)
            for i in range(3):
                h = 1e-6
                e = np.zeros(3)
                e[i] = h
                fd = (m.rates(x + e, f) - m.rates(x - e, f)) / (2 * h)
                np.testing.assert_allclose(dfdx[:, i], fd, rtol=1e-5, atol=1e-9)
                gd = (m.force(x + e, f) - m.force(x - e, f)) / (2 * h)
                assert dgdx[i] == pytest.approx(gd, rel=1e-6)
            h = 1e-7
            fd_u = (m.rates(x, f + h) - m.rates(x, f - h)) / (2 * h)
            np.testing.assert_allclose(dfdu, fd_u, rtol=1e-5, atol=1e-9)
            assert dgdu == pytest.approx(
                (m.force(x, f + h) - m.force(x, f - h)) / (2 * h), rel=1e-6
            )


def test_linearisation_along_path_is_the_mean_of_finite_difference_jacobians() -> None:
    m = ToolWearModel()
    f = 0.1
    x1 = np.array([0.16, 0.05, 0.03])

    def fd_jac(x, u):
        h = 1e-6
        J = np.empty((3, 3))
        for i in range(3):
            e = np.zeros(3)
            e[i] = h
            J[:, i] = (m.rates(x + e, u) - m.rates(x - e, u)) / (2 * h)
        ju = (m.rates(x, u + h) - m.rates(x, u - h)) / (2 * h)
        gx = np.array(
            [(m.force(x + h * e, u) - m.force(x - h * e, u)) / (2 * h) for e in np.eye(3)]
        )
        gu = (m.force(x, u + h) - m.force(x, u - h)) / (2 * h)
        return J, ju, gx, gu

    # finite differences at x = 0 reach negative w_f2, which eq. (6) clamps: start at a
    # small positive offset through a shifted callable
    lin_a = linearise_along_path(lambda x, u: m.jacobians(x + 1e-5, u), x1, f, n_intervals=50)
    lin_f = linearise_along_path(lambda x, u: fd_jac(x + 1e-5, u), x1, f, n_intervals=50)
    np.testing.assert_allclose(lin_a.A, lin_f.A, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(lin_a.b, lin_f.b, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(lin_a.c, lin_f.c, rtol=1e-6)
    # eq. (A11) by hand: the mean over i = 0..n'-1 of the Jacobian at i x1 / n'
    manual = np.mean([m.jacobians(i * x1 / 50 + 1e-5, f)[0] for i in range(50)], axis=0)
    np.testing.assert_allclose(lin_a.A, manual, rtol=1e-12)


def test_zoh_transfer_function_and_observer_transform() -> None:
    rng = np.random.default_rng(2)
    A = rng.standard_normal((3, 3)) * 0.5 - np.eye(3)
    lm = LinearModel(A=A, b=rng.standard_normal(3), c=rng.standard_normal(3), D=2.0)
    dm = zoh(lm, 0.1)
    Pd, qd, _, _, _ = cont2discrete((A, lm.b[:, None], lm.c[None, :], [[0.0]]), 0.1, method="zoh")
    np.testing.assert_allclose(dm.P, Pd, rtol=1e-10)
    np.testing.assert_allclose(dm.q, qd[:, 0], rtol=1e-10)
    a, b = transfer_function(dm)
    num, den = ss2tf(dm.P, dm.q[:, None], dm.c[None, :], [[0.0]])
    np.testing.assert_allclose(a, den[1:], atol=1e-10)
    np.testing.assert_allclose(b, num[0, 1:], atol=1e-10)
    T = observer_transform(dm)
    Ao, bo, co = observer_form(a, b)
    Ti = np.linalg.inv(T)
    np.testing.assert_allclose(Ti @ dm.P @ T, Ao, atol=1e-9)
    np.testing.assert_allclose(Ti @ dm.q, bo, atol=1e-9)
    np.testing.assert_allclose(dm.c @ T, co, atol=1e-9)


def test_unobservable_model_is_rejected() -> None:
    dm = DiscreteModel(
        P=np.eye(3), q=np.ones(3), c=np.array([1.0, 0.0, 0.0]), D=0.0, sample_time=0.1
    )
    with pytest.raises(EstParameterError, match="observable"):
        observer_transform(dm)


# ---------------------------------------------------------------- nonlinear model


def test_model_rejects_non_positive_feed_speed_depth() -> None:
    m = ToolWearModel()
    with pytest.raises(MachParameterError, match=r"feed.*> 0 mm/rev.*-0\.1"):
        m.force(np.zeros(3), -0.1)
    with pytest.raises(MachParameterError, match=r"feed.*> 0"):
        m.simulate([0.1, 0.0], 0.01)
    with pytest.raises(MachParameterError, match=r"speed.*> 0.*0"):
        CuttingCondition(speed=0.0)
    with pytest.raises(MachParameterError, match=r"depth.*> 0.*-2"):
        CuttingCondition(depth=-2.0)
    with pytest.raises(MachParameterError, match=r"K1.*> 0"):
        WearModelParams(K1=0.0)
    with pytest.raises(MachParameterError, match=r"sample_time"):
        m.simulate([0.1], 0.0)


def test_model_sharp_tool_and_wear_growth() -> None:
    m = ToolWearModel()
    tr = m.simulate(np.full(500, 0.1), 0.01)
    assert tr.force[0] == pytest.approx(m.force(np.zeros(3), 0.1))
    assert np.all(np.diff(tr.states[:, 1]) > 0) and np.all(np.diff(tr.states[:, 2]) > 0)
    # the abrasive land approaches its eq. (3) steady state, which the force raises
    assert 0.1 < tr.states[-1, 0] < 0.25


# ---------------------------------------------------------------- tool-life monitor


def test_monitor_exact_on_linear_wear() -> None:
    s = 996.0
    t = np.arange(1, 201) * 0.2
    # pass means of a land growing 0.01 mm/min from 0.05 mm: the value at mid-pass
    F = 500.0 + s * (0.05 + 0.01 * (t - 0.1))
    # the sharp-tool force is extrapolated to t = 0 from the first two passes, so the
    # estimated land is the growth since t = 0, which reaches 0.3 mm at 30.1 min
    mon = ToolLifeMonitor(ToolLifeParams(force_per_flank_wear=s, trend_forgetting=1.0))
    _, rec = mon.step(mon.initial_state(), t, F, np.full(len(t), 0.1))
    np.testing.assert_allclose(rec.vb[1:], 0.01 * (t[1:] - 0.1), atol=1e-9)
    t_star = 30.1
    j = 50
    assert rec.remaining_life[j] == pytest.approx(t_star - t[j], rel=1e-6)
    assert rec.remaining_life_sd[j] == pytest.approx(0.0, abs=1e-4)
    w = np.flatnonzero(rec.warning)[0]
    a = np.flatnonzero(rec.alarm)[0]
    assert t[w] == pytest.approx(0.8 * t_star, abs=0.2 + 1e-9)
    assert t[a] == pytest.approx(0.95 * t_star, abs=0.2 + 1e-9)


def test_monitor_split_blocks_equal_one_block() -> None:
    t = np.arange(1, 61) * 0.25
    F = 520.0 + 90.0 * np.sqrt(t) + np.sin(t)
    mon = ToolLifeMonitor(ToolLifeParams(force_per_flank_wear=900.0))
    _, r1 = mon.step(mon.initial_state(), t, F, np.full(60, 0.1))
    s = mon.initial_state()
    parts = []
    for i in range(0, 60, 7):
        s, r = mon.step(s, t[i : i + 7], F[i : i + 7], np.full(len(t[i : i + 7]), 0.1))
        parts.append(r.remaining_life)
    np.testing.assert_allclose(np.concatenate(parts), r1.remaining_life, rtol=1e-12)


def test_monitor_rejects_bad_input() -> None:
    with pytest.raises(EstParameterError, match=r"warning_fraction.*\(0, 0.95\).*0\.97"):
        ToolLifeParams(force_per_flank_wear=900.0, warning_fraction=0.97)
    with pytest.raises(EstParameterError, match=r"alarm_fraction"):
        ToolLifeParams(force_per_flank_wear=900.0, alarm_fraction=1.2)
    with pytest.raises(EstParameterError, match=r"force_per_flank_wear.*> 0"):
        ToolLifeParams(force_per_flank_wear=0.0)
    with pytest.raises(EstParameterError, match=r"trend_forgetting"):
        ToolLifeParams(force_per_flank_wear=900.0, trend_forgetting=0.0)
    mon = ToolLifeMonitor(ToolLifeParams(force_per_flank_wear=900.0))
    with pytest.raises(EstParameterError, match=r"feed.*> 0 mm/rev for every pass"):
        mon.step(mon.initial_state(), [1.0], [500.0], [0.0])
    with pytest.raises(EstParameterError, match=r"strictly increasing"):
        mon.step(mon.initial_state(), [1.0, 1.0], [500.0, 501.0], [0.1, 0.1])
