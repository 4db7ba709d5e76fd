r"""The motor side of a two-inertia feed axis identified live: its mass, friction and the
drive train's stiffness, from the motor encoder, the linear scale and the effort.

Seed 000's two-inertia stage (its eq. (1)) seen from the motor: the motor-side mass
:math:`M_M` driven by the effort :math:`\tau` against the spring force of the drive
train (ball screw, nut, bearings, coupling) :math:`K(q_M - q_L)` and its own friction,

.. math:: \tau = M_M\ddot q_M + K\,(q_M - q_L) + B_M\dot q_M + F_{CM}\,\mathrm{sgn}\,\dot q_M
          + \tau_{off}.

Everything is measured but the five coefficients, and the process force does not enter
(it acts on the load, beyond the spring): the regression holds in the cut as in the air,
and a cut, which twists the spring by a force the other columns do not hold, is what
separates :math:`K` from the load's inertia best. A machine's CNC hands out no such
parameters; a two-inertia axis with a linear scale gives them. The load side
(:math:`M_L, B_L, F_{CL}` in :math:`K(q_M-q_L) = M_L\ddot q_L + B_L\dot q_L + F_{CL}
\mathrm{sgn}\,\dot q_L + F`) is :class:`estimators.rigid_id.RigidIdentifier` on the scale
with the twist force as its effort, learnt in the air.

As :mod:`estimators.rigid_id`: velocities and accelerations are central differences
(referred to the previous sample), every column and the effort go through the same
causal low-pass :math:`(\omega_c/(s+\omega_c))^4` (the regression holds exactly between
the filtered signals), rows enter while the motor moves (above ``moving_rel`` of its
fastest speed), exponentially weighted over ``memory_s`` of motion. The estimate is the
weighted least-squares solution, with its plain least-squares standard deviations
(indicative: the rows are correlated).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter, lfilter_zi

from common.arrays import F64
from estimators.errors import ParameterError, require_positive
from estimators.filters import lowpass

#: the coefficients, in column order
NAMES: tuple[str, ...] = ("M_M", "K", "B_M", "F_CM", "offset")


@dataclass(frozen=True)
class TwistIdParams:
    """Design of the motor side's identifier (module docstring)."""

    sample_time: float
    filter_hz: float = 50.0
    filter_order: int = 4
    memory_s: float = 10.0
    moving_rel: float = 0.02
    settle_s: float = 0.1
    min_rows: int = 200

    def __post_init__(self) -> None:
        ts = require_positive("sample_time", self.sample_time)
        if not 0 < self.filter_hz < 0.5 / ts:
            raise ParameterError("filter_hz", f"a cut-off in (0, {0.5 / ts:g}) Hz", self.filter_hz)
        for name in ("memory_s", "moving_rel"):
            require_positive(name, getattr(self, name))


@dataclass
class TwistIdState:
    """Explicit state: the filters (the 4 columns and the effort), the last two samples of
    each position and of the effort, the information matrix and its right-hand side, the
    estimate, the fastest speed seen, the samples seen."""

    z: F64  # (order, 5)
    prev: F64  # q_m[k-1], q_m[k-2], q_l[k-1], q_l[k-2], tau[k-1]
    G: F64
    b: F64
    theta: F64
    sd: F64
    s2: float = 0.0
    vmax: float = 0.0
    seen: int = 0
    rows: float = 0.0


class TwistIdentifier:
    """The motor side's live identifier (module docstring)."""

    def __init__(self, params: TwistIdParams) -> None:
        self.params = params
        self.filter = lowpass(params.filter_hz, params.sample_time, params.filter_order)
        self.lam = math.exp(-params.sample_time / params.memory_s)

    def initial_state(self) -> TwistIdState:
        p = len(NAMES)
        nz = len(self.filter.a) - 1
        return TwistIdState(
            z=np.zeros((nz, 5)),
            prev=np.zeros(5),
            G=np.zeros((p, p)),
            b=np.zeros(p),
            theta=np.full(p, math.nan),
            sd=np.full(p, math.nan),
        )

    def restart_filters(self, state: TwistIdState) -> TwistIdState:
        """After a break in the data: the filters start again, the estimate is kept."""
        fresh = self.initial_state()
        fresh.G, fresh.b, fresh.theta, fresh.sd = state.G, state.b, state.theta, state.sd
        fresh.s2, fresh.vmax, fresh.rows = state.s2, state.vmax, state.rows
        return fresh

    def step(self, state: TwistIdState, q_m: F64, q_l: F64, tau: F64) -> TwistIdState:
        """One block of samples: the motor encoder, the scale [m] and the effort [N]."""
        pr = self.params
        ts = pr.sample_time
        qm = np.asarray(q_m, dtype=np.float64)
        ql = np.asarray(q_l, dtype=np.float64)
        tu = np.asarray(tau, dtype=np.float64)
        n = len(qm)
        if not (len(ql) == len(tu) == n):
            raise ParameterError("q_l/tau", f"{n} samples (as q_m)", (len(ql), len(tu)))
        st = TwistIdState(state.z.copy(), state.prev.copy(), state.G.copy(), state.b.copy(),
                          state.theta.copy(), state.sd.copy(), state.s2, state.vmax,
                          state.seen, state.rows)  # fmt: skip
        if n == 0:
            return st
        if st.seen == 0:
            st.prev[:] = (qm[0], qm[0], ql[0], ql[0], tu[0])
        qm2 = np.concatenate([st.prev[[1, 0]], qm])
        ql2 = np.concatenate([st.prev[[3, 2]], ql])
        t1 = np.concatenate([st.prev[[4]], tu])[:-1]  # the effort at k-1
        # central differences at k-1
        v = (qm2[2:] - qm2[:-2]) / (2.0 * ts)
        acc = (qm2[2:] - 2.0 * qm2[1:-1] + qm2[:-2]) / (ts * ts)
        twist = qm2[1:-1] - ql2[1:-1]
        raw = np.column_stack([acc, twist, v, np.sign(v), t1])
        if st.seen == 0:  # the filters start in the steady state of the first sample
            st.z = np.outer(lfilter_zi(self.filter.b, self.filter.a), raw[0])
        filt, st.z = lfilter(self.filter.b, self.filter.a, raw, axis=0, zi=st.z)
        st.prev[:] = (qm[-1], qm2[-2], ql[-1], ql2[-2], tu[-1])
        k = st.seen + np.arange(n)
        st.seen += n
        vf = filt[:, 2]
        st.vmax = max(st.vmax, float(np.max(np.abs(vf))))
        use = (np.abs(vf) > pr.moving_rel * st.vmax) & (k * ts >= pr.settle_s)
        use &= np.all(np.isfinite(filt), axis=1)
        if not use.any():
            return st
        x = np.column_stack([filt[use, :4], np.ones(int(use.sum()))])
        y = filt[use, 4]
        m = len(y)
        w = self.lam ** np.arange(m - 1, -1, -1, dtype=np.float64)
        st.G = self.lam**m * st.G + (x * w[:, None]).T @ x
        st.b = self.lam**m * st.b + (x * w[:, None]).T @ y
        st.rows += m
        if st.rows < pr.min_rows:
            return st
        try:
            d = np.sqrt(np.diag(st.G))
            d[d == 0] = 1.0
            A = st.G / np.outer(d, d)
            th = np.linalg.solve(A, st.b / d) / d
            e = y - x @ th
            s2 = float(np.sum(w * e * e) / np.sum(w))
            cov = np.linalg.inv(A) / np.outer(d, d) * s2  # plain least squares: s^2 G^-1
            st.theta, st.s2 = th, s2
            st.sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        except np.linalg.LinAlgError:
            pass
        return st


def mode_hz(K: float, m_motor: float, m_load: float) -> float:
    """The two-inertia axis' first axial mode [Hz]: sqrt(K (1/M_M + 1/M_L)) / 2 pi."""
    if not (K > 0 and m_motor > 0 and m_load > 0):
        return math.nan
    return math.sqrt(K * (1.0 / m_motor + 1.0 / m_load)) / (2.0 * math.pi)


__all__ = ["NAMES", "TwistIdParams", "TwistIdState", "TwistIdentifier", "mode_hz"]
