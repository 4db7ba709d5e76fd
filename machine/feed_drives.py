r"""X and Y feed drives: position-controlled servos that carry the spindle.

Each axis is a rigid carriage (mass ``mass``, viscous friction ``viscous``, optional
smoothed Coulomb friction) driven by a motor whose force is ``force_constant`` times the
motor current. A digital PID position loop at the drive's sample rate (5 kHz, as in
seed 003 section 4) computes the current command from the position error; the current
loop is taken as ideal (the force follows the command within the sample). The modulation
of seed003 (7) is added to the position command, so its amplitude and phase at the
spindle frequency are shaped by the closed loop :math:`G(j\omega)` computed by
:meth:`FeedDrives.response`.

The PID is the CNC's own difference equation (backward-difference derivative, rectangular
integral), not a discretised continuous filter. The carriage is continuous: it is advanced
over each sample by the exact zero-order-hold solution of
:math:`m\ddot x + b\dot x = F`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from common.arrays import F64
from machine.errors import ParameterError, require_nonnegative, require_positive


@dataclass(frozen=True)
class AxisParams:
    r"""One feed axis: carriage and PID gains.

    Parameters
    ----------
    mass : float
        Moving mass [kg] (carriage, spindle head, motor and screw reflected).
    viscous : float
        Viscous friction [N s/m].
    coulomb : float
        Coulomb friction [N] (smoothed with ``tanh(v / 1 mm/s)``); 0 disables it.
    force_constant : float
        Motor force per ampere [N/A] (linear equivalent of torque constant and lead).
    bandwidth_hz : float
        Placement frequency of the PID: the three closed-loop poles sit at
        :math:`-2\pi f` (``kp = 3 m w^2``, ``ki = m w^3``, ``kd = 3 m w - b``).
    """

    mass: float = 150.0
    viscous: float = 300.0
    coulomb: float = 0.0
    force_constant: float = 60.0
    bandwidth_hz: float = 18.0

    def __post_init__(self) -> None:
        require_positive("mass", self.mass)
        require_nonnegative("viscous", self.viscous)
        require_nonnegative("coulomb", self.coulomb)
        require_positive("force_constant", self.force_constant)
        require_positive("bandwidth_hz", self.bandwidth_hz)

    def gains(self) -> tuple[float, float, float]:
        """PID gains ``(kp [N/m], ki [N/(m s)], kd [N s/m])`` from the pole placement."""
        w = 2.0 * math.pi * self.bandwidth_hz
        kd = max(3.0 * self.mass * w - self.viscous, 0.0)
        return 3.0 * self.mass * w * w, self.mass * w**3, kd


@dataclass(frozen=True)
class FeedDriveParams:
    """The X (feed) and Y (normal) axes and the drive sample time.

    ``y`` defaults to a copy of ``x`` (matched axes). A mismatch between the axes (seed 003
    section 4: "mismatched feed drive dynamics ... distort circular motion") is set by
    giving ``y`` a different mass or bandwidth.
    """

    x: AxisParams = field(default_factory=AxisParams)
    y: AxisParams = field(default_factory=AxisParams)
    sample_time: float = 2e-4

    def __post_init__(self) -> None:
        ts = require_positive("sample_time", self.sample_time)
        if ts > 2e-3:
            raise ParameterError("sample_time", "a drive sample time <= 2 ms", ts)
        for name, ax in (("x", self.x), ("y", self.y)):
            if not isinstance(ax, AxisParams):
                raise ParameterError(name, "an AxisParams", type(ax).__name__)

    def packed(self) -> F64:
        """Per-axis coefficients for the kernel: rows x, y; columns
        ``kp, ki, kd, m, b, coulomb, e1, e2, e3`` (exact ZOH terms, see :func:`zoh_terms`)."""
        out = np.zeros((2, 9))
        for i, ax in enumerate((self.x, self.y)):
            kp, ki, kd = ax.gains()
            e1, e2, e3 = zoh_terms(ax.mass, ax.viscous, self.sample_time)
            out[i] = (kp, ki, kd, ax.mass, ax.viscous, ax.coulomb, e1, e2, e3)
        return out


def zoh_terms(mass: float, viscous: float, ts: float) -> tuple[float, float, float]:
    r"""Exact sample-to-sample solution of :math:`m\ddot x + b\dot x = F` (F constant).

    Returns ``(e1, e2, e3)`` with :math:`v^+ = e_1 v + e_2 F` and
    :math:`x^+ = x + e_3 v + e_4 F`: ``e1 = exp(-b T/m)``, ``e2 = (1 - e1)/b`` (or
    ``T/m`` when b = 0), ``e3 = (1 - e1) m / b`` (or ``T``), the displacement per unit
    initial velocity. The kernel forms ``e4 = (T - e3)/b`` (or ``T^2/(2m)``).
    """
    if viscous <= 0.0:
        return 1.0, ts / mass, ts
    a = viscous / mass
    e1 = math.exp(-a * ts)
    return e1, (1.0 - e1) / viscous, (1.0 - e1) / a


def axis_response(ax: AxisParams, ts: float, freq_hz: float) -> complex:
    """Closed-loop response position/command of one axis at ``freq_hz`` (exact, discrete).

    The loop is the PID difference equation of the kernel around the exact ZOH carriage;
    Coulomb friction is left out (it is not linear).
    """
    c, p = loop_terms(ax, ts, freq_hz)
    return complex(c * p / (1.0 + c * p))


def loop_terms(ax: AxisParams, ts: float, freq_hz: float) -> tuple[complex, complex]:
    """The PID :math:`C(z)` and the carriage under a held force :math:`P(z)` (force to
    position, exact ZOH) of one axis at ``freq_hz``."""
    kp, ki, kd = ax.gains()
    e1, e2, e3 = zoh_terms(ax.mass, ax.viscous, ts)
    z = complex(math.cos(2 * math.pi * freq_hz * ts), math.sin(2 * math.pi * freq_hz * ts))
    # carriage: v+ = e1 v + e2 F ; x+ = x + e3 v + e4 F with e4 the displacement per unit
    # force: e4 = (T - e3)/b (or T^2/(2m) when b = 0)
    e4 = (ts - e3) / ax.viscous if ax.viscous > 0 else ts * ts / (2 * ax.mass)
    # transfer F -> x: X (z-1) = e3 V + e4 F ; V (z - e1) = e2 F
    p = (e3 * e2 / (z - e1) + e4) / (z - 1.0)
    # PID on the error e = r - x: u = kp e + ki T z/(z-1) e + kd (1 - 1/z)/T e
    c = kp + ki * ts * z / (z - 1.0) + kd * (1.0 - 1.0 / z) / ts
    return c, p


class FeedDrives:
    """The pair of servo axes; the kernel state lives in :class:`machine.milling.MillingMachine`.

    This class holds the parameters and answers questions about the linear loop
    (:meth:`response`), which the server uses to score how well a modulation cancels the
    eccentricity.
    """

    def __init__(self, params: FeedDriveParams | None = None) -> None:
        self.params = params if params is not None else FeedDriveParams()

    def response(self, freq_hz: float) -> tuple[complex, complex]:
        """Closed-loop position/command responses ``(G_x, G_y)`` at ``freq_hz``."""
        f = require_positive("freq_hz", freq_hz)
        ts = self.params.sample_time
        return axis_response(self.params.x, ts, f), axis_response(self.params.y, ts, f)


__all__ = [
    "AxisParams",
    "FeedDriveParams",
    "FeedDrives",
    "axis_response",
    "loop_terms",
    "zoh_terms",
]
