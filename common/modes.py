r"""Vibration modes of the tool and of the workpiece at the cutting point.

Each mode is a single-degree-of-freedom oscillator acting along a direction in the X-Y
plane (X the feed, Y the normal direction, as in :mod:`machine.milling`):

.. math::

    \ddot\eta + 2\zeta\omega_n\dot\eta + \omega_n^2\eta = \frac{1}{m}\,u^T F,
    \qquad u = [\cos\theta, \sin\theta]

where :math:`F` is the cutting force on the tool and :math:`m` the modal mass. A tool
mode moves the tool by :math:`u\eta`; a workpiece mode feels :math:`-F` and moves the
workpiece, so the relative displacement tool minus workpiece is the sum over every mode
of :math:`u\eta'` with :math:`\eta' = -\eta` for workpiece modes: both kinds enter the
chip the same way, and only the force each passes on to the machine differs (a tool
mode loads the spindle and the feed drives, a workpiece mode the table).

The simulator (:mod:`machine.regeneration`) and the stability lobes
(:mod:`estimators.chatter.lobes`) both take a :class:`ModalModel`; it lives here so that they
share one definition.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.arrays import F64
from common.errors import ParameterError, require_in, require_positive

#: the two bodies a mode may belong to
BODIES = ("tool", "workpiece")


@dataclass(frozen=True)
class Mode:
    """One vibration mode at the cutting point.

    Parameters
    ----------
    freq_hz : float
        Natural frequency :math:`f_n` [Hz].
    damping : float
        Damping ratio :math:`\\zeta`, in (0, 1).
    mass : float
        Modal mass :math:`m` [kg]; the modal stiffness is :math:`m (2\\pi f_n)^2`.
    direction_deg : float
        Direction of the mode in the X-Y plane [deg]: 0 along X (feed), 90 along Y.
    body : str
        ``"tool"`` or ``"workpiece"``.
    """

    freq_hz: float
    damping: float
    mass: float
    direction_deg: float = 0.0
    body: str = "tool"

    def __post_init__(self) -> None:
        require_positive("freq_hz", self.freq_hz)
        require_in("damping", self.damping, 0.0, 1.0, lo_open=True, hi_open=True)
        require_positive("mass", self.mass)
        if not math.isfinite(self.direction_deg):
            raise ParameterError("direction_deg", "a finite angle [deg]", self.direction_deg)
        if self.body not in BODIES:
            raise ParameterError("body", f"one of {BODIES}", self.body)

    @classmethod
    def from_stiffness(
        cls,
        freq_hz: float,
        damping: float,
        stiffness: float,
        direction_deg: float = 0.0,
        body: str = "tool",
    ) -> Mode:
        """The mode with modal stiffness ``stiffness`` [N/m] instead of a mass."""
        k = require_positive("stiffness", stiffness)
        w = 2.0 * math.pi * require_positive("freq_hz", freq_hz)
        return cls(freq_hz, damping, k / (w * w), direction_deg, body)

    @property
    def omega(self) -> float:
        """:math:`\\omega_n = 2\\pi f_n` [rad/s]."""
        return 2.0 * math.pi * self.freq_hz

    @property
    def stiffness(self) -> float:
        """Modal stiffness :math:`k = m\\omega_n^2` [N/m]."""
        return self.mass * self.omega**2

    @property
    def direction(self) -> tuple[float, float]:
        """Unit vector :math:`u` of the mode in the X-Y plane."""
        th = math.radians(self.direction_deg)
        return math.cos(th), math.sin(th)

    def receptance(self, freq_hz: float) -> complex:
        """Displacement per unit force along :math:`u` at ``freq_hz`` [m/N]."""
        w = 2.0 * math.pi * freq_hz
        wn = self.omega
        return 1.0 / (self.mass * complex(wn * wn - w * w, 2.0 * self.damping * wn * w))


@dataclass(frozen=True)
class ModalModel:
    """The modes at the cutting point (at least one).

    Examples
    --------
    The 1-DOF milling benchmark of Insperger and Stepan (a mode along X only):

    >>> m = ModalModel((Mode(922.0, 0.011, 0.03993),))
    >>> round(m.modes[0].stiffness / 1e6, 3)
    1.34
    """

    modes: tuple[Mode, ...]

    def __post_init__(self) -> None:
        if not isinstance(self.modes, tuple) or not self.modes:
            raise ParameterError("modes", "a non-empty tuple of Mode", self.modes)
        for i, m in enumerate(self.modes):
            if not isinstance(m, Mode):
                raise ParameterError(f"modes[{i}]", "a Mode", type(m).__name__)

    def frf(self, freq_hz: float) -> np.ndarray:
        """2x2 receptance of the relative displacement (tool minus workpiece) per unit force
        on the tool, ``[[xx, xy], [yx, yy]]`` [m/N], at ``freq_hz``."""
        out = np.zeros((2, 2), dtype=np.complex128)
        for m in self.modes:
            u = np.array(m.direction)
            out += np.outer(u, u) * m.receptance(freq_hz)
        return out

    def frf_many(self, freqs_hz: np.ndarray) -> np.ndarray:
        """:meth:`frf` at each frequency of ``freqs_hz``: shape ``(n, 2, 2)``."""
        f = np.asarray(freqs_hz, dtype=float)
        out = np.zeros((f.size, 2, 2), dtype=np.complex128)
        w = 2.0 * np.pi * f
        for m in self.modes:
            u = np.array(m.direction)
            g = 1.0 / (m.mass * (m.omega**2 - w * w + 2j * m.damping * m.omega * w))
            out += np.outer(u, u)[None, :, :] * g[:, None, None]
        return out

    def packed(self) -> F64:
        """Per-mode rows ``[omega_n, zeta, mass, ux, uy, tool]`` for the kernels
        (``tool`` is 1.0 for a tool mode, 0.0 for a workpiece mode)."""
        out = np.zeros((len(self.modes), 6))
        for i, m in enumerate(self.modes):
            ux, uy = m.direction
            out[i] = (m.omega, m.damping, m.mass, ux, uy, 1.0 if m.body == "tool" else 0.0)
        return out

    @property
    def highest_hz(self) -> float:
        return max(m.freq_hz for m in self.modes)


#: The 1-DOF milling benchmark of Insperger & Stepan (2004): a tool mode along X (feed),
#: f_n 922 Hz, damping ratio 0.011, modal mass 0.03993 kg.
BENCHMARK_1DOF = ModalModel((Mode(922.0, 0.011, 0.03993, 0.0, "tool"),))

__all__ = ["BENCHMARK_1DOF", "BODIES", "ModalModel", "Mode"]
