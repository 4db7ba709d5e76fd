r"""The two-inertia ball-screw stage of seed 000 (Fig. 1, 2) as a simulation.

.. math::

    J_M \dot\omega_M &= T_M - B_M \omega_M - F_{CM}\,\mathrm{sgn}(\omega_M) - T_s \\
    J_L \dot\omega_L &= T_s - B_L \omega_L - F_{CL}\,\mathrm{sgn}(\omega_L) - F_{cut} \\
    T_s &= K (\theta_M - \theta_L) + C_s (\omega_M - \omega_L)

with motor torque :math:`T_M = K_t i_M`. The drive samples every 0.4 ms (seed 000
Table II); between samples the plant is integrated in ``substeps`` steps: the linear part
exactly (matrix exponential with the inputs held over a sub-step), the nonlinear terms
(Coulomb friction, the optional effects, the cutting force) evaluated at the start of each
sub-step. Coulomb friction is :math:`F_C \tanh(\omega/\omega_s)` with
:math:`\omega_s = 0.05` rad/s, far below the operating speeds (tens of rad/s) and large
enough for the explicit sub-step to stay stable.

A PI angular-velocity controller on the motor encoder's velocity, with a double pole at
5 Hz on the nominal rigid-body mode (seed 000 IV.A), follows a reciprocating velocity
trajectory. The encoders on both sides are 20-bit (quantised angles). The output of each
block is kept in two records: :class:`Measurements` (what a drive sees) and
:class:`Truth` (true force and parameters, for display and scoring only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from common.arrays import F64
from common.linalg import zoh
from machine.effects import PlantEffects
from machine.errors import ParameterError, require_positive
from machine.stage_params import (
    ADDED_WEIGHT_INERTIA,
    ENCODER_BITS,
    SAMPLE_TIME,
    StageParams,
    preset,
)

OMEGA_S = 0.05  # velocity scale of the regularised Coulomb friction [rad/s]


@dataclass(frozen=True)
class CuttingForce:
    """Simulated cutting torque on the load: offset + sinusoids (seed 000 IV.A, seed 001 4).

    ``gain`` scales everything; ``freq_scale`` scales the frequencies (the spindle-speed
    change of seed 001 Fig. 9 sets both to 0.8 at 11 s).
    """

    offset: float = 4.0
    amplitudes: tuple[float, ...] = (4.0, 4.0)
    frequencies: tuple[float, ...] = (100.0, 200.0)
    gain: float = 1.0
    freq_scale: float = 1.0
    engage_time: float = 0.0  # the force acts from this time on [s]

    def __post_init__(self) -> None:
        if len(self.amplitudes) != len(self.frequencies):
            raise ParameterError(
                "amplitudes",
                f"{len(self.frequencies)} values (one per frequency)",
                len(self.amplitudes),
            )
        for f in self.frequencies:
            require_positive("frequencies", f)
        require_positive("freq_scale", self.freq_scale)
        if not math.isfinite(self.gain) or not math.isfinite(self.offset):
            raise ParameterError("gain", "finite gain and offset", (self.gain, self.offset))

    def vector(self) -> F64:
        n = len(self.frequencies)
        v = np.zeros(3 + 2 * n)
        v[0], v[1], v[2] = self.offset, self.gain, self.engage_time
        v[3 : 3 + n] = self.amplitudes
        v[3 + n :] = np.asarray(self.frequencies) * self.freq_scale
        return v


SEED000_FORCE = CuttingForce(offset=4.0, amplitudes=(4.0, 4.0), frequencies=(100.0, 200.0))
SEED001_FORCE = CuttingForce(offset=2.0, amplitudes=(1.0, 1.0), frequencies=(100.0, 200.0))


@dataclass(frozen=True)
class Trajectory:
    """Reciprocating angular-velocity command (seed 000 Fig. 8, seed 001 Fig. 7(b)).

    From rest, a ramp to +``speed``; then plateaus of alternating sign joined by linear
    ramps of ``ramp`` seconds centred on every multiple of ``half_period`` (the velocity
    reverses there: seed 001 has reversals at 12 s and 16 s). The figures themselves are
    not in the seed text; this shape keeps their features (plateaus, reversals).

    Two options make a record richer for identification (``cutwatch simulate`` uses
    them; the papers' experiments do not): ``dwell`` seconds at rest in the middle of each
    reversal (friction that acts only while moving then differs from a constant load),
    and ``levels``, plateau speeds as fractions of ``speed`` taken in turn (friction's
    dependence on speed becomes visible).
    """

    speed: float = 30.0  # plateau speed [rad/s]
    half_period: float = 4.0  # time between reversals [s]
    ramp: float = 0.1  # duration of a reversal ramp [s]
    start_ramp: float = 0.1  # from rest to the first plateau [s]
    dwell: float = 0.0  # rest at each reversal [s]
    levels: tuple[float, ...] = (1.0,)  # plateau speeds, fractions of ``speed``, in turn

    def __post_init__(self) -> None:
        for name in ("speed", "half_period", "ramp", "start_ramp"):
            require_positive(name, getattr(self, name))
        if not (math.isfinite(self.dwell) and self.dwell >= 0):
            raise ParameterError("dwell", "a finite value >= 0", self.dwell)
        if self.ramp + self.dwell >= self.half_period:
            raise ParameterError(
                "dwell", f"ramp + dwell < half_period ({self.half_period:g} s)", self.dwell
            )
        if not self.levels or not all(math.isfinite(x) and 0 < x <= 1 for x in self.levels):
            raise ParameterError("levels", "fractions in (0, 1]", self.levels)

    def __call__(self, t: ArrayLike) -> F64:
        ta = np.asarray(t, dtype=np.float64)
        out = np.empty(ta.shape)
        lv = np.asarray(self.levels, dtype=np.float64)
        _trajectory(
            np.ascontiguousarray(ta).reshape(-1),
            self.half_period,
            self.ramp,
            self.speed,
            self.dwell,
            self.start_ramp,
            lv,
            out.reshape(-1),
        )
        return out


@njit(cache=True)
def _plateau(k: float, v: float, lv: F64) -> float:  # pragma: no cover
    # segment k (after reversal k): sign (-1)^k, speed level k mod len(levels)
    kk = np.int64(max(k, 0.0))
    return (1.0 if kk % 2 == 0 else -1.0) * v * lv[kk % lv.shape[0]]


@njit(cache=True)
def _trajectory(
    t: F64, hp: float, r: float, v: float, dw: float, start_ramp: float, lv: F64, out: F64
) -> None:  # pragma: no cover
    """The speed reference of :class:`Trajectory` at each ``t`` (one sample at a time,
    the same operations as the former array expression, so the same values)."""
    half = 0.5 * r + 0.5 * dw
    for i in range(t.shape[0]):
        ti = t[i]
        w = _plateau(math.floor(ti / hp), v, lv)
        # reversal m (m >= 1) at m*hp: ramp from the previous plateau to rest in r/2,
        # rest for the dwell, ramp to the next plateau in r/2 (m: nearest, ties to even)
        m = np.rint(ti / hp)
        d = ti - m * hp
        if m >= 1 and abs(d) < half:
            before = _plateau(m - 1, v, lv) * min(max((-0.5 * dw - d) / (0.5 * r), 0.0), 1.0)
            after = _plateau(m, v, lv) * min(max((d - 0.5 * dw) / (0.5 * r), 0.0), 1.0)
            w = before + after
        # start from rest
        if ti < start_ramp:
            w = v * lv[0] * max(ti, 0.0) / start_ramp
        out[i] = w


@dataclass
class Measurements:
    """What the drive sees, one entry per sample."""

    t: F64  # sample time [s]
    i_m: F64  # motor current [A]
    tau_m: F64  # motor torque from the current, K_t (nominal) * i_m [N m]
    q_m: F64  # motor encoder angle, quantised [rad]
    q_l: F64  # load encoder angle, quantised [rad]
    f_ext: F64  # reference force (the load-side motor's torque on the bench) [N m]


@dataclass
class Truth:
    """What only the simulator knows (display and scoring)."""

    f_cut: F64  # true cutting torque on the load [N m]
    omega_m: F64
    omega_l: F64
    t_s: F64  # true torsional torque [N m]
    omega_ref: F64
    J_L: F64  # true load inertia during the sample [kg m^2]
    B_L: F64
    F_CL: F64


@dataclass
class StageConfig:
    """Everything that defines a run of the stage (may change between blocks)."""

    params: StageParams = field(default_factory=lambda: preset("seed000"))
    nominal: StageParams | None = None  # the controller's model; default = params
    force: CuttingForce = SEED000_FORCE
    trajectory: Trajectory = field(default_factory=Trajectory)
    effects: PlantEffects = field(default_factory=PlantEffects)
    sample_time: float = SAMPLE_TIME
    substeps: int = 4
    encoder_bits: int = ENCODER_BITS
    pole_hz: float = 5.0  # PI velocity loop: double pole on the rigid-body mode
    current_noise: float = 0.0  # rms of the current measurement noise [A]
    extra_inertia: float = 0.0  # added on the load (weight, workpiece) [kg m^2]

    def __post_init__(self) -> None:
        require_positive("sample_time", self.sample_time)
        if int(self.substeps) != self.substeps or self.substeps < 1:
            raise ParameterError("substeps", "an integer >= 1", self.substeps)
        if int(self.encoder_bits) != self.encoder_bits or not 8 <= self.encoder_bits <= 32:
            raise ParameterError("encoder_bits", "an integer in [8, 32]", self.encoder_bits)
        require_positive("pole_hz", self.pole_hz)
        if not math.isfinite(self.current_noise) or self.current_noise < 0:
            raise ParameterError("current_noise", "a finite value >= 0", self.current_noise)
        if not math.isfinite(self.extra_inertia) or self.params.J_L + self.extra_inertia <= 0:
            raise ParameterError(
                "extra_inertia",
                f"a value > {-self.params.J_L:g} (total load inertia positive)",
                self.extra_inertia,
            )

    @property
    def true_params(self) -> StageParams:
        return self.params.with_(J_L=self.params.J_L + self.extra_inertia)

    @property
    def encoder_resolution(self) -> float:
        return 2 * math.pi / 2**self.encoder_bits


def _discrete_linear_part(p: StageParams, h: float) -> tuple[F64, F64]:
    """Exact ZOH discretisation of the linear two-inertia dynamics over one sub-step."""
    a = np.array(
        [
            [0.0, 1.0, 0.0, 0.0],
            [-p.K / p.J_M, -(p.B_M + p.C_s) / p.J_M, p.K / p.J_M, p.C_s / p.J_M],
            [0.0, 0.0, 0.0, 1.0],
            [p.K / p.J_L, p.C_s / p.J_L, -p.K / p.J_L, -(p.B_L + p.C_s) / p.J_L],
        ]
    )
    b = np.array([[0.0, 0.0], [1.0 / p.J_M, 0.0], [0.0, 0.0], [0.0, 1.0 / p.J_L]])
    return zoh(a, b, h)


class StageModel(NamedTuple):
    """The stage's design as the kernel takes it (read only; made per block)."""

    ts: float  # sample time [s]
    nsub: int  # plant sub-steps per sample
    q: float  # encoder resolution [rad]
    phi: F64  # (4, 4) the linear part over one sub-step, exp(A h)
    gam: F64  # (4, 2) its inputs (motor torque, load torque)
    plant: F64  # [K, C_s, F_CM, F_CL, K_t_true]
    eff: F64  # PlantEffects.vector()
    force: F64  # ForceProfile.vector(): [offset, gain, t0, amplitudes..., frequencies...]
    gains: F64  # [Kp, Ki, K_t_nominal]


class StageArrays(NamedTuple):
    """The stage's state as the kernel updates it (in place)."""

    x: F64  # [th_M, w_M, th_L, w_L]
    ctrl: F64  # [integrator, previous quantised th_M]
    phases: F64  # of the force sinusoids


class StageOut(NamedTuple):
    """The kernel's per-sample outputs (filled in place)."""

    t: F64  # sample time [s]
    i_m: F64  # measured motor current (with noise) [A]
    q_m: F64  # quantised motor angle [rad]
    q_l: F64  # quantised load angle [rad]
    f_cut: F64  # cutting torque at t[k] [N m]
    omega_m: F64  # [rad/s]
    omega_l: F64  # [rad/s]
    t_s: F64  # torsional torque [N m]


@njit(cache=True)
def _simulate_block(s, m, t0, w_ref, noise, out):  # pragma: no cover
    """Advance ``len(w_ref)`` samples from time ``t0`` of the stage ``m``
    (:class:`StageModel`) in state ``s`` (:class:`StageArrays`, in place); the current
    noise per sample ``noise``; ``out`` (:class:`StageOut`) filled."""
    x, ctrl, phases = s.x, s.ctrl, s.phases
    ts, nsub, q, phi, gam = m.ts, m.nsub, m.q, m.phi, m.gam
    plant, eff, force, gains = m.plant, m.eff, m.force, m.gains
    out_t, out_i, out_qm, out_ql = out.t, out.i_m, out.q_m, out.q_l
    out_f, out_wm, out_wl, out_ts = out.f_cut, out.omega_m, out.omega_l, out.t_s
    K, Cs, FCM, FCL, Kt = plant[0], plant[1], plant[2], plant[3], plant[4]
    off, asym, strb, vstr = eff[0], eff[1], eff[2], eff[3]
    pp_a, pp_per, rip_a, rip_n, gap = eff[4], eff[5], eff[6], eff[7], eff[8]
    pp_ph, rip_ph = eff[9], eff[10]
    f_off, f_gain, f_t0 = force[0], force[1], force[2]
    nh = (len(force) - 3) // 2
    h = ts / nsub
    kp, ki, kt_nom = gains[0], gains[1], gains[2]
    n = len(w_ref)
    # per sample: PI velocity loop tau_m = Kt (K_p e + K_i sum T_s e); per sub-step the two-inertia
    #  stage J_M dw_M = tau_m - T_s - F_CM sgn w_M, J_L dw_L = T_s - T_cut - friction (seed000 Table
    #  I)
    for k in range(n):
        tk = t0 + k * ts
        # encoders: quantised angles (floor to the count)
        qm = math.floor(x[0] / q) * q
        ql = math.floor(x[2] / q) * q
        # PI velocity control on the motor encoder's backward-difference velocity
        w_meas = (qm - ctrl[1]) / ts
        ctrl[1] = qm
        e = w_ref[k] - w_meas
        u_cmd = kp * e + ctrl[0]
        ctrl[0] += ki * ts * e
        i_cmd = u_cmd / kt_nom
        tm = Kt * i_cmd
        out_t[k] = tk
        out_i[k] = i_cmd + noise[k]
        out_qm[k] = qm
        out_ql[k] = ql
        out_wm[k] = x[1]
        out_wl[k] = x[3]
        out_ts[k] = 0.0
        for j in range(nsub):
            ts_sub = tk + j * h
            # cutting torque on the load, at the sub-step's midpoint (second-order
            # accurate for the held input); the recorded value is the one at t[k]
            fc = 0.0
            f0 = 0.0
            if ts_sub + 0.5 * h >= f_t0:
                fc = f_off
                f0 = f_off
                for i in range(nh):
                    dphi = 2.0 * math.pi * force[3 + nh + i] * h
                    fc += force[3 + i] * math.sin(phases[i] + 0.5 * dphi)
                    f0 += force[3 + i] * math.sin(phases[i])
                fc *= f_gain
                f0 *= f_gain
            if j == 0:
                out_f[k] = f0 if ts_sub >= f_t0 else 0.0
            for i in range(nh):
                phases[i] += 2.0 * math.pi * force[3 + nh + i] * h
            wm, wl = x[1], x[3]
            sm = math.tanh(wm / OMEGA_S)
            sl = math.tanh(wl / OMEGA_S)
            # load-side Coulomb friction, optionally direction dependent
            fcl = FCL * (1.0 + asym * sl) * sl
            # Stribeck: extra friction near rest, decaying with speed
            fcl += strb * math.exp(-((wl / vstr) ** 2)) * sl
            u_l = -fc - fcl - off
            if pp_a != 0.0:
                u_l -= pp_a * math.sin(2.0 * math.pi * x[2] / pp_per + pp_ph)
            u_m = tm - FCM * sm
            if rip_a != 0.0:
                u_m += rip_a * math.sin(rip_n * x[0] + rip_ph)
            dth = x[0] - x[2]
            if gap > 0.0:
                # dead zone of total width gap: the linear part applies K*dth; correct it
                half = 0.5 * gap
                if dth > half:
                    dz = dth - half
                elif dth < -half:
                    dz = dth + half
                else:
                    dz = 0.0
                corr = K * (dth - dz)
                u_m += corr
                u_l -= corr
            if j == 0:
                tsk = K * dth + Cs * (x[1] - x[3])
                if gap > 0.0:
                    tsk -= corr
                out_ts[k] = tsk
            x0, x1, x2, x3 = x[0], x[1], x[2], x[3]
            for r in range(4):
                x[r] = (
                    phi[r, 0] * x0
                    + phi[r, 1] * x1
                    + phi[r, 2] * x2
                    + phi[r, 3] * x3
                    + gam[r, 0] * u_m
                    + gam[r, 1] * u_l
                )


class StageSim:
    """The simulated stage; ``step(n)`` advances ``n`` samples and returns both records.

    Changing the configuration between blocks (weight, spindle speed, effects) takes
    effect at the next sample; the state (positions, velocities, controller, force
    phases) carries over, so nothing is skipped or repeated.
    """

    def __init__(self, config: StageConfig | None = None, seed: int = 0) -> None:
        self.config = config or StageConfig()
        self._rng = np.random.default_rng(seed)
        self.reset()

    def reset(self) -> None:
        self.k = 0
        self.x = np.zeros(4)
        self.ctrl = np.zeros(2)
        self.phases = np.zeros(len(self.config.force.frequencies))
        self._prepare()

    @property
    def t(self) -> float:
        """Time of the next sample [s]."""
        return self.k * self.config.sample_time

    def reconfigure(self, **changes: object) -> None:
        """Replace fields of the configuration (validated) from the next sample on."""
        new = replace(self.config, **changes)  # type: ignore[arg-type]
        if len(new.force.frequencies) != len(self.phases):
            self.phases = np.zeros(len(new.force.frequencies))
        self.config = new
        self._prepare()

    def set_weight(self, on: bool) -> None:
        """Add or remove the weight of seed 000 Fig. 7(b) (+2.92e-4 kg m^2 on the load)."""
        self.reconfigure(extra_inertia=ADDED_WEIGHT_INERTIA if on else 0.0)

    def _prepare(self) -> None:
        c = self.config
        p = c.true_params
        nom = c.nominal or c.params
        h = c.sample_time / c.substeps
        # re-discretise only when the linear plant changed (a force or effect change
        # between blocks costs nothing then)
        key = (p, h)
        if getattr(self, "_disc_key", None) != key:
            self._phi, self._gam = _discrete_linear_part(p, h)
            self._disc_key = key
        self._plant = np.array([p.K, p.C_s, p.F_CM, p.F_CL, p.K_t])
        self._true_load = (p.J_L, p.B_L, p.F_CL)  # for the Truth of every block
        self._eff = c.effects.vector()
        self._force = c.force.vector()
        # seed 000 IV.A: PI with a double pole at pole_hz on the nominal rigid-body mode:
        # (J_M + J_L) s^2 + Kp s + Ki = (J_M + J_L)(s + w0)^2
        jt = nom.J_M + nom.J_L
        w0 = 2 * math.pi * c.pole_hz
        self._gains = np.array([2 * jt * w0, jt * w0 * w0, nom.K_t])

    def step(self, n: int) -> tuple[Measurements, Truth]:
        if n < 1:
            raise ParameterError("n", "an integer >= 1", n)
        c = self.config
        ts = c.sample_time
        t = (self.k + np.arange(n)) * ts
        w_ref = c.trajectory(t)
        noise = self._rng.normal(0.0, c.current_noise, n) if c.current_noise > 0 else np.zeros(n)
        out = StageOut(*(np.empty(n) for _ in StageOut._fields))
        arrays = StageArrays(self.x, self.ctrl, self.phases)
        # the record is made here, not kept: a checkpoint (common.state_io) gives a kept
        # NamedTuple back as a plain tuple
        model = StageModel(
            ts=ts,
            nsub=c.substeps,
            q=c.encoder_resolution,
            phi=self._phi,
            gam=self._gam,
            plant=self._plant,
            eff=self._eff,
            force=self._force,
            gains=self._gains,
        )
        _simulate_block(arrays, model, self.k * ts, w_ref, noise, out)
        o_t, o_i, o_qm, o_ql, o_f, o_wm, o_wl, o_ts = out
        self.k += n
        nom = c.nominal or c.params
        j_l, b_l, f_cl = self._true_load  # c.true_params, kept by _prepare
        meas = Measurements(t=o_t, i_m=o_i, tau_m=nom.K_t * o_i, q_m=o_qm, q_l=o_ql, f_ext=o_f)
        truth = Truth(
            f_cut=o_f,
            omega_m=o_wm,
            omega_l=o_wl,
            t_s=o_ts,
            omega_ref=w_ref,
            J_L=np.full(n, j_l),
            B_L=np.full(n, b_l),
            F_CL=np.full(n, f_cl),
        )
        return meas, truth
