r"""Cutting force observer on a robust torsional-torque estimate (seed000 (1)-(8)).

The observer runs in two parts:

1. :class:`TorsionEstimator` — the front end, shared by every observer variant. From the
   motor torque and the two encoders it forms the motor-side disturbance-observer
   estimate :math:`\hat T_{sM}` (seed000 (3)), the shaft-twist estimate :math:`\hat T_{sK}`
   (seed000 (4)), mixes them with the minimum-variance ratio :math:`\alpha_M` (seed000 (5)-(8)) into
   :math:`\hat T_s`, and filters the load-side signals through Q(s).
2. :func:`cutting_force` — seed000 (2) with a given (possibly time-varying) set of load-side
   parameters. Because Q(s) is linear, :math:`Q\{J_L s\omega_L + B_L\omega_L + F_{CL}
   \mathrm{sgn}\,\omega_L\} = J_L\,Q s\omega_L + B_L\,Q\omega_L + F_{CL}\,Q\,\mathrm{sgn}
   \,\omega_L` for constant parameters; we apply the parameters after the filter, so the
   fixed, adaptive and switching observers share one front end and an updated parameter
   acts at once (no filter transient).

Velocities and accelerations are central differences of the quantised encoder angles,
so every estimate refers to the previous sample time (one sample, 0.4 ms, of lag).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit

from common.arrays import F64
from estimators.errors import ParameterError, require_nonnegative, require_positive
from estimators.filters import DiscreteFilter, df2t_step, lowpass


@dataclass(frozen=True)
class ObserverParams:
    """Nominal motor-side and shaft parameters of the observer, and its design values.

    ``err3_*`` are the modelling errors at the +-3 sigma interval as fractions of the
    nominal value (seed 000 IV.A: J_M 5 %, B_M 50 %, K 30 %, F_CM 50 %); seed 001 uses
    quantisation noise only (all zero).
    """

    J_M: float
    B_M: float
    F_CM: float
    K: float
    sample_time: float = 4e-4
    encoder_resolution: float = 2 * math.pi / 2**20
    # Q(s) cut-off; nan: designed from the rate, q_cutoff (seed 000 Table II: 250 Hz at
    # 2.5 kHz)
    q_hz: float = math.nan
    q_order: int = 1  # seed 000 III.A: "Q(s) is a first-order LPF"
    err3_J_M: float = 0.05
    err3_B_M: float = 0.5
    err3_K: float = 0.3
    err3_F_CM: float = 0.5
    # "minimum_variance": seed000 (5)'s mix of the motor-side DOB and the shaft twist;
    # "twist": the load-side relation only (T_s = K dtheta, alpha = 0), for a rate whose
    # Nyquist frequency lies below the torsion (observer_design)
    mix: str = "minimum_variance"

    def __post_init__(self) -> None:
        for n in ("J_M", "K", "sample_time", "encoder_resolution"):
            require_positive(n, getattr(self, n))
        for n in ("B_M", "F_CM", "err3_J_M", "err3_B_M", "err3_K", "err3_F_CM"):
            require_nonnegative(n, getattr(self, n))
        if math.isnan(self.q_hz):
            object.__setattr__(self, "q_hz", q_cutoff(self.sample_time))
        if self.mix not in ("minimum_variance", "twist"):
            raise ParameterError("mix", "'minimum_variance' or 'twist'", self.mix)
        nyq = 0.5 / self.sample_time
        if not (0 < self.q_hz < nyq) or not math.isfinite(self.q_hz):
            raise ParameterError("q_hz", f"a cut-off in (0, {nyq:g}) Hz (below Nyquist)", self.q_hz)
        if int(self.q_order) != self.q_order or self.q_order < 1:
            raise ParameterError("q_order", "an integer >= 1", self.q_order)


#: Q(s)'s cut-off at and above 625 Hz (seed 000 Table II, at 2.5 kHz) [Hz]
Q_HZ = 250.0


def q_cutoff(sample_time: float) -> float:
    """Q(s)'s cut-off for a rate: seed 000's 250 Hz, at most 0.4 of the rate (0.8 of the
    Nyquist frequency, where the Tustin pre-warp still maps it)."""
    return min(Q_HZ, 0.4 / require_positive("sample_time", sample_time))


def torsion_frequencies(J_M: float, J_L: float, K: float) -> tuple[float, float]:
    r"""The two-inertia stage's resonance and anti-resonance [Hz]:
    :math:`\sqrt{K (1/J_M + 1/J_L)}/2\pi` and :math:`\sqrt{K/J_L}/2\pi`."""
    return (
        math.sqrt(K * (1.0 / J_M + 1.0 / J_L)) / (2 * math.pi),
        math.sqrt(K / J_L) / (2 * math.pi),
    )


def observer_design(
    J_M: float, J_L: float, K: float, sample_time: float
) -> tuple[dict[str, float | str], str]:
    """The observer's design for a rate, and why it departs from seed 000's (``""``:
    it does not). Q(s) at :func:`q_cutoff`; when the torsion's resonance lies at or above
    the Nyquist frequency, the motor-side observer's acceleration folds the torsion into
    the band (a point sample aliases it, a cycle average only damps it): the load-side
    relation only (``mix="twist"``: the shaft torque from its twist)."""
    f_res, f_anti = torsion_frequencies(J_M, J_L, K)
    nyq = 0.5 / sample_time
    design: dict[str, float | str] = {"q_hz": q_cutoff(sample_time)}
    if f_res < nyq:
        return design, ""
    design["mix"] = "twist"
    return design, (
        f"the torsion ({f_res:.0f} Hz resonance, {f_anti:.0f} Hz anti-resonance) lies above "
        f"the Nyquist frequency {nyq:g} Hz: the motor-side observer is aliased; the "
        "load-side relation (the shaft's twist) only"
    )


@dataclass(frozen=True)
class LoadParams:
    """Load-side parameters of seed000 (1)-(2)."""

    J_L: float
    B_L: float
    F_CL: float

    def __post_init__(self) -> None:
        require_positive("J_L", self.J_L)
        require_nonnegative("B_L", self.B_L)
        require_nonnegative("F_CL", self.F_CL)


@dataclass
class TorsionState:
    """Explicit state of the front end: previous angles and the filter states."""

    prev: F64  # PV_*: angles and torques one and two samples back, samples-seen flag
    z: F64  # filter states, one row per filtered channel


@dataclass
class TorsionRecord:
    """Per-sample outputs of the front end."""

    t_s: F64  # robust torsional torque estimate (seed000 (5) mix) [N m]
    t_sm: F64  # motor-side DOB estimate, seed000 (3)
    t_sk: F64  # shaft-twist estimate, seed000 (4)
    alpha: F64  # mixing ratio alpha_M, seed000 (5)
    acc_l: F64  # Q(s) d omega_L/dt [rad/s^2]
    vel_l: F64  # Q(s) omega_L [rad/s]
    sgn_l: F64  # Q(s) sgn(omega_L)
    omega_l: F64  # raw central-difference load velocity (at t[k-1]) [rad/s]


# channels filtered by Q
_N_CH = 8


# Index of each entry of the kernel's packed design array ``pr`` (TorsionEstimator._pr):
# sample time, nominal motor-side parameters and K, the variances of their errors
# (seed000 (6)-(7)) and of the quantisation (seed000 (8))
PR_TS, PR_J_M, PR_B_M, PR_F_CM, PR_K = 0, 1, 2, 3, 4
PR_VAR_J_M, PR_VAR_B_M, PR_VAR_K, PR_VAR_F_CM = 5, 6, 7, 8
PR_VAR_W, PR_VAR_DW, PR_VAR_Q, PR_MIX = 9, 10, 11, 12
PR_SIZE = 13
# Index of each entry of the kernel's history ``prev`` (TorsionState.prev): the angles and
# torques one and two samples back, and the samples-seen flag
PV_QM1, PV_QM2, PV_QL1, PV_QL2, PV_TAU1, PV_TAU2, PV_SEEN = 0, 1, 2, 3, 4, 5, 6
PV_SIZE = 7


class TorsionOut(NamedTuple):
    """The kernel's per-sample outputs (filled in place): :class:`TorsionRecord`'s fields."""

    t_s: F64
    t_sm: F64
    t_sk: F64
    alpha: F64
    acc_l: F64
    vel_l: F64
    sgn_l: F64
    omega_l: F64


@njit(cache=True)
def _torsion_kernel(tau, qm, ql, prev, z, bq, aq, pr, out):  # pragma: no cover
    """The front end over a block of motor torque ``tau`` and angles ``qm``, ``ql``:
    the history ``prev`` (PV_*) and Q's states ``z`` (numerator ``bq``, denominator
    ``aq``) updated in place; ``pr`` the design (PR_*); ``out`` filled."""
    o_ts, o_tsm, o_tsk, o_al = out.t_s, out.t_sm, out.t_sk, out.alpha
    o_acc, o_vel, o_sgn, o_wl = out.acc_l, out.vel_l, out.sgn_l, out.omega_l
    # prev = [q_m[k-1], q_m[k-2], q_l[k-1], q_l[k-2], tau[k-1], tau[k-2], samples seen]
    ts = pr[PR_TS]
    JM, BM, FCM, K = pr[PR_J_M], pr[PR_B_M], pr[PR_F_CM], pr[PR_K]
    s2J, s2B, s2K, s2F = pr[PR_VAR_J_M], pr[PR_VAR_B_M], pr[PR_VAR_K], pr[PR_VAR_F_CM]
    var_w, var_dw, var_q = pr[PR_VAR_W], pr[PR_VAR_DW], pr[PR_VAR_Q]
    # T_s = alpha T_sM + (1 - alpha) T_sK, alpha = V_K / (V_M + V_K) (seed000 (3)-(8))
    for k in range(len(tau)):
        if prev[PV_SEEN] == 0.0:
            prev[PV_QM1] = prev[PV_QM2] = qm[k]
            prev[PV_QL1] = prev[PV_QL2] = ql[k]
            prev[PV_TAU1] = prev[PV_TAU2] = tau[k]
            prev[PV_SEEN] = 1.0
        # Every signal is aligned at t[k-1]: central differences of the angles, and the
        # torque averaged over the two zero-order-hold intervals around t[k-1] (exact for
        # the second difference of a ZOH-driven rigid body). Backward differences against
        # the current torque would misalign the torque and the acceleration by 1.5
        # samples (0.8 rad of phase at 200 Hz). The estimate therefore refers to t[k-1].
        wm = (qm[k] - prev[PV_QM2]) / (2.0 * ts)
        wl = (ql[k] - prev[PV_QL2]) / (2.0 * ts)
        am = (qm[k] - 2.0 * prev[PV_QM1] + prev[PV_QM2]) / (ts * ts)
        al_ = (ql[k] - 2.0 * prev[PV_QL1] + prev[PV_QL2]) / (ts * ts)
        tq = 0.5 * (prev[PV_TAU1] + prev[PV_TAU2])
        dth = prev[PV_QM1] - prev[PV_QL1]
        prev[PV_QM2] = prev[PV_QM1]
        prev[PV_QM1] = qm[k]
        prev[PV_QL2] = prev[PV_QL1]
        prev[PV_QL1] = ql[k]
        prev[PV_TAU2] = prev[PV_TAU1]
        prev[PV_TAU1] = tau[k]
        sm = 1.0 if wm > 0 else (-1.0 if wm < 0 else 0.0)
        sl = 1.0 if wl > 0 else (-1.0 if wl < 0 else 0.0)
        acc_m = df2t_step(bq, aq, z[0], am)
        acc_l = df2t_step(bq, aq, z[1], al_)
        vel_m = df2t_step(bq, aq, z[2], wm)
        vel_l = df2t_step(bq, aq, z[3], wl)
        sgn_m = df2t_step(bq, aq, z[4], sm)
        sgn_l = df2t_step(bq, aq, z[5], sl)
        tau_f = df2t_step(bq, aq, z[6], tq)
        dth_f = df2t_step(bq, aq, z[7], dth)
        # seed000 (3): motor-side disturbance observer
        tsm = tau_f - JM * acc_m - BM * vel_m - FCM * sgn_m
        # seed000 (4): shaft twist times stiffness
        tsk = K * dth_f
        # seed000 (6): error variance of T_sM (modelling + quantisation), on filtered signals
        v_m = acc_m * acc_m * s2J + vel_m * vel_m * s2B + JM * JM * var_dw + BM * BM * var_w + s2F
        # seed000 (7): error variance of T_sK; both encoders quantised alike (seed000 (8))
        v_k = dth_f * dth_f * s2K + 2.0 * K * K * var_q
        # seed000 (5): minimum-variance mixing ratio (the load-side relation alone: 0)
        al = v_k / (v_m + v_k) if (v_m + v_k) > 0 else 0.5
        if pr[PR_MIX] == 1.0:
            al = 0.0
        o_ts[k] = al * tsm + (1.0 - al) * tsk
        o_tsm[k] = tsm
        o_tsk[k] = tsk
        o_al[k] = al
        o_acc[k] = acc_l
        o_vel[k] = vel_l
        o_sgn[k] = sgn_l
        o_wl[k] = wl


@dataclass
class TorsionEstimator:
    """Front end of the cutting force observer (robust torsional torque, seed 000 Fig. 4)."""

    params: ObserverParams
    q: DiscreteFilter = field(init=False)
    # a field, so that a checkpoint (common.state_io: a dataclass's fields) keeps it
    _pr: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        p = self.params
        self.q = lowpass(p.q_hz, p.sample_time, p.q_order)
        qn = p.encoder_resolution
        ts = p.sample_time
        # seed000 (8): quantisation variance q^2/12; q/ts and q/ts^2 as the equivalent
        # resolutions of omega and d omega/dt (seed 000 III.B)
        pr = np.empty(PR_SIZE)
        pr[PR_TS] = ts
        pr[PR_J_M], pr[PR_B_M], pr[PR_F_CM], pr[PR_K] = p.J_M, p.B_M, p.F_CM, p.K
        pr[PR_VAR_J_M] = (p.err3_J_M * p.J_M / 3) ** 2
        pr[PR_VAR_B_M] = (p.err3_B_M * p.B_M / 3) ** 2
        pr[PR_VAR_K] = (p.err3_K * p.K / 3) ** 2
        pr[PR_VAR_F_CM] = (p.err3_F_CM * p.F_CM / 3) ** 2
        pr[PR_VAR_W] = (qn / ts) ** 2 / 12
        pr[PR_VAR_DW] = (qn / ts**2) ** 2 / 12
        pr[PR_VAR_Q] = qn**2 / 12
        pr[PR_MIX] = 1.0 if p.mix == "twist" else 0.0
        self._pr = pr

    def initial_state(self) -> TorsionState:
        return TorsionState(prev=np.zeros(PV_SIZE), z=np.zeros((_N_CH, max(self.q.order, 1))))

    def step(
        self, state: TorsionState, tau_m: F64, q_m: F64, q_l: F64
    ) -> tuple[TorsionState, TorsionRecord]:
        """Process one block; returns the new state and the per-sample record."""
        tau = np.ascontiguousarray(tau_m, dtype=np.float64)
        qm = np.ascontiguousarray(q_m, dtype=np.float64)
        ql = np.ascontiguousarray(q_l, dtype=np.float64)
        if not (len(tau) == len(qm) == len(ql)):
            raise ParameterError(
                "block", "tau_m, q_m, q_l of equal length", (len(tau), len(qm), len(ql))
            )
        new = TorsionState(prev=state.prev.copy(), z=state.z.copy())
        out = TorsionOut(*(np.empty(len(tau)) for _ in TorsionOut._fields))
        _torsion_kernel(tau, qm, ql, new.prev, new.z, self.q.b, self.q.a, self._pr, out)
        return new, TorsionRecord(**out._asdict())


@njit(cache=True)
def _cutting_force_lagged(
    t_s: F64, acc: F64, vel: F64, sgn: F64, theta0: F64, theta: F64, out: F64
) -> None:  # pragma: no cover
    for k in range(t_s.shape[0]):
        th = theta0 if k == 0 else theta[k - 1]
        # seed 000 (2): F_cut = T_s - (J_L d omega_L/dt + B_L omega_L + F_CL sgn omega_L),
        # J_L, B_L, F_CL as identified up to the previous sample
        out[k] = t_s[k] - (th[0] * acc[k] + th[1] * vel[k] + th[2] * sgn[k])


def cutting_force_lagged(rec: TorsionRecord, theta0: F64, theta: F64) -> F64:
    """Eq. (2) with the parameters the identifier held before each sample.

    The same values as ``cutting_force(rec, *np.vstack([theta0, theta[:-1]])[:, :3].T)``
    (the same operations per sample), without building the shifted parameter arrays.

    Parameters
    ----------
    rec : TorsionRecord
        The front end's record of the block.
    theta0 : (m,) array
        ``J_L, B_L, F_CL, ...`` before the block's first sample.
    theta : (n, m) array
        The identifier's parameters after each sample of the block (m >= 3).
    """
    th0 = np.ascontiguousarray(theta0, dtype=np.float64)
    th = np.ascontiguousarray(theta, dtype=np.float64)
    n = len(rec.t_s)
    if th.ndim != 2 or th.shape[0] != n or th.shape[1] < 3 or th0.shape != th.shape[1:]:
        raise ParameterError(
            "theta0/theta", f"shapes (m,) and ({n}, m) with m >= 3", (th0.shape, th.shape)
        )
    out = np.empty(n)
    _cutting_force_lagged(rec.t_s, rec.acc_l, rec.vel_l, rec.sgn_l, th0, th, out)
    return out


def cutting_force(rec: TorsionRecord, J_L: F64 | float, B_L: F64 | float, F_CL: F64 | float) -> F64:
    r"""seed000 (2): :math:`\hat F_{cut} = \hat T_s - Q\{J_L s\omega_L + B_L\omega_L +
    F_{CL}\mathrm{sgn}\,\omega_L\}` with parameters per sample (or constants)."""
    return np.asarray(
        rec.t_s
        - (
            np.asarray(J_L) * rec.acc_l + np.asarray(B_L) * rec.vel_l + np.asarray(F_CL) * rec.sgn_l
        ),
        dtype=np.float64,
    )
