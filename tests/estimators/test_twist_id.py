"""The motor side of a two-inertia axis identified live (estimators/twist_id.py): a
two-mass axis simulated here with a known stiffness, masses and friction, and its design
checks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common.errors import ParameterError
from estimators.twist_id import NAMES, TwistIdentifier, TwistIdParams, mode_hz

TS = 2e-3
#: motor-side mass [kg], load [kg], stiffness [N/m], motor viscous [N s/m], Coulomb [N]
MM, ML, K, BM, FCM = 1000.0, 350.0, 1.7e8, 300.0, 120.0


def _two_mass(seconds: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A two-mass axis driven by a PD loop on a reciprocating command with a load force
    (a cut) switching on and off, integrated at 20x the sample rate; sampled at TS."""
    rng = np.random.default_rng(seed)
    sub = 20
    h = TS / sub
    n = int(seconds / TS)
    xm = vm = xl = vl = 0.0
    qm, ql, tau = np.empty(n), np.empty(n), np.empty(n)
    c = 2 * 0.05 * math.sqrt(K * MM * ML / (MM + ML))
    f_cut = 0.0
    u = 0.0
    for k in range(n):
        t = k * TS
        ref = 0.05 * math.sin(2 * math.pi * 0.5 * t)
        if k % 250 == 0:
            f_cut = float(rng.uniform(-400.0, 400.0)) if rng.random() < 0.5 else 0.0
        u = 4e6 * (ref - xm) - 8e4 * vm
        for _ in range(sub):
            fs = K * (xm - xl) + c * (vm - vl)
            am = (u - fs - BM * vm - FCM * math.tanh(vm / 1e-4)) / MM
            al = (fs - 800.0 * vl - 150.0 * math.tanh(vl / 1e-4) - f_cut) / ML
            vm += am * h
            xm += vm * h
            vl += al * h
            xl += vl * h
        qm[k], ql[k], tau[k] = xm, xl, u
    return qm, ql, tau


def test_the_motor_side_and_the_stiffness_are_found() -> None:
    qm, ql, tau = _two_mass(30.0, seed=1)
    ident = TwistIdentifier(TwistIdParams(TS))
    st = ident.initial_state()
    for a in range(0, len(qm), 25):
        st = ident.step(st, qm[a : a + 25], ql[a : a + 25], tau[a : a + 25])
    th = dict(zip(NAMES, st.theta, strict=True))
    assert th["K"] == pytest.approx(K, rel=0.03)
    assert th["M_M"] == pytest.approx(MM, rel=0.03)
    assert th["F_CM"] == pytest.approx(FCM, rel=0.15)
    # a restart keeps the estimate and starts the filters again
    again = ident.restart_filters(st)
    np.testing.assert_array_equal(again.theta, st.theta)
    assert again.seen == 0


def test_the_design_is_checked_and_the_mode_follows() -> None:
    with pytest.raises(ParameterError, match="filter_hz"):
        TwistIdParams(TS, filter_hz=300.0)
    with pytest.raises(ParameterError, match="memory_s"):
        TwistIdParams(TS, memory_s=0.0)
    assert mode_hz(1.7e8, 1013.0, 341.0) == pytest.approx(130.0, rel=0.01)
    assert math.isnan(mode_hz(math.nan, 1013.0, 341.0))
