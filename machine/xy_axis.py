r"""The x-axis of the XY positioning table of seed 002, with its cascade P/PI controller.

Plant (seed002 (1)), input voltage :math:`u` [V], output table position :math:`z` [mm]:

.. math::

    G(s) = \frac{Z(s)}{U(s)} = \frac{A\,e^{-s T_d}}{s^2 + B s + C},
    \quad A = 78020\ \mathrm{mm/(V s^2)},\ B = 163\ \mathrm{s^{-1}},
    \ C = 193.3\ \mathrm{s^{-2}},\ T_d = 1.2\ \mathrm{ms}.

The delay is simulated exactly: the command is a zero-order hold and the delay
:math:`T_d = D T_s + \tau` (integer ``D`` samples plus a fraction ``tau``) splits each
sample interval into a part driven by ``u[k-D-1]`` and a part driven by ``u[k-D]``
(the modified z-transform of the ZOH plant); no Padé approximation.

Disturbance: the cutting force enters at the plant input, expressed as its voltage
equivalent :math:`d/k_f` (the paper's motor constant :math:`k_f` [N/V] is not given), and
acts on the mechanics *without* the delay: the delay belongs to the command path
(amplifier / DAC), the force acts on the table directly.

The closed loop is stepped in blocks of at most ``D`` samples: the position measured in
such a block depends only on commands issued before it, so a controller can compute the
block's commands afterwards and hand them back with :func:`apply`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from common.arrays import F64
from common.linalg import zoh
from machine.errors import ParameterError, require_nonnegative, require_positive

#: Seed 002, Section 2: the identified x-axis (seed002 (1)).
PAPER_A = 78020.0  # mm / (V s^2)
PAPER_B = 163.0  # 1/s
PAPER_C = 193.3  # 1/s^2
PAPER_DELAY = 0.0012  # s
#: Seed 002, Section 4.1: cascade P/PI gains. kp [V s/mm] and ki [V/mm] act on the
#: velocity error (the paper prints ki's unit as V s^2/mm; read as the integral gain of
#: the velocity PI, the only reading under which the units compose), kv [1/s] is the
#: position loop's gain (velocity reference per position error).
PAPER_KP = 0.00661
PAPER_KI = 0.12075
PAPER_KV = 225.0
#: Seed 002, Section 5: the reference is a 10 mm sine at 0.5 Hz.
PAPER_REF_AMPLITUDE = 10.0  # mm
PAPER_REF_FREQUENCY = 0.5  # Hz
#: Seed 002, Section 3: harmonics of the measured cutting force at 1500 rpm.
PAPER_HARMONICS_HZ = (26.0, 52.0, 78.0)

#: Our sample time: seed 002 runs on a dSPACE DS1104 without stating the rate; 10 kHz
#: is a common DS1104 rate and makes the 1.2 ms delay a whole number of samples.
DEFAULT_SAMPLE_TIME = 1e-4


def split_delay(delay: float, sample_time: float) -> tuple[int, float]:
    """Whole samples ``D`` and the fraction ``tau`` (s) of a delay, robust to rounding."""
    q = delay / sample_time
    d = math.floor(q + 1e-9)
    tau = max(0.0, delay - d * sample_time)
    if tau < 1e-12 * sample_time:
        tau = 0.0
    return d, tau


@dataclass(frozen=True, eq=False)
class XYAxisParams:
    """Seed 002's x-axis plant, seed002 (1), sampled at ``sample_time``.

    Parameters
    ----------
    a, b, c : float
        Gain [mm/(V s^2)], damping [1/s] and stiffness [1/s^2] of seed002 (1), all > 0.
    delay : float
        Input delay ``Td`` [s], > 0 and at least one sample (the block closed loop needs
        the measured positions of a block to depend on earlier commands only).
    sample_time : float
        Controller sample time [s].
    """

    a: float = PAPER_A
    b: float = PAPER_B
    c: float = PAPER_C
    delay: float = PAPER_DELAY
    sample_time: float = DEFAULT_SAMPLE_TIME
    phi: F64 = field(init=False, repr=False)
    gamma_a: F64 = field(init=False, repr=False)
    gamma_b: F64 = field(init=False, repr=False)
    gamma_d: F64 = field(init=False, repr=False)
    delay_samples: int = field(init=False)
    delay_fraction: float = field(init=False)

    def __post_init__(self) -> None:
        for name in ("a", "b", "c", "delay", "sample_time"):
            require_positive(name, getattr(self, name))
        if self.delay < self.sample_time * (1 - 1e-9):
            raise ParameterError(
                "delay", f"a delay >= one sample ({self.sample_time:g} s)", self.delay
            )
        d, tau = split_delay(self.delay, self.sample_time)
        f, g = self.state_space()
        ts = self.sample_time
        phi, gam_full = zoh(f, g, ts)
        # modified z-transform of the delayed ZOH input: u[k-D-1] drives the first tau
        # of the interval, u[k-D] the remaining Ts - tau.
        phi_rest, gam_b = zoh(f, g, ts - tau)
        _, gam_tau = zoh(f, g, tau) if tau > 0 else (None, np.zeros_like(g))
        gam_a = phi_rest @ gam_tau
        object.__setattr__(self, "phi", phi)
        object.__setattr__(self, "gamma_a", gam_a[:, 0].copy())
        object.__setattr__(self, "gamma_b", gam_b[:, 0].copy())
        object.__setattr__(self, "gamma_d", gam_full[:, 0].copy())
        object.__setattr__(self, "delay_samples", d)
        object.__setattr__(self, "delay_fraction", tau)

    def state_space(self) -> tuple[F64, F64]:
        """Continuous ``F``, ``G`` of the states ``[z, dz/dt]`` (mm, mm/s)."""
        f = np.array([[0.0, 1.0], [-self.c, -self.b]])
        g = np.array([[0.0], [self.a]])
        return f, g

    def response(self, f_hz: ArrayLike, *, with_delay: bool = True) -> NDArray[np.complex128]:
        """Continuous frequency response of seed002 (1) [mm/V] at ``f_hz``."""
        s = 2j * np.pi * np.asarray(f_hz, dtype=np.float64)
        g = self.a / (s**2 + self.b * s + self.c)
        if with_delay:
            g = g * np.exp(-s * self.delay)
        return np.asarray(g, dtype=np.complex128)


@dataclass(frozen=True, eq=False)
class AxisState:
    """Plant state at the next sample to measure.

    ``x`` = [z (mm), dz/dt (mm/s)] at sample ``k``; ``u_hist`` holds the commands
    ``u[k-D-1] ... u[k-1]`` not yet consumed by the delay line (length ``D+1`` when the
    previous block's commands have been applied).
    """

    x: F64
    u_hist: F64
    k: int


def initial_state(params: XYAxisParams, z0: float = 0.0) -> AxisState:
    """The axis at rest at ``z0`` with zero commands in the delay line."""
    return AxisState(x=np.array([float(z0), 0.0]), u_hist=np.zeros(params.delay_samples + 1), k=0)


@njit(cache=True)
def _plant_block(
    phi: F64,
    ga: F64,
    gb: F64,
    gd: F64,
    x: F64,
    u_hist: F64,
    d: F64,
    z: F64,
) -> None:  # pragma: no cover
    x0 = x[0]
    x1 = x[1]
    # x[k+1] = Phi x[k] + G_a u[k-D-1] + G_b u[k-D] + G_d d[k], z[k] = x_1[k] (seed002 (1), ZOH with
    #  delay)
    for j in range(len(d)):
        z[j] = x0
        ua = u_hist[j]
        ub = u_hist[j + 1]
        n0 = phi[0, 0] * x0 + phi[0, 1] * x1 + ga[0] * ua + gb[0] * ub + gd[0] * d[j]
        n1 = phi[1, 0] * x0 + phi[1, 1] * x1 + ga[1] * ua + gb[1] * ub + gd[1] * d[j]
        x0 = n0
        x1 = n1
    x[0] = x0
    x[1] = x1


def step(params: XYAxisParams, state: AxisState, disturbance: ArrayLike) -> tuple[AxisState, F64]:
    """Measure and advance one block of ``n <= D`` samples.

    Parameters
    ----------
    params : XYAxisParams
    state : AxisState
        With the previous block's commands applied (:func:`apply`).
    disturbance : array_like, shape (n,)
        Input disturbance [V equivalent], held over each sample interval (evaluate it at
        the interval's midpoint for a second-order accurate hold of a smooth force).

    Returns
    -------
    state : AxisState
        Advanced ``n`` samples; waits for the block's ``n`` commands via :func:`apply`.
    z : ndarray, shape (n,)
        Position [mm] measured at samples ``k ... k+n-1``.
    """
    d = np.ascontiguousarray(disturbance, dtype=np.float64)
    n = d.shape[0]
    big_d = params.delay_samples
    if d.ndim != 1 or n < 1 or n > big_d:
        raise ParameterError(
            "disturbance", f"a 1-D block of 1..{big_d} samples (the delay)", d.shape
        )
    if state.u_hist.shape[0] != big_d + 1:
        raise ParameterError(
            "state",
            "the previous block's commands applied first",
            f"{big_d + 1 - state.u_hist.shape[0]} commands missing",
        )
    x = state.x.copy()
    z = np.empty(n)
    _plant_block(params.phi, params.gamma_a, params.gamma_b, params.gamma_d, x, state.u_hist, d, z)
    return AxisState(x=x, u_hist=state.u_hist[n:].copy(), k=state.k + n), z


def apply(params: XYAxisParams, state: AxisState, commands: ArrayLike) -> AxisState:
    """Hand the commands [V] computed for the last measured block to the delay line."""
    u = np.ascontiguousarray(commands, dtype=np.float64)
    need = params.delay_samples + 1 - state.u_hist.shape[0]
    if u.ndim != 1 or u.shape[0] != need:
        raise ParameterError("commands", f"a 1-D block of {need} samples", u.shape)
    return AxisState(x=state.x, u_hist=np.concatenate([state.u_hist, u]), k=state.k)


# --------------------------------------------------------------------------- controller


@dataclass(frozen=True)
class CascadeParams:
    """Seed 002 Section 4.1's cascade: P position loop, PI velocity loop.

    ``v_ref = kv (z_ref - z)``, ``u = kp e_v + ki * integral(e_v)``, ``e_v = v_ref - v``,
    with ``v`` the backward difference of the measured position.
    """

    kp: float = PAPER_KP
    ki: float = PAPER_KI
    kv: float = PAPER_KV
    sample_time: float = DEFAULT_SAMPLE_TIME

    def __post_init__(self) -> None:
        require_positive("kp", self.kp)
        require_nonnegative("ki", self.ki)
        require_positive("kv", self.kv)
        require_positive("sample_time", self.sample_time)

    def response(self, f_hz: ArrayLike) -> tuple[NDArray[np.complex128], float]:
        """Continuous velocity PI ``kp + ki/s`` at ``f_hz`` and the position gain kv."""
        s = 2j * np.pi * np.asarray(f_hz, dtype=np.float64)
        return np.asarray(self.kp + self.ki / s, dtype=np.complex128), self.kv


@dataclass(frozen=True, eq=False)
class CascadeState:
    """Velocity-error integral [mm] and the previous measured position [mm]."""

    integral: float = 0.0
    z_prev: float = 0.0


@njit(cache=True)
def _cascade_block(
    kp: float,
    ki: float,
    kv: float,
    ts: float,
    integral: float,
    z_prev: float,
    z: F64,
    ref: F64,
    u: F64,
) -> tuple[float, float]:  # pragma: no cover
    # u = K_p e_v + K_i sum(T_s e_v), e_v = K_v (r - z) - dz/dt (seed002 section 4.1 cascade)
    for k in range(len(z)):
        v = (z[k] - z_prev) / ts
        z_prev = z[k]
        ev = kv * (ref[k] - z[k]) - v
        u[k] = kp * ev + ki * integral
        # forward-rectangle integral: u[k] uses the integral up to k-1
        integral += ts * ev
    return integral, z_prev


def cascade_step(
    params: CascadeParams, state: CascadeState, z: ArrayLike, ref: ArrayLike
) -> tuple[CascadeState, F64]:
    """Controller output [V] for a block of measured positions and references [mm]."""
    za = np.ascontiguousarray(z, dtype=np.float64)
    ra = np.ascontiguousarray(ref, dtype=np.float64)
    if za.shape != ra.shape or za.ndim != 1:
        raise ParameterError("ref", f"a 1-D block shaped like z {za.shape}", ra.shape)
    u = np.empty_like(za)
    integral, z_prev = _cascade_block(
        params.kp, params.ki, params.kv, params.sample_time, state.integral, state.z_prev, za, ra, u
    )
    return CascadeState(integral=integral, z_prev=z_prev), u


# --------------------------------------------------------------------- reference, force


def sine_reference(
    t: ArrayLike, amplitude: float = PAPER_REF_AMPLITUDE, frequency: float = PAPER_REF_FREQUENCY
) -> F64:
    """Seed 002 Section 5's reference ``amplitude * sin(2 pi f t)`` [mm]."""
    ta = np.asarray(t, dtype=np.float64)
    return np.asarray(amplitude * np.sin(2 * np.pi * frequency * ta))


@dataclass(frozen=True, eq=False)
class HarmonicForce:
    r"""A milling force as a mean plus harmonics, :math:`d(t) = d_0 + \sum_i a_i \sin(2\pi
    f_i t + \varphi_i)`, in the unit the caller chooses (here: volts at the plant input).
    """

    frequencies: tuple[float, ...]
    amplitudes: tuple[float, ...]
    phases: tuple[float, ...]
    mean: float = 0.0

    def __post_init__(self) -> None:
        n = len(self.frequencies)
        if len(self.amplitudes) != n or len(self.phases) != n:
            raise ParameterError(
                "amplitudes",
                f"{n} amplitudes and {n} phases",
                (len(self.amplitudes), len(self.phases)),
            )
        for f in self.frequencies:
            require_positive("frequencies", f)
        for a in self.amplitudes:
            require_nonnegative("amplitudes", a)

    def __call__(self, t: ArrayLike) -> F64:
        ta = np.asarray(t, dtype=np.float64)
        out = np.full(ta.shape, float(self.mean))
        for f, a, p in zip(self.frequencies, self.amplitudes, self.phases, strict=True):
            out += a * np.sin(2 * np.pi * f * ta + p)
        return out


__all__ = [
    "AxisState",
    "CascadeParams",
    "CascadeState",
    "HarmonicForce",
    "XYAxisParams",
    "apply",
    "cascade_step",
    "initial_state",
    "sine_reference",
    "split_delay",
    "step",
]
