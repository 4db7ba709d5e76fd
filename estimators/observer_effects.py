r"""Identified plant effects as terms of the cutting force observer (seed000 (2)-(4)).

The residual analysis of a two-inertia log (:mod:`estimators.residual.two_inertia`)
finds effects the nominal observer lacks; this module puts them *into* the observer, so
the offline report and the live observers use the same terms. Each effect is a basis of
functions of the measured signals, filtered by the observer's own Q(s), times fitted
coefficients, on one side of the observer's model:

=========== ================================= =============================================
side        families                          where the term acts
=========== ================================= =============================================
load        offset, coulomb_asymmetry,        seed000 (2): subtracted from the force estimate,
            stribeck, position_periodic,      like :math:`Q\{J_L s\omega_L + B_L\omega_L +
            inertia, viscous, harmonic, drift F_{CL}\mathrm{sgn}\,\omega_L\}`
motor       torque_ripple, delay              seed000 (3): added to :math:`\hat T_{sM}`
                                              (a torque the motor model lacks)
shaft       backlash                          seed000 (4): subtracted from :math:`\hat T_{sK}`
                                              (a twist :math:`K\Delta\theta` that carries
                                              no torque inside the gap)
=========== ================================= =============================================

Because the two torsion estimates are mixed by :math:`\alpha_M` (seed000 (5)), a motor-side
term changes the force estimate by :math:`\alpha_M Q\{m\}` and a shaft-side term by
:math:`-(1-\alpha_M) Q\{b\}`. The *residual signature* of an effect (what the analysis
fits) is therefore, in the force residual :math:`r_F = \hat F - Q F_{ref}` and in the
twist disagreement :math:`r_S = \hat T_{sK} - \hat T_{sM}`:

======= ====================== ==================
side    :math:`r_F` column     :math:`r_S` column
======= ====================== ==================
load    :math:`Q g`            0
motor   :math:`-\alpha_M Q m`  :math:`Q m`
shaft   :math:`(1-\alpha_M)Qb` :math:`Q b`
======= ====================== ==================

and the corrected observer subtracts the fitted signature. All signals refer to
:math:`t_{k-1}` at sample k, like :class:`estimators.force_observer.TorsionEstimator`.

Basis functions (:math:`\omega, a` the central-difference load velocity and acceleration,
:math:`\Delta\theta = \theta_M - \theta_L`):

================== ===============================================================
offset             1
coulomb_asymmetry  :math:`1[\omega_L>0]`, :math:`1[\omega_L<0]` (friction per direction)
stribeck           :math:`\mathrm{sgn}(\omega_L)\,e^{-(\omega_L/v_s)^2}`, averaged over
                   the sample (:func:`stribeck_basis`)
position_periodic  :math:`\cos, \sin(2\pi k\theta_L/P)`, k = 1, 2 (load angle)
torque_ripple      :math:`\cos, \sin(2\pi k\theta_M/P)`, k = 1, 2 (motor angle)
backlash           :math:`\Delta\theta - \mathrm{dz}(\Delta\theta)`, dz the dead zone of
                   total width ``gap`` (coefficient: the stiffness)
inertia            :math:`a_L`
viscous            :math:`\omega_L`
harmonic           :math:`\cos, \sin(2\pi f t)`
drift              :math:`(t - t_0)/T`
delay              :math:`\tau(t - d) - \tau(t)` (the torque acts late by d; gain 1 =
                   the whole torque late), :math:`\tau` the observer's motor torque
================== ===============================================================
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from common.arrays import F64
from estimators.errors import ParameterError, require_positive
from estimators.filters import DiscreteFilter, lowpass

#: side of the observer's model each family acts on
SIDES: dict[str, str] = {
    "offset": "load",
    "coulomb_asymmetry": "load",
    "stribeck": "load",
    "position_periodic": "load",
    "inertia": "load",
    "viscous": "load",
    "harmonic": "load",
    "drift": "load",
    "torque_ripple": "motor",
    "delay": "motor",
    "backlash": "shaft",
}
#: coefficient names per family (one per basis column)
COLUMNS: dict[str, tuple[str, ...]] = {
    "offset": ("offset",),
    "coulomb_asymmetry": ("F_pos", "F_neg"),
    "stribeck": ("F_s",),
    "position_periodic": ("c1", "s1", "c2", "s2"),
    "torque_ripple": ("c1", "s1", "c2", "s2"),
    "backlash": ("K",),
    "inertia": ("J",),
    "viscous": ("B",),
    "harmonic": ("c", "s"),
    "drift": ("slope",),
    "delay": ("gain",),
}
#: shape parameters each family needs
SHAPES: dict[str, tuple[str, ...]] = {
    "stribeck": ("v_s",),
    "position_periodic": ("period",),
    "torque_ripple": ("period",),
    "backlash": ("gap",),
    "harmonic": ("frequency",),
    "drift": ("t0", "span"),
    "delay": ("delay_s",),
}


@dataclass(frozen=True)
class ObserverEffect:
    """One identified effect: family, shape parameters and fitted coefficients.

    Parameters
    ----------
    name : str
        Family (a key of :data:`SIDES`).
    shape : mapping of str to float
        Shape parameters (:data:`SHAPES`), e.g. ``{"period": 1.2566}``.
    coef : tuple of float
        One coefficient per basis column (:data:`COLUMNS`), in the residual's unit.
    """

    name: str
    shape: Mapping[str, float] = field(default_factory=dict)
    coef: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if self.name not in SIDES:
            raise ParameterError("name", f"one of {', '.join(SIDES)}", self.name)
        for key in SHAPES.get(self.name, ()):
            v = self.shape.get(key)
            if v is None or not math.isfinite(float(v)):
                raise ParameterError(f"{self.name}.{key}", "a finite shape parameter", v)
        for key in ("v_s", "period", "gap", "span", "delay_s"):
            if key in SHAPES.get(self.name, ()):
                require_positive(f"{self.name}.{key}", float(self.shape[key]))
        n = len(COLUMNS[self.name])
        if self.coef and len(self.coef) != n:
            raise ParameterError(f"{self.name}.coef", f"{n} coefficients", len(self.coef))

    @property
    def side(self) -> str:
        return SIDES[self.name]


@dataclass(frozen=True)
class ObserverKinematics:
    """Signals at :math:`t_{k-1}` for sample k (central differences, like the observer)."""

    t: F64
    q_m: F64
    q_l: F64
    w_l: F64
    a_l: F64
    # motor torque as the observer uses it (mean over the two ZOH intervals around
    # t[k-1]), preceded by n_hist earlier values (for the delay family)
    tau_ext: F64 = field(default_factory=lambda: np.zeros(0))
    n_hist: int = 0
    sample_time: float = 0.0


def kinematics(
    t: F64,
    q_m: F64,
    q_l: F64,
    sample_time: float,
    prev: F64 | None = None,
    tau: F64 | None = None,
    tau_hist: F64 | None = None,
) -> tuple[ObserverKinematics, F64]:
    """Aligned signals of one block; ``prev`` = [q_m[k-1], q_m[k-2], q_l[k-1], q_l[k-2],
    seen] carries the history between blocks (None: start of a record). With ``tau``,
    ``tau_hist`` (>= 3 raw torques before the block, oldest first; None at the start of a
    record: the first torque held) gives the torque history of the delay family."""
    qm = np.asarray(q_m, dtype=np.float64)
    ql = np.asarray(q_l, dtype=np.float64)
    n = len(qm)
    if prev is None or prev[4] == 0.0:
        hist_m = np.array([qm[0], qm[0]]) if n else np.zeros(2)
        hist_l = np.array([ql[0], ql[0]]) if n else np.zeros(2)
    else:
        hist_m = np.array([prev[1], prev[0]])
        hist_l = np.array([prev[3], prev[2]])
    em = np.concatenate([hist_m, qm])  # em[k + 2] = q_m[k]
    el = np.concatenate([hist_l, ql])
    ts = sample_time
    # as in force_observer._torsion_kernel: the estimate at sample k refers to t[k-1]
    w_l = (el[2:] - el[:-2]) / (2.0 * ts)
    a_l = (el[2:] - 2.0 * el[1:-1] + el[:-2]) / (ts * ts)
    new_prev = np.array([em[-1], em[-2], el[-1], el[-2], 1.0])
    tau_ext = np.zeros(0)
    n_hist = 0
    if tau is not None:
        ta = np.asarray(tau, dtype=np.float64)
        hist = np.full(3, ta[0] if len(ta) else 0.0) if tau_hist is None else tau_hist
        ext = np.concatenate([hist, ta])
        # as in the observer kernel: the torque at t[k-1] is 0.5 (tau[k-1] + tau[k-2])
        tau_ext = 0.5 * (ext[1:-1] + ext[:-2])
        n_hist = len(hist) - 2
    kin = ObserverKinematics(
        t=np.asarray(t, dtype=np.float64) - ts,
        q_m=em[1:-1],
        q_l=el[1:-1],
        w_l=w_l,
        a_l=a_l,
        tau_ext=tau_ext,
        n_hist=n_hist,
        sample_time=ts,
    )
    return kin, new_prev


def raw_basis(name: str, shape: Mapping[str, float], kin: ObserverKinematics) -> F64:
    """Unfiltered basis columns of family ``name`` (shape ``(n, len(COLUMNS[name]))``)."""
    w = kin.w_l
    n = len(w)
    if name == "offset":
        return np.ones((n, 1))
    if name == "coulomb_asymmetry":
        return np.column_stack([(w > 0).astype(np.float64), -(w < 0).astype(np.float64)])
    if name == "stribeck":
        return stribeck_basis(w, kin.a_l, kin.sample_time, shape["v_s"])[:, None]
    if name in ("position_periodic", "torque_ripple"):
        q = kin.q_l if name == "position_periodic" else kin.q_m
        ph = 2.0 * np.pi * q / shape["period"]
        return np.column_stack([np.cos(ph), np.sin(ph), np.cos(2 * ph), np.sin(2 * ph)])
    if name == "backlash":
        dth = kin.q_m - kin.q_l
        half = 0.5 * shape["gap"]
        # twist minus its dead zone: +-gap/2 outside the gap, the twist itself inside
        return np.clip(dth, -half, half)[:, None]
    if name == "inertia":
        return kin.a_l[:, None].copy()
    if name == "viscous":
        return w[:, None].copy()
    if name == "harmonic":
        ph = 2.0 * np.pi * shape["frequency"] * kin.t
        return np.column_stack([np.cos(ph), np.sin(ph)])
    if name == "drift":
        return ((kin.t - shape["t0"]) / shape["span"])[:, None]
    if name == "delay":
        lag = shape["delay_s"] / kin.sample_time if kin.sample_time > 0 else math.inf
        if len(kin.tau_ext) != n + kin.n_hist or lag > kin.n_hist:
            raise ParameterError(
                "delay", f"a torque history of at least {lag:.3g} samples", kin.n_hist
            )
        now = np.arange(n) + float(kin.n_hist)
        past = np.interp(now - lag, np.arange(len(kin.tau_ext)), kin.tau_ext)
        # the torque acts late by delay_s: the motor model lacks tau(t - d) - tau(t)
        return (past - kin.tau_ext[kin.n_hist :])[:, None]
    raise ParameterError("name", f"one of {', '.join(SIDES)}", name)


#: points of the sub-sample average of the Stribeck basis
_STRIBECK_POINTS = 8


def stribeck_basis(w: F64, a: F64, sample_time: float, v_s: float) -> F64:
    r"""Stribeck basis averaged over the sample: the velocity runs linearly from the
    previous interval's mean :math:`u_- = \omega - a T/2` to the next one's
    :math:`u_+ = \omega + a T/2` (the two encoder differences around :math:`t_{k-1}`),
    and :math:`\mathrm{sgn}(u)e^{-(u/v_s)^2}` is averaged along it.

    Choice: a load that vibrates through zero speed (the simulator's 100/200 Hz cutting
    force at rest or at a slow plateau) crosses the Stribeck band within a sample; the
    value at the sample's mean velocity misses or doubles those crossings, and the
    cross-validation found such a term wrong on some speed plateaus. Without vibration
    (``a T`` small against ``v_s``) it equals the sampled basis.
    """
    if sample_time <= 0.0:
        return np.asarray(np.sign(w) * np.exp(-((w / v_s) ** 2)), dtype=np.float64)
    half = 0.5 * a * sample_time
    out = np.zeros(len(w))
    for i in range(_STRIBECK_POINTS):
        f = (i + 0.5) / _STRIBECK_POINTS
        u = w - half + 2.0 * half * f
        out += np.sign(u) * np.exp(-((u / v_s) ** 2))
    return out / _STRIBECK_POINTS


def filter_columns(q: DiscreteFilter, x: F64, z: F64 | None = None) -> tuple[F64, F64]:
    """Q(s) on every column of ``x``; ``z`` (columns x order) carries the filter states."""
    out = np.empty_like(x)
    zz = np.zeros((x.shape[1], max(q.order, 1))) if z is None else z.copy()
    for j in range(x.shape[1]):
        out[:, j], zz[j] = q.run(x[:, j], zz[j])
    return out, zz


def signature(side: str, qcols: F64, alpha: F64) -> tuple[F64, F64]:
    """Columns of an effect in the force residual and in the twist disagreement.

    ``qcols`` are the Q-filtered basis columns; ``alpha`` the mixing ratio of seed000 (5).
    """
    zero = np.zeros_like(qcols)
    if side == "load":
        return qcols, zero
    a = np.asarray(alpha, dtype=np.float64)[:, None]
    if side == "motor":
        # seed000 (3) lacks +m: T_sM is low by Q m; seed000 (5) passes alpha of it to the force
        return -a * qcols, qcols
    # shaft, seed000 (4): K*dtheta overstates the torque by Q b; (1 - alpha) of it reaches F
    return (1.0 - a) * qcols, qcols


@dataclass(frozen=True)
class EffectsParams:
    """The effects of an observer and its Q(s) design (same as the observer's)."""

    effects: tuple[ObserverEffect, ...]
    sample_time: float
    q_hz: float = 250.0
    q_order: int = 1

    def __post_init__(self) -> None:
        require_positive("sample_time", self.sample_time)
        for e in self.effects:
            if len(e.coef) != len(COLUMNS[e.name]):
                raise ParameterError(
                    f"{e.name}.coef", f"{len(COLUMNS[e.name])} fitted coefficients", len(e.coef)
                )


@dataclass
class EffectsState:
    """History of the angles (alignment) and the Q(s) states of every basis column."""

    prev: F64
    z: F64
    tau_hist: F64 = field(default_factory=lambda: np.zeros(0))


@dataclass
class EffectsRecord:
    """Per-sample terms of the corrected observer (all at :math:`t_{k-1}`).

    ``f_corr`` is subtracted from seed000 (2)'s force; ``t_sm_add`` is added to
    :math:`\\hat T_{sM}` (seed000 (3)); ``t_sk_sub`` subtracted from
    :math:`\\hat T_{sK}` (seed000 (4)).
    """

    f_corr: F64
    t_sm_add: F64
    t_sk_sub: F64


class ObserverEffects:
    """Identified effects inside the observer; call :meth:`step` once per block.

    Examples
    --------
    >>> fx = ObserverEffects(EffectsParams((ObserverEffect("offset", {}, (0.3,)),), 4e-4))
    >>> s = fx.initial_state()
    >>> # per block, after TorsionEstimator.step:
    >>> # s, er = fx.step(s, rec.alpha, t, q_m, q_l); force = cutting_force(...) - er.f_corr
    """

    def __init__(self, params: EffectsParams) -> None:
        self.params = params
        self.q = lowpass(params.q_hz, params.sample_time, params.q_order)
        self._ncols = sum(len(COLUMNS[e.name]) for e in params.effects)
        lags = [
            e.shape["delay_s"] / params.sample_time for e in params.effects if e.name == "delay"
        ]
        self._hist = int(math.ceil(max(lags))) + 3 if lags else 0

    def initial_state(self) -> EffectsState:
        return EffectsState(
            prev=np.zeros(5),
            z=np.zeros((self._ncols, max(self.q.order, 1))),
            tau_hist=np.zeros(0),
        )

    def step(
        self,
        state: EffectsState,
        alpha: F64,
        t: F64,
        q_m: F64,
        q_l: F64,
        tau_m: F64 | None = None,
    ) -> tuple[EffectsState, EffectsRecord]:
        """Terms of one block (``alpha`` from the block's :class:`TorsionRecord`;
        ``tau_m``, the block's motor torque, is needed by a ``delay`` effect)."""
        n = len(t)
        if self._hist and (tau_m is None or len(tau_m) != n):
            raise ParameterError("tau_m", f"the block's {n} motor torques (delay effect)", None)
        if not (len(alpha) == len(q_m) == len(q_l) == n):
            raise ParameterError(
                "block", "alpha, t, q_m, q_l of equal length", (len(alpha), n, len(q_m), len(q_l))
            )
        hist = None
        if self._hist and state.prev[4] != 0.0:
            hist = state.tau_hist
        elif self._hist and tau_m is not None and n:
            hist = np.full(self._hist, float(tau_m[0]))
        kin, prev = kinematics(
            t, q_m, q_l, self.params.sample_time, state.prev, tau_m if self._hist else None, hist
        )
        new_hist = np.zeros(0)
        if self._hist and tau_m is not None and hist is not None:
            new_hist = np.concatenate([hist, np.asarray(tau_m, dtype=np.float64)])[-self._hist :]
        f = np.zeros(n)
        tsm = np.zeros(n)
        tsk = np.zeros(n)
        z = state.z.copy()
        j = 0
        a = np.asarray(alpha, dtype=np.float64)
        for e in self.params.effects:
            k = len(COLUMNS[e.name])
            qc, z[j : j + k] = filter_columns(self.q, raw_basis(e.name, e.shape, kin), z[j : j + k])
            j += k
            term = qc @ np.asarray(e.coef)
            if e.side == "load":
                f += term
            elif e.side == "motor":
                tsm += term
                f -= a * term
            else:
                tsk += term
                f += (1.0 - a) * term
        return EffectsState(prev=prev, z=z, tau_hist=new_hist), EffectsRecord(f, tsm, tsk)
