r"""The spindle drive: a speed loop around the spindle's inertia, loaded by the cut.

.. math::

    J\dot\omega = T_m - T_c - b\,\omega, \qquad
    T_m = K_p(\omega_{ref} - \omega) + K_i\!\int(\omega_{ref} - \omega)\,dt

with the motor torque limited to :math:`\pm T_{max}` (the integral held while it is).
The PI gains put both closed-loop poles at :math:`-2\pi f_{bw}` (``kp = 2 J w``,
``ki = J w^2``), so the bandwidth is stated by one number. The CNC hands out the motor
current :math:`T_m / K_T` and the power :math:`T_m\omega` (its "spindle load"). A
cutting torque at frequency :math:`f` reaches the motor torque through
:math:`T_m/T_c = C/(Js + b + C)` (:func:`torque_response`): whole below the bandwidth,
falling as :math:`2 f_{bw}/f` above it, the rest taken by the inertia.

The loop runs at the drive's sample time; within a sample the speed is advanced in the
cut's sub-steps (:func:`spindle_substep`), the motor torque held.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from common.arrays import F64
from machine.errors import ParameterError, require_nonnegative, require_positive


@dataclass(frozen=True)
class SpindleParams:
    """A spindle drive.

    Parameters
    ----------
    inertia : float
        Rotor, holder and tool inertia :math:`J` [kg m^2].
    bandwidth_hz : float
        Speed-loop bandwidth :math:`f_{bw}` [Hz] (both poles placed there).
    torque_constant : float
        Motor torque per ampere :math:`K_T` [N m/A].
    max_torque : float
        Motor torque limit [N m].
    viscous : float
        Bearing and windage friction :math:`b` [N m s/rad].
    """

    inertia: float = 0.01
    bandwidth_hz: float = 30.0
    torque_constant: float = 0.5
    max_torque: float = 60.0
    viscous: float = 1e-4

    def __post_init__(self) -> None:
        require_positive("inertia", self.inertia)
        require_positive("bandwidth_hz", self.bandwidth_hz)
        require_positive("torque_constant", self.torque_constant)
        require_positive("max_torque", self.max_torque)
        require_nonnegative("viscous", self.viscous)

    def gains(self) -> tuple[float, float]:
        """``(kp [N m s/rad], ki [N m/rad])`` of the speed loop."""
        w = 2.0 * math.pi * self.bandwidth_hz
        return 2.0 * self.inertia * w, self.inertia * w * w

    def packed(self) -> F64:
        """``[J, kp, ki, b, T_max, K_T]`` for the kernels."""
        kp, ki = self.gains()
        return np.array([self.inertia, kp, ki, self.viscous, self.max_torque, self.torque_constant])


def torque_response(sp: SpindleParams, freq_hz: float, sample_time: float | None = None) -> complex:
    r"""Motor torque per unit cutting torque at ``freq_hz``.

    Continuous loop by default; with ``sample_time`` the loop of :func:`spindle_command`
    (PI sampled, torque held) around the continuous rotor: :math:`C(z) P_c(i\omega) /
    (1 + C(z) P(z))` with :math:`P_c = 1/(Js + b)` and :math:`P(z) = (T/J)/(z - 1)`.
    """
    f = require_positive("freq_hz", freq_hz)
    s = complex(0.0, 2.0 * math.pi * f)
    kp, ki = sp.gains()
    pc = 1.0 / (sp.inertia * s + sp.viscous)
    if sample_time is None:
        c = kp + ki / s
        return complex(c * pc / (1.0 + c * pc))
    ts = require_positive("sample_time", sample_time)
    z = complex(math.cos(2.0 * math.pi * f * ts), math.sin(2.0 * math.pi * f * ts))
    cz = kp + ki * ts * z / (z - 1.0)
    return complex(cz * pc / (1.0 + cz * (ts / sp.inertia) / (z - 1.0)))


@njit(cache=True)
def spindle_command(sp: F64, state: F64, w_ref: float, ts: float) -> float:  # pragma: no cover
    """The motor torque for the next drive sample; ``state = [w, integral, T_m]``."""
    e = w_ref - state[0]
    integ = state[1] + e * ts
    tm = sp[1] * e + sp[2] * integ
    if tm > sp[4]:
        tm = sp[4]
    elif tm < -sp[4]:
        tm = -sp[4]
    else:
        state[1] = integ  # the integral runs only while the torque is not limited
    state[2] = tm
    return tm


@njit(cache=True, inline="always")
def spindle_substep(sp: F64, state: F64, t_cut: float, dt: float) -> float:  # pragma: no cover
    """Advance the speed over ``dt`` under the held motor torque and the cutting torque
    ``t_cut`` (explicit; the step is far below the loop's time constant); returns it."""
    w = state[0]
    state[0] = w + dt * (state[2] - t_cut - sp[3] * w) / sp[0]
    return state[0]


def check(sp: object) -> SpindleParams:
    """``sp`` if it is a :class:`SpindleParams`."""
    if not isinstance(sp, SpindleParams):
        raise ParameterError("spindle", "a SpindleParams", type(sp).__name__)
    return sp


__all__ = ["SpindleParams", "check", "spindle_command", "spindle_substep", "torque_response"]
