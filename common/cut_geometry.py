r"""The milling cut as the stability of chatter sees it: flutes, immersion, the force law.

Frame and geometry are those of :mod:`machine.milling` (seed 003): X is the feed
direction, Y the normal one, the spindle turns counter-clockwise, an edge at immersion
angle :math:`\phi` points along :math:`v(\phi) = [\sin\phi, -\cos\phi]`, the nominal chip is
:math:`c\sin\phi`. Up-milling engages :math:`\phi\in[0, \arccos(1-2a_e/D)]`,
down-milling :math:`\phi\in[\arccos(2a_e/D-1), \pi]`: the same angles as in Insperger
and Stepan's milling model, so their 1-DOF benchmark is this frame's X direction.

Linear force law (no edge forces: they do not depend on the chip and so do not enter
the stability): tangential :math:`F_t = K_t a h`, normal (radial) :math:`F_n = K_n a h`.
The force on the tool from one edge is :math:`-a h\,w(\phi)` with
:math:`w = [K_t\cos\phi + K_n\sin\phi,\; K_t\sin\phi - K_n\cos\phi]`. A relative
displacement :math:`q` (tool minus workpiece) thickens the chip by
:math:`v^T(q(t) - q(t-\tau))`, so the regenerative force is

.. math::

    F(t) = a\,A(t)\,[q(t-\tau) - q(t)], \qquad
    A(t) = \sum_j g(\phi_j)\, w(\phi_j)\, v(\phi_j)^T

the directional matrix (for the X-X entry Insperger and Stepan's
:math:`h(t) = \sum_j g\,\sin\phi_j(K_t\cos\phi_j + K_n\sin\phi_j)`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from common.arrays import F64
from common.errors import ParameterError, require_in, require_nonnegative, require_positive


@dataclass(frozen=True)
class CutGeometry:
    """Flutes, radial immersion, direction of milling and the cutting coefficients.

    Parameters
    ----------
    n_flutes : int
        Number of flutes, equally spaced (>= 1).
    radial_immersion : float
        Radial width of cut over the tool diameter :math:`a_e/D`, in (0, 1].
    down_milling : bool
        Down (climb) milling if true, up (conventional) milling otherwise.
    kt, kn : float
        Tangential and normal (radial) cutting coefficients [N/m^2].
    """

    n_flutes: int
    radial_immersion: float
    down_milling: bool
    kt: float
    kn: float

    def __post_init__(self) -> None:
        if int(self.n_flutes) != self.n_flutes or self.n_flutes < 1:
            raise ParameterError("n_flutes", "an integer >= 1", self.n_flutes)
        require_in("radial_immersion", self.radial_immersion, 0.0, 1.0, lo_open=True)
        require_positive("kt", self.kt)
        require_nonnegative("kn", self.kn)

    def engagement(self) -> tuple[float, float]:
        """Entry and exit angles :math:`(\\phi_{st}, \\phi_{ex})` [rad]."""
        return engagement(self.radial_immersion, self.down_milling)

    def tooth_period(self, rpm: float) -> float:
        """The delay :math:`\\tau = 60 / (N\\,\\Omega)` [s] at ``rpm``."""
        return 60.0 / (self.n_flutes * require_positive("rpm", rpm))

    def mean_directional(self) -> F64:
        """:math:`A_0`, the average of :math:`A(t)` over a tooth period (the zero-order term)."""
        st, ex = self.engagement()
        return self.n_flutes / (2.0 * math.pi) * directional_integral(st, ex, self.kt, self.kn)

    def interval_directional(self, m: int) -> F64:
        """``(m, 2, 2)``: the average of :math:`A(t)` over each of ``m`` equal intervals of
        one tooth period (t = 0 puts flute 0 at immersion 0), exact (analytic) integrals."""
        pitch = 2.0 * math.pi / self.n_flutes
        d = pitch / m
        st, ex = self.engagement()
        out = np.zeros((m, 2, 2))
        for i in range(m):
            lo = i * d
            for j in range(self.n_flutes):
                a = (lo - j * pitch) % (2.0 * math.pi)
                out[i] += _window_integral(a, a + d, st, ex, self.kt, self.kn)
            out[i] /= d
        return out


def engagement(radial_immersion: float, down_milling: bool) -> tuple[float, float]:
    """Entry and exit angles [rad] of a cut of radial immersion ``a_e/D``."""
    r = float(radial_immersion)
    if down_milling:
        return math.acos(2.0 * r - 1.0), math.pi
    return 0.0, math.acos(1.0 - 2.0 * r)


def directional_integral(lo: float, hi: float, kt: float, kn: float) -> F64:
    """:math:`\\int_{lo}^{hi} w(\\phi) v(\\phi)^T d\\phi` in closed form (``lo <= hi``)."""
    d = hi - lo
    s2 = math.sin(hi) ** 2 - math.sin(lo) ** 2  # 2 * integral of sin cos
    sin2 = math.sin(2.0 * hi) - math.sin(2.0 * lo)
    i_sc = 0.5 * s2
    i_ss = 0.5 * d - 0.25 * sin2
    i_cc = 0.5 * d + 0.25 * sin2
    return np.array(
        [
            [kt * i_sc + kn * i_ss, -kt * i_cc - kn * i_sc],
            [kt * i_ss - kn * i_sc, -kt * i_sc + kn * i_cc],
        ]
    )


def _window_integral(a: float, b: float, st: float, ex: float, kt: float, kn: float) -> F64:
    """Integral over ``[a, b]`` (``0 <= a < 2 pi``, ``b - a <= 2 pi``) of the windowed
    :math:`g(\\phi) w v^T`, the window :math:`[st, ex]` repeating every :math:`2\\pi`."""
    out = np.zeros((2, 2))
    two_pi = 2.0 * math.pi
    for shift in (0.0, two_pi):
        lo = max(a, st + shift)
        hi = min(b, ex + shift)
        if hi > lo:
            out += directional_integral(lo, hi, kt, kn)
    return out


#: Insperger & Stepan's 1-DOF milling benchmark cut coefficients (two flutes, N/m^2).
BENCHMARK_KT = 6e8
BENCHMARK_KN = 2e8

__all__ = [
    "BENCHMARK_KN",
    "BENCHMARK_KT",
    "CutGeometry",
    "directional_integral",
    "engagement",
]
