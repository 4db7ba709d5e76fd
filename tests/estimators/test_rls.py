"""The rectangular-window RLS: against batch least squares, and its properties."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimators.errors import ParameterError
from estimators.rls import (
    IdentifierParams,
    LoadIdentifier,
    Ridge,
    RLSParams,
    excitation_index,
    rls_box,
    rls_init,
    rls_update,
)


def _feed(p: RLSParams, phi: np.ndarray, y: np.ndarray, theta0: np.ndarray):
    s = rls_init(p, theta0)
    box, ridge = rls_box(p), Ridge(p.p0, 1)
    out = []
    for k in range(len(y)):
        rls_update(s.arrays, box, ridge, phi[k] * box.scale, y[k])
        out.append(s.theta * box.scale)
    return s, np.array(out)


def test_sliding_rls_equals_batch_least_squares_over_the_window() -> None:
    rng = np.random.default_rng(3)
    n, L = 600, 100
    phi = rng.normal(size=(n, 4)) * [300.0, 20.0, 1.0, 1.0]
    theta = np.array([2.8e-4, 2e-3, 0.15, 4.0])
    # the true parameters drift half way: the window must forget the old ones
    y = phi @ theta + 1e-3 * rng.normal(size=n)
    y[300:] += phi[300:, 0] * 2.92e-4
    p = RLSParams(
        window=L, scale=(2.8e-4, 2e-3, 0.15, 1.0), lower=(-1e3,) * 4, upper=(1e3,) * 4, p0=1e8
    )
    _, est = _feed(p, phi, y, np.zeros(4))
    for k in (150, 299, 350, 420, 599):
        sl = slice(k - L + 1, k + 1)
        ref = np.linalg.lstsq(phi[sl], y[sl], rcond=None)[0]
        np.testing.assert_allclose(est[k], ref, rtol=1e-5, atol=1e-9)
    assert abs(est[-1, 0] - (2.8e-4 + 2.92e-4)) < 1e-5


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), window=st.integers(4, 40), scale=st.floats(1e-3, 1e3))
def test_covariance_stays_symmetric_positive_definite(seed: int, window: int, scale: float) -> None:
    rng = np.random.default_rng(seed)
    n = 150
    phi = rng.normal(size=(n, 3)) * scale
    y = rng.normal(size=n)
    p = RLSParams(
        window=window, scale=(1.0, 1.0, 1.0), lower=(-1e6,) * 3, upper=(1e6,) * 3, p0=10.0
    )
    s, _ = _feed(p, phi, y, np.zeros(3))
    np.testing.assert_allclose(s.P, s.P.T, atol=1e-12 * np.abs(s.P).max())
    assert np.linalg.eigvalsh(s.P).min() > 0


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), lo=st.floats(-2, 0.5), width=st.floats(0.1, 3))
def test_projection_keeps_parameters_in_bounds(seed: int, lo: float, width: float) -> None:
    rng = np.random.default_rng(seed)
    n = 200
    phi = rng.normal(size=(n, 2))
    theta_true = rng.normal(size=2) * 5  # often outside the box
    y = phi @ theta_true
    hi = lo + width
    p = RLSParams(window=20, scale=(1.0, 1.0), lower=(lo, lo), upper=(hi, hi), p0=10.0)
    _, est = _feed(p, phi, y, np.array([lo, lo]))
    assert np.all(est >= lo - 1e-12)
    assert np.all(est <= hi + 1e-12)


def test_rls_converges_on_rich_noise_free_data() -> None:
    rng = np.random.default_rng(5)
    phi = rng.normal(size=(300, 3))
    th = np.array([1.5, -0.3, 2.0])
    p = RLSParams(window=50, scale=(1.0, 1.0, 1.0), lower=(-10,) * 3, upper=(10,) * 3, p0=1e6)
    _, est = _feed(p, phi, phi @ th, np.zeros(3))
    np.testing.assert_allclose(est[-1], th, atol=1e-4)


def test_lost_positive_definiteness_is_detected_and_reported() -> None:
    p = RLSParams(window=5, scale=(1.0, 1.0), lower=(-10, -10), upper=(10, 10), p0=1.0)
    s = rls_init(p, np.zeros(2))
    # corrupt the covariance: the next downdate/update must detect it and reset
    box, ridge = rls_box(p), Ridge(p.p0, 1)
    for k in range(5):
        rls_update(s.arrays, box, ridge, np.array([1.0, k]), 1.0)
    s.P[:] = -np.eye(2)
    rc = rls_update(s.arrays, box, ridge, np.array([1.0, 0.5]), 1.0)
    assert rc == 1
    assert s.meta[2] == 1  # reset counted
    assert np.linalg.eigvalsh(s.P).min() > 0


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"window": 2}, "window.*>= the number of parameters \\(4\\)"),
        ({"q_rls_hz": 1250.0}, "q_rls_hz"),
        ({"acc_threshold": float("nan")}, "acc_threshold"),
        ({"lower": (1.0, 0.0, 0.0, -1.0), "upper": (0.5, 1.0, 1.0, 1.0)}, "lower < upper"),
        ({"scale": (0.0, 1.0, 1.0, 1.0)}, "scale"),
    ],
)
def test_bad_identifier_parameters_are_named(kwargs: dict, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        IdentifierParams(**kwargs)


def test_a_failed_downdate_resets_and_keeps_the_new_sample() -> None:
    p = RLSParams(window=3, scale=(1.0,), lower=(-10,), upper=(10,), p0=1.0)
    s = rls_init(p, np.zeros(1))
    box, ridge = rls_box(p), Ridge(p.p0, 1)
    for _ in range(3):
        rls_update(s.arrays, box, ridge, np.array([1.0]), 2.0)
    # make the oldest sample's downdate impossible (1 - phi P phi <= 0)
    s.P[0, 0] = 5.0
    rc = rls_update(s.arrays, box, ridge, np.array([1.0]), 3.0)
    assert rc == 1
    assert s.meta[1] == 1  # the fresh window holds the new sample
    assert s.buf_y[s.meta[0]] == 3.0


@pytest.mark.parametrize("switching", [False, True])
def test_excitation_off_skips_only_the_excitation_index(switching: bool) -> None:
    rng = np.random.default_rng(3)
    n = 400
    t = np.arange(n) * 4e-4
    acc = 800.0 * np.sin(2 * np.pi * 3 * t) + rng.normal(0, 5, n)
    vel = 40.0 * np.cos(2 * np.pi * 3 * t)
    sgn = np.sign(vel)
    ts = 2.8e-4 * acc + 2e-3 * vel + 0.15 * sgn
    ident = LoadIdentifier(IdentifierParams(), switching=switching)
    s0 = ident.initial_state(2.0e-4, 1e-3, 0.1)
    sa, a = ident.step(s0, ts, acc, vel, sgn, vel)
    sb, b = ident.step(s0, ts, acc, vel, sgn, vel, excitation=False)
    assert np.array_equal(a.theta, b.theta) and np.array_equal(a.mode, b.mode)
    assert np.array_equal(sa.rls4.P, sb.rls4.P) and a.cov_trace == b.cov_trace
    assert a.excitation_index == excitation_index(sa.rls4) > 0.0
    assert np.isnan(b.excitation_index)
