"""The eccentricity loop: milling machine on its feed drives + a tuner, block by block.

:class:`EccentricityLoop` composes :class:`machine.milling.MillingMachine` with either the
extremum seeking controller (:mod:`estimators.esc`, seed 003) or the fast tuner
(:mod:`estimators.fast_tuner`), or neither. The tuner sees one revolution of force and
spindle angle at a time, taken from the dynamometer (the machine's true force) or from
cutting-force observers on the X/Y drives (a callable given by the caller). The modulation
it returns is held for the next revolution.

``step(n)`` advances ``n`` samples in any chunking and returns per-sample arrays, so the
live service can call it with its block length; the reproductions call
:meth:`EccentricityLoop.run_revolutions`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common.arrays import F64
from common.errors import ParameterError
from estimators.esc import EscParams, EscState, ExtremumSeekingController, positive_polar
from estimators.fast_tuner import FastTuner, FastTunerParams, FastTunerState
from estimators.force_observer import LoadParams, TorsionEstimator, TorsionState
from machine.feed_drives import FeedDriveParams
from machine.milling import MillingMachine, MillingParams, MillingRecord

#: A force estimator: takes a machine block record, returns (fx_hat, fy_hat) [N].
ForceSource = Callable[[MillingRecord], tuple[F64, F64]]


@dataclass
class RevolutionLog:
    """One entry per completed revolution (tuner active or not)."""

    t_end: list[float] = field(default_factory=list)
    cost: list[float] = field(default_factory=list)
    cost_true: list[float] = field(default_factory=list)
    a_um: list[float] = field(default_factory=list)
    theta_deg: list[float] = field(default_factory=list)
    a_n_um: list[float] = field(default_factory=list)
    theta_n_deg: list[float] = field(default_factory=list)
    saturated: list[bool] = field(default_factory=list)
    adapting: list[bool] = field(default_factory=list)
    rpm: list[float] = field(default_factory=list)

    def arrays(self) -> dict[str, F64]:
        return {k: np.asarray(v, dtype=np.float64) for k, v in self.__dict__.items()}


class ObserverForceSource:
    """Cutting force of X and Y estimated from the drives' own signals (no dynamometer).

    Runs the cutting force observer of seed 000 (:class:`estimators.force_observer.
    TorsionEstimator` and :func:`~estimators.force_observer.cutting_force`) on each feed
    axis, with the motor current times the force constant as effort and the linear scale
    (quantised to ``resolution``) as position. The axes are rigid, so motor and load
    position are the same signal; the shaft-twist branch (seed003 (4)) then carries no
    information, and a very stiff nominal ``K`` makes the minimum-variance mix (seed003 (5))
    use the motor-side disturbance observer (seed003 (3)) alone. The mass is split evenly
    between the motor and load sides (any split gives the same estimate for a rigid axis).

    Parameters
    ----------
    drives : FeedDriveParams
        The feed drives: the nominal mass, friction and force constant of each axis
        (``MillingMachine.drives.params``, ``ProcessMachine.drives``).
    mass_error : float
        Relative error of the observer's nominal mass (0: exact).
    resolution : float
        Linear-scale resolution [m].
    q_hz : float
        Cut-off of the observer's Q(s).
    current_noise : float
        White noise on the measured motor current [A rms]; needs ``rng``.
    rng : numpy.random.Generator, optional
        Seeded generator for the current noise.
    """

    def __init__(
        self,
        drives: FeedDriveParams,
        *,
        mass_error: float = 0.0,
        resolution: float = 5e-9,
        q_hz: float = 1000.0,
        current_noise: float = 0.0,
        rng: np.random.Generator | None = None,
    ) -> None:
        from estimators.force_observer import ObserverParams

        if not (math.isfinite(current_noise) and current_noise >= 0.0):
            raise ParameterError("current_noise", "a value >= 0 A", current_noise)
        if current_noise > 0.0 and rng is None:
            raise ParameterError("rng", "a seeded numpy Generator when current_noise > 0", rng)
        self.current_noise = float(current_noise)
        self.rng = rng
        dp = drives
        self.resolution = float(resolution)
        self._est: list[TorsionEstimator] = []
        self._state: list[TorsionState] = []
        self._load: list[LoadParams] = []
        self._kf: list[float] = []
        for ax in (dp.x, dp.y):
            m = ax.mass * (1.0 + mass_error)
            op = ObserverParams(
                J_M=0.5 * m,
                B_M=0.0,
                F_CM=0.0,
                K=1e15,
                sample_time=dp.sample_time,
                encoder_resolution=resolution,
                q_hz=q_hz,
                err3_J_M=0.0,
                err3_B_M=0.0,
                err3_K=0.0,
                err3_F_CM=0.0,
            )
            est = TorsionEstimator(op)
            load = LoadParams(J_L=0.5 * m, B_L=ax.viscous, F_CL=ax.coulomb)
            self._est.append(est)
            self._state.append(est.initial_state())
            self._load.append(load)
            self._kf.append(ax.force_constant)

    def __call__(self, rec: MillingRecord) -> tuple[F64, F64]:
        from estimators.force_observer import cutting_force

        out = []
        for i, (cur, pos) in enumerate(((rec.ix, rec.x), (rec.iy, rec.y))):
            q = np.round(pos / self.resolution) * self.resolution
            if self.current_noise > 0.0 and self.rng is not None:
                cur = cur + self.rng.normal(0.0, self.current_noise, cur.size)
            self._state[i], trec = self._est[i].step(self._state[i], cur * self._kf[i], q, q)
            ld = self._load[i]
            out.append(cutting_force(trec, ld.J_L, ld.B_L, ld.F_CL))
        return out[0], out[1]


class AdaptiveObserverForceSource(ObserverForceSource):
    """:class:`ObserverForceSource` whose mass is identified while cutting (seed 000's
    adaptive observer, on the feed drives).

    Each axis runs :class:`estimators.axis_mass.AxisMassIdentifier` on the observer's
    Q-filtered motor force, acceleration and velocity at the spindle order of the
    identification circle, ``N_f + 1/window_revs``; the identified mass replaces the
    nominal one in seed000 (2) from the next sample on (as seed 000 updates J_L). The
    circle itself is a machine input: apply :attr:`excitation` with
    ``MillingMachine.set_excitation`` on the machine that is cut.

    Parameters
    ----------
    machine : MillingMachine
        As for :class:`ObserverForceSource`.
    mass_error : float
        Relative error of the observer's nominal (initial) mass.
    excitation_um : float
        Radius of the commanded identification circle [um].
    window_revs, windows : int
        Revolutions per DFT window; windows in the least-squares window.
    stop_after : int or None
        Switch the circle off once both axes have had this many windows of
        identification (the mass then stays at its last estimate: no excitation, no
        update, seed 000's PE condition); None keeps it on.
    **kw
        ``resolution``, ``q_hz``, ``current_noise``, ``rng`` of :class:`ObserverForceSource`.
    """

    def __init__(
        self,
        machine: MillingMachine,
        *,
        mass_error: float = 0.0,
        excitation_um: float = 1.0,
        window_revs: int = 8,
        windows: int = 5,
        stop_after: int | None = None,
        **kw: Any,
    ) -> None:
        from estimators.axis_mass import (
            AxisMassIdentifier,
            AxisMassParams,
            AxisMassState,
            excitation_order,
        )

        super().__init__(machine.drives.params, mass_error=mass_error, **kw)
        order = excitation_order(machine.milling.n_flutes, window_revs)
        self.excitation = (excitation_um * 1e-6, order)
        self.stop_after = stop_after
        self._excited: MillingMachine | None = None
        dp = machine.drives.params
        self.true_mass = (dp.x.mass, dp.y.mass)
        self._jm = [est.params.J_M for est in self._est]
        self._ident: list[AxisMassIdentifier] = []
        self._ident_state: list[AxisMassState] = []
        f_nu = order * machine.spindle_rpm / 60.0
        for ax, g in zip((dp.x, dp.y), machine.drives.response(f_nu), strict=True):
            m0 = ax.mass * (1.0 + mass_error)
            # PE condition: a quarter of the acceleration the circle gives at this speed
            acc_exp = excitation_um * 1e-6 * abs(g) * (2.0 * math.pi * f_nu) ** 2
            ip = AxisMassParams(
                acc_min=max(0.25 * acc_exp, 1e-6),
                mass0=m0,
                viscous=ax.viscous,
                order=order,
                window_revs=window_revs,
                windows=windows,
                mass_min=0.5 * m0,
                mass_max=2.0 * m0,
            )
            idf = AxisMassIdentifier(ip)
            self._ident.append(idf)
            self._ident_state.append(idf.initial_state())

    def attach(self, machine: MillingMachine) -> None:
        """Put the identification circle on ``machine`` (the one that is cut); it is
        switched off there again after ``stop_after`` windows."""
        machine.set_excitation(*self.excitation)
        self._excited = machine

    def relink(self, machine: MillingMachine) -> None:
        """The machine the circle is on is ``machine`` (after a restore), if attached."""
        if self._excited is not None:
            self._excited = machine

    def restart(self) -> None:
        """Identify again from the current estimate (circle back on if attached)."""
        for i, idf in enumerate(self._ident):
            st = idf.initial_state()
            st.mass = self._ident_state[i].mass
            self._ident_state[i] = st
        if self._excited is not None:
            self._excited.set_excitation(*self.excitation)

    @property
    def identifying(self) -> bool:
        """Whether the circle is on (when attached)."""
        return self._excited is not None and self._excited.excitation[0] > 0.0

    @property
    def masses(self) -> tuple[float, float]:
        """The identified masses (X, Y) in effect [kg]."""
        return self._ident_state[0].mass, self._ident_state[1].mass

    def mass_errors(self) -> tuple[float, float]:
        """Identified / true mass - 1 of (X, Y) (truth, for scoring)."""
        mx, my = self.masses
        return mx / self.true_mass[0] - 1.0, my / self.true_mass[1] - 1.0

    def __call__(self, rec: MillingRecord) -> tuple[F64, F64]:
        from estimators.force_observer import cutting_force

        out = []
        for i, (cur, pos) in enumerate(((rec.ix, rec.x), (rec.iy, rec.y))):
            q = np.round(pos / self.resolution) * self.resolution
            if self.current_noise > 0.0 and self.rng is not None:
                cur = cur + self.rng.normal(0.0, self.current_noise, cur.size)
            self._state[i], trec = self._est[i].step(self._state[i], cur * self._kf[i], q, q)
            # Q tau: the motor-side DOB (seed000 (3), B_M = F_CM = 0) plus J_M Q x''
            q_tau = trec.t_sm + self._jm[i] * trec.acc_l
            self._ident_state[i], irec = self._ident[i].step(
                self._ident_state[i], trec.acc_l, trec.vel_l, q_tau, rec.psi
            )
            ld = self._load[i]
            # seed000 (2) with the identified mass: J_L = m_hat - J_M (the front end has
            # already taken J_M Q x'' off)
            out.append(cutting_force(trec, irec.mass - self._jm[i], ld.B_L, ld.F_CL))
        if (
            self.stop_after is not None
            and self._excited is not None
            and min(st.updates for st in self._ident_state) >= self.stop_after
        ):
            self._excited.set_excitation(0.0, self.excitation[1])
        return out[0], out[1]


#: the per-sample outputs of :meth:`EccentricityLoop.step`, in this order
STEP_KEYS = (
    "t",
    "fx",
    "fy",
    "fx_used",
    "fy_used",
    "x",
    "y",
    "ix",
    "iy",
    "psi",
    "a_m_um",
    "theta_m_deg",
    "cost",
)


@dataclass
class LoopState:
    """Everything an :class:`EccentricityLoop` carries from sample to sample, as a value
    (a checkpoint): the simulated machine (its state, cut, generator), the drives' force
    observers (None: the dynamometer), the tuner's mode, state and modulation, and the
    revolution under way."""

    machine: MillingMachine
    force_source: Any
    tuner: str
    adapt_start_s: float
    esc: EscState
    fast: FastTunerState
    #: a_um, theta_deg, b_um, phi_deg, a_n_um, theta_n_deg
    modulation: tuple[float, float, float, float, float, float]
    saturated: bool
    last_cost: float
    started: bool
    rev_start_t: float
    next_boundary: float
    buf: list[MillingRecord]
    est: list[tuple[F64, F64]]
    log: RevolutionLog


def _joined(parts: list[F64]) -> F64:
    """The chunks of one revolution as one array (the chunk itself when it is one)."""
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


class EccentricityLoop:
    """Milling with eccentricity, feed drives and a tuner closing the loop per revolution.

    Parameters
    ----------
    milling : MillingParams
        The cut (spindle speed, depth, eccentricity, ...).
    tuner : {"esc", "fast", "off"}
        Which tuner adjusts the modulation.
    esc, fast : EscParams, FastTunerParams
        Their parameters.
    cost_axis : {"x", "y"}
        Force component of the ESC cost (seed003 (8)). The fast tuner uses both.
    adapt_start_s : float
        Time at which the tuner starts (before it: no modulation, as in Fig. 3).
    force_source : callable, optional
        Estimated force from the drive signals; default: the dynamometer (true force).
    """

    def __init__(
        self,
        milling: MillingParams | None = None,
        *,
        tuner: str = "esc",
        esc: EscParams | None = None,
        fast: FastTunerParams | None = None,
        cost_axis: str = "x",
        adapt_start_s: float = 1.0,
        force_source: ForceSource | None = None,
        machine: MillingMachine | None = None,
    ) -> None:
        if tuner not in ("esc", "fast", "off"):
            raise ParameterError("tuner", "'esc', 'fast' or 'off'", tuner)
        if cost_axis not in ("x", "y"):
            raise ParameterError("cost_axis", "'x' or 'y'", cost_axis)
        self.machine = machine if machine is not None else MillingMachine(milling)
        self.tuner = tuner
        self.esc = ExtremumSeekingController(esc)
        self.fast = FastTuner(fast)
        self.cost_axis = cost_axis
        self.adapt_start_s = float(adapt_start_s)
        self.force_source = force_source
        #: wall seconds spent in the simulated machine (not in the tuner or the observers)
        self.sim_s = 0.0
        self.reset()

    def reset(self) -> None:
        self.machine.reset()
        self.esc_state = self.esc.initial_state()
        self.fast_state = self.fast.initial_state()
        self.a_um = 0.0
        self.theta_deg = 0.0
        self.a_n_um = 0.0
        self.theta_n_deg = 0.0
        self.b_um = 0.0
        self.phi_deg = 0.0
        self.saturated = False
        self.log = RevolutionLog()
        self._buf: list[MillingRecord] = []
        self._est: list[tuple[F64, F64]] = []
        self._rev_start_t = 0.0
        self._next_boundary = 2.0 * math.pi
        self.last_cost = math.nan
        self._started = False

    @property
    def adapting(self) -> bool:
        return self.tuner != "off" and self.machine.t >= self.adapt_start_s - 1e-12

    def set_spindle_rpm(self, rpm: float) -> None:
        """Change the spindle speed (takes effect at the next sample)."""
        self.machine.set_spindle_rpm(rpm)

    def samples_to_boundary(self) -> int:
        """Samples until the current revolution ends (the tuner updates there)."""
        psi = self.machine.spindle_angle
        w_ts = 2.0 * math.pi * self.machine.spindle_rpm / 60.0 * self.machine.sample_time
        return max(1, math.ceil((self._next_boundary - psi) / w_ts - 1e-9))

    def step(self, n: int) -> dict[str, F64]:
        """Advance ``n`` samples; per-sample arrays of forces, positions and tuner state."""
        return self._advance(n, collect=True)

    def _advance(self, n: int, *, collect: bool) -> dict[str, F64]:
        left = int(n)
        if left <= 0:
            return {}
        # one array for every output row, filled chunk by chunk (a chunk ends at a
        # revolution's end or at the block's end): no per-chunk dicts, no concatenation
        res = np.empty((len(STEP_KEYS), left)) if collect else None
        off = 0
        while left > 0:
            m = self.samples_to_boundary()
            c = min(m, left)
            w0 = time.perf_counter()
            rec = self.machine.step(
                c,
                self.a_um * 1e-6,
                math.radians(self.theta_deg),
                self.b_um * 1e-6,
                math.radians(self.phi_deg),
            )
            self.sim_s += time.perf_counter() - w0
            self.saturated = rec.saturated
            est = self.force_source(rec) if self.force_source is not None else (rec.fx, rec.fy)
            self._buf.append(rec)
            self._est.append(est)
            if res is not None:
                r = res[:, off : off + c]
                for row, v in enumerate(
                    (rec.t, rec.fx, rec.fy, est[0], est[1], rec.x, rec.y, rec.ix, rec.iy, rec.psi)
                ):
                    r[row] = v
                r[10] = self.a_um
                r[11] = self.theta_deg
                r[12] = self.last_cost
            off += c
            left -= c
            if c == m:
                self._end_revolution()
        if res is None:
            return {}
        return dict(zip(STEP_KEYS, res, strict=True))

    def state(self) -> dict[str, float | bool | str]:
        """Latest values for a live display: modulation applied and nominal, cost, tuner
        mode, clamp, and the truth (eccentricity, cancelling modulation) for scoring."""
        a_s, th_s = self.machine.cancelling_modulation()
        an, tn = positive_polar(self.a_n_um, self.theta_n_deg)
        p = self.machine.milling
        mode = self.tuner
        if self.tuner == "esc":
            mode = "esc:frozen" if self.esc_state.frozen else "esc:adapting"
        elif self.tuner == "fast":
            mode = f"fast:{self.fast_state.mode}"
        return {
            "t": self.machine.t,
            "rpm": self.machine.spindle_rpm,
            "adapting": self._started,
            "mode": mode,
            "a_m_um": self.a_um,
            "theta_m_deg": self.theta_deg,
            "b_m_um": self.b_um,
            "phi_m_deg": self.phi_deg,
            "a_n_um": an,
            "theta_n_deg": tn,
            "cost": self.last_cost,
            "saturated": self.saturated,
            "true.eccentricity_um": p.eccentricity * 1e6,
            "true.eccentricity_deg": p.eccentricity_deg,
            "true.cancelling_a_um": a_s * 1e6,
            "true.cancelling_theta_deg": math.degrees(th_s),
        }

    def loop_state(self) -> LoopState:
        """The loop's state (:class:`LoopState`; shares its objects: copy it to keep it)."""
        return LoopState(
            machine=self.machine,
            force_source=self.force_source,
            tuner=self.tuner,
            adapt_start_s=self.adapt_start_s,
            esc=self.esc_state,
            fast=self.fast_state,
            modulation=(self.a_um, self.theta_deg, self.b_um, self.phi_deg, self.a_n_um,
                        self.theta_n_deg),
            saturated=self.saturated,
            last_cost=self.last_cost,
            started=self._started,
            rev_start_t=self._rev_start_t,
            next_boundary=self._next_boundary,
            buf=self._buf,
            est=self._est,
            log=self.log,
        )  # fmt: skip

    def restore_loop(self, st: LoopState) -> None:
        """Continue from a :meth:`loop_state` (taken over, not copied). The adaptive
        observers' identification circle is put back on this machine (a state read from
        a file holds its own copy of the machine it excites)."""
        self.machine = st.machine
        self.force_source = st.force_source
        if isinstance(st.force_source, AdaptiveObserverForceSource):
            st.force_source.relink(self.machine)
        self.tuner, self.adapt_start_s = st.tuner, st.adapt_start_s
        self.esc_state, self.fast_state = st.esc, st.fast
        (self.a_um, self.theta_deg, self.b_um, self.phi_deg, self.a_n_um,
         self.theta_n_deg) = st.modulation  # fmt: skip
        self.saturated, self.last_cost, self._started = st.saturated, st.last_cost, st.started
        self._rev_start_t, self._next_boundary = st.rev_start_t, st.next_boundary
        self._buf, self._est, self.log = st.buf, st.est, st.log

    def run_revolutions(self, n_revs: int) -> None:
        """Advance whole revolutions (the reproduction's driver)."""
        for _ in range(int(n_revs)):
            self._advance(self.samples_to_boundary(), collect=False)

    def _end_revolution(self) -> None:
        buf, est = self._buf, self._est
        psi = _joined([r.psi for r in buf])
        # only what this revolution's update reads (the true force is the one used
        # when the dynamometer is the source; the fast tuner reads both axes)
        ax = 0 if self.cost_axis == "x" else 1
        f_cost = _joined([e[ax] for e in est])
        f_true = f_cost
        if self.force_source is not None:
            f_true = _joined([(r.fx, r.fy)[ax] for r in buf])
        t_end = self.machine.t
        rev_time = t_end - self._rev_start_t
        self._buf = []
        self._est = []
        self._rev_start_t = t_end
        self._next_boundary += 2.0 * math.pi
        from estimators.esc import harmonic_cost

        cost = harmonic_cost(f_cost, psi)
        cost_true = cost if self.force_source is None else harmonic_cost(f_true, psi)
        adapting = self._started
        if adapting and self.tuner == "esc":
            self.esc_state, erec = self.esc.step(self.esc_state, f_cost, psi, rev_time, cost=cost)
            self.a_um, self.theta_deg = erec.a_um, erec.theta_deg
            self.a_n_um, self.theta_n_deg = erec.a_n_um, erec.theta_n_deg
            self.saturated = self.saturated or erec.saturated
        elif adapting and self.tuner == "fast":
            fxy = np.vstack([_joined([e[0] for e in est]), _joined([e[1] for e in est])])
            self.fast_state, frec = self.fast.step(self.fast_state, fxy, psi, rev_time)
            self.a_um, self.theta_deg = frec.a_um, frec.theta_deg
            self.b_um, self.phi_deg = frec.b_um, frec.phi_deg
            self.a_n_um, self.theta_n_deg = frec.a_best_um, frec.theta_best_deg
            self.saturated = self.saturated or frec.saturated
        if not self._started and self.adapting:
            # adaptation starts with the next revolution: apply the tuner's first values
            self._started = True
            if self.tuner == "esc":
                # normalise by the cost of this revolution, measured without modulation
                self.esc_state = self.esc.initial_state(
                    cost_ref=cost if cost > 0 and self.a_um == 0.0 else None
                )
                self.a_um, self.theta_deg = self.esc_state.a_um, self.esc_state.theta_deg
            else:
                self.a_um, self.theta_deg = self.fast_state.a_um, self.fast_state.theta_deg
                self.b_um, self.phi_deg = self.fast_state.b_um, self.fast_state.phi_deg
        self.last_cost = cost
        lg = self.log
        lg.t_end.append(t_end)
        lg.cost.append(cost)
        lg.cost_true.append(cost_true)
        lg.a_um.append(self.a_um)
        lg.theta_deg.append(self.theta_deg)
        an, tn = positive_polar(self.a_n_um, self.theta_n_deg)
        lg.a_n_um.append(an)
        lg.theta_n_deg.append(tn)
        lg.saturated.append(self.saturated)
        lg.adapting.append(adapting)
        lg.rpm.append(self.machine.spindle_rpm)


__all__ = [
    "AdaptiveObserverForceSource",
    "EccentricityLoop",
    "ForceSource",
    "LoopState",
    "ObserverForceSource",
    "RevolutionLog",
]
