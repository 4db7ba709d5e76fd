"""The reduced wear law's remaining-life predictor (``estimators/wear/law.py``) on its own.

The truth is the reduced law of seed004 (3)-(8) integrated here from its equations (scipy's
``solve_ivp``, tight tolerances), with the low-passed ``z = F / (f d)`` as a fourth state;
the predictor sees per pass the flank wear, ``z`` and the crater's force loss, fits the two
scale factors and integrates forward (its own RK4) to the limit. The constants are seed
004's at its default condition (speed 150 m/min, depth 2 mm, feed 0.1 mm/rev, as
``server/pipeline/wear_clock.wear_law_params`` reads them from ``machine/tool_wear``).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from scipy.integrate import quad, solve_ivp

from estimators.errors import ParameterError
from estimators.wear.law import WearLawParams, WearLawPredictor, w2_table, w_grid

P = WearLawParams(
    feed=0.1,
    depth=2.0,
    tau_abrasive=0.68096,
    kappa0=4.483016292970519e-05,
    k2_0=5241.908049556001,
    activation=12000.0,
    theta0=834.8465904055447,
    theta_per_wear=330.0,
    crater_gain=8.25,
    crater_activation=12000.0,
    crater_theta_per_newton=1.5511588294177048,
)
FORCE_SHARP = 525.4  # N, the sharp tool's force at the condition
S = 996.0  # N per mm of flank wear, K13 d
LIMIT = 0.3  # mm


def _truth(kappa: float, k2: float, p: WearLawParams = P) -> tuple[Any, float]:
    """The reduced law from a sharp tool: the dense solution of (w1, w2, C, z) and the
    time [min] the flank wear w1 + w2 reaches the limit (inf: not within 600 min)."""
    fd = p.feed * p.depth

    def rhs(_t: float, x: np.ndarray) -> list[float]:
        w1, w2, c, z = x
        force = FORCE_SHARP + S * (w1 + w2) - c  # seed004 (8)
        return [
            (-w1 + kappa * force / fd) / p.tau_abrasive,  # (3)
            k2 * math.exp(-p.activation / (p.theta0 + p.theta_per_wear * w2)),  # (4), (6)
            p.crater_gain
            * force
            * math.exp(-p.crater_activation / (273.0 + p.crater_theta_per_newton * force)),
            (-z + force / fd) / p.tau_abrasive,  # the low-passed F / (f d)
        ]

    def worn(_t: float, x: np.ndarray) -> float:
        return float(x[0] + x[1] - LIMIT)

    worn.terminal = True  # type: ignore[attr-defined]
    sol = solve_ivp(
        rhs, (0.0, 600.0), [0.0] * 4, events=worn, dense_output=True, rtol=1e-10, atol=1e-12,
        max_step=0.5,
    )  # fmt: skip
    hits = sol.t_events[0]
    return sol, float(hits[0]) if hits.size else math.inf


def _predict(
    pred: WearLawPredictor, sol: Any, t_now: float, noise: float = 0.0, seed: int = 0, **kw: Any
) -> tuple[float, float, float, float]:
    tm = np.arange(0.5, t_now, 1.0)  # one pass a minute, its mid-time
    x, xn = sol.sol(tm), sol.sol(t_now)
    vb = x[0] + x[1] + noise * np.random.default_rng(seed).standard_normal(tm.size)
    return pred.predict(
        tm, vb, x[3], x[2], t_now=t_now, z_now=float(xn[3]), crater_now=float(xn[2]),
        force_sharp=FORCE_SHARP, force_per_flank_wear=S, vb_limit=LIMIT, **kw,
    )  # fmt: skip


def test_the_w2_table_is_the_integral_of_the_inverse_diffusion_rate() -> None:
    # seed004 (4), (6): tau(w) = int_0^w exp(A / (Theta_0 + c s)) ds
    tau = w2_table(P.activation, P.theta0, P.theta_per_wear)
    w = w_grid()
    assert tau[0] == 0.0 and np.all(np.diff(tau) > 0.0)
    for wi in (0.05, 0.3, 1.0, 2.0):
        want, _ = quad(lambda s: math.exp(P.activation / (P.theta0 + P.theta_per_wear * s)), 0, wi)
        assert float(np.interp(wi, w, tau)) == pytest.approx(want, rel=1e-6)
    # no temperature rise with wear: tau is linear in w
    flat = w2_table(P.activation, P.theta0, 0.0)
    np.testing.assert_allclose(flat, w * math.exp(P.activation / P.theta0), rtol=1e-12)


@pytest.mark.parametrize(
    ("kw", "name"),
    [
        ({"feed": 0.0}, "feed"),
        ({"k2_0": -1.0}, "k2_0"),
        ({"theta_per_wear": math.inf}, "theta_per_wear"),
        ({"crater_gain": -0.1}, "crater_gain"),
        ({"activation_rel_sd": 0.5}, "activation_rel_sd"),
        ({"crater_rel_sd": 1.0}, "crater_rel_sd"),
    ],
)
def test_bad_constants_name_their_field(kw: dict[str, float], name: str) -> None:
    with pytest.raises(ParameterError) as err:
        replace(P, **kw)
    assert err.value.name == name


def test_the_crater_rate_is_seed004_5_7_8_and_none_without_a_crater_law() -> None:
    pred = WearLawPredictor(P)
    f = np.array([400.0, 525.4, 700.0])
    want = (
        P.crater_gain * f * np.exp(-P.crater_activation / (273.0 + P.crater_theta_per_newton * f))
    )
    np.testing.assert_allclose(pred.crater_rate(f), want, rtol=1e-14)
    assert pred.crater_rate(525.4) == pytest.approx(float(want[1]), rel=1e-14)
    none = WearLawPredictor(replace(P, crater_gain=0.0))
    assert none.crater_rate(525.4) == 0.0
    np.testing.assert_array_equal(none.crater_rate(f), np.zeros(3))


@pytest.mark.parametrize("t_now", [10.0, 20.0])
def test_on_noise_free_passes_the_fit_recovers_the_law_and_the_remaining_life(
    t_now: float,
) -> None:
    # the scale factors away from their nominal: kappa 1.2x, k2 0.7x (crossing at 34.1 min)
    sol, t_cross = _truth(1.2 * P.kappa0, 0.7 * P.k2_0)
    pred = WearLawPredictor(P)
    vb_fit, rate, rem, sd = _predict(pred, sol, t_now)
    x = sol.sol(t_now)
    assert vb_fit == pytest.approx(x[0] + x[1], abs=1e-5)
    # the rate is the law's at the fitted state: the truth's slope
    h = 1e-3
    slope = (sum(sol.sol(t_now + h)[:2]) - sum(sol.sol(t_now - h)[:2])) / (2 * h)
    assert rate == pytest.approx(slope, rel=1e-3)
    # measured: 24.124 against 24.120 min at 10 min, 14.124 against 14.120 at 20 min
    assert rem == pytest.approx(t_cross - t_now, rel=1e-3)
    assert math.isfinite(sd) and sd > 0.0
    vb2, rate2, rem2, sd2 = _predict(pred, sol, t_now, with_sd=False)
    assert (vb2, rate2, rem2) == (vb_fit, rate, rem) and math.isnan(sd2)


def test_with_noisy_passes_the_remaining_life_falls_inside_two_sd() -> None:
    # 20 tools: kappa 0.7-1.4x and k2 0.5-1.5x nominal, 3 um of noise on the flank wear
    # from the force, predicted at 60 % of the life. Measured (seeds 0-39): 40 of 40
    # inside 2 S.D. (the model-form part, +-5 % on A and +-50 % on the crater, dominates
    # the S.D.), relative error median 6 %, 90th percentile 18 %, largest 38 %
    inside, errs = 0, []
    pred = WearLawPredictor(P)
    for seed in range(20):
        rng = np.random.default_rng(seed)
        kappa = P.kappa0 * rng.uniform(0.7, 1.4)
        k2 = P.k2_0 * rng.uniform(0.5, 1.5)
        sol, t_cross = _truth(kappa, k2)
        t_now = 0.6 * t_cross
        _, _, rem, sd = _predict(pred, sol, t_now, noise=0.003, seed=1000 + seed)
        true = t_cross - t_now
        inside += abs(rem - true) <= 2.0 * sd
        errs.append(abs(rem - true) / true)
    assert inside >= 19, inside  # a 2-sigma band holds ~95 %
    assert float(np.median(errs)) < 0.15


def test_a_life_beyond_the_horizon_is_reported_as_inf() -> None:
    # diffusion 5x slower than nominal: the limit at 164 min, beyond a 60 min horizon
    sol, t_cross = _truth(P.kappa0, 0.2 * P.k2_0)
    assert 10.0 + 60.0 < t_cross < 600.0
    pred = WearLawPredictor(replace(P, horizon=60.0))
    _, _, rem, sd = _predict(pred, sol, 10.0)
    assert rem == math.inf and sd == math.inf
    # and with the default 600 min horizon, a finite life
    _, _, rem600, _ = _predict(WearLawPredictor(P), sol, 10.0, with_sd=False)
    assert rem600 == pytest.approx(t_cross - 10.0, rel=1e-3)
