r"""Moving mass of a feed axis, identified while it cuts (the adaptive part of an observer).

Seed 000 makes its cutting force observer adaptive by identifying the load-side inertia
with a rectangular-window RLS on seed000 (1), :math:`T_s = J_L\dot\omega_L + B_L\omega_L +
F_{CL}\mathrm{sgn}\,\omega_L + F_{cut}`, low-pass filtered so that the cutting force is a
constant over the window (seed000 (14)). On seed 003's feed drives that assumption fails
where it matters: the axes move at the spindle frequency (the modulation circle), and the
cutting force has a large component at exactly that frequency which changes with the
modulation. At the spindle frequency the inertial force :math:`m\ddot x` and the cutting
force's response to the modulation are both linear in the modulation, so no regression on
the 1x motion can tell them apart (measured in ``docs/reproductions/seed003-eccentricity.md``).

Here the regression is taken at a frequency where the cutting force does not respond to
the axis motion: the chip is the tool-centre displacement since the previous flute
(seed003 (4)), so a motion at :math:`N_f` times the spindle frequency leaves every chip
unchanged. A small circle at spindle order :math:`\nu = N_f + 1/W` is added to the
position command (``MillingMachine.set_excitation``); over a window of ``W`` revolutions
its DFT bin is orthogonal to every spindle harmonic (the cut's mean force, tooth-passing
harmonics and eccentricity 1x), and the chip responds to it with only
:math:`2\sin(\pi/(N_f W))` of the gain it has at other frequencies (0.20 for 4 flutes, W = 8),
while the inertial force grows with :math:`\nu^2`. Per window, with the phasors
:math:`A, V, Y` of :math:`Q\ddot x, Q\dot x, Q\tau` at order :math:`\nu`,

.. math:: Y - b V = m A + e,

and the mass is the least-squares solution over the last ``windows`` windows (seed000
(9)-(12), rectangular window), kept inside ``[mass_min, mass_max]`` (seed000 (13)), updated
only when the window's acceleration phasor exceeds ``acc_min`` (seed 000 III.C's
acceleration threshold as the PE condition). The viscous friction :math:`b` is taken as
known: at :math:`\nu` its force is :math:`b/(m\,2\pi f_\nu)` (0.4 % at 82.5 Hz) of the
inertial one, below what the cutting force's small response there would bias.

For one parameter the recursion of seed000 (9)-(12) is the ratio of two sliding sums,
which is what :meth:`AxisMassIdentifier.step` keeps (same estimate, no round-off drift).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from common.arrays import F64
from estimators.errors import ParameterError, require_nonnegative, require_positive


def excitation_order(n_flutes: int, window_revs: int) -> float:
    """Spindle order :math:`N_f + 1/W` of the identification circle."""
    if int(n_flutes) != n_flutes or n_flutes < 1:
        raise ParameterError("n_flutes", "an integer >= 1", n_flutes)
    if int(window_revs) != window_revs or window_revs < 2:
        raise ParameterError("window_revs", "an integer >= 2", window_revs)
    return float(n_flutes) + 1.0 / float(window_revs)


@dataclass(frozen=True)
class AxisMassParams:
    """Identifier of one axis.

    Parameters
    ----------
    mass0 : float
        Initial estimate [kg] (the observer's nominal mass).
    viscous : float
        Known viscous friction [N s/m].
    order : float
        Spindle order of the excitation (:func:`excitation_order`).
    window_revs : int
        Revolutions per DFT window (``order * window_revs`` must be an integer).
    windows : int
        Windows in the rectangular least-squares window (seed000 (9)-(12)'s L).
    acc_min : float
        PE condition: smallest acceleration phasor of a window used [m/s^2].
    mass_min, mass_max : float
        Projection bounds of seed000 (13) [kg].
    """

    mass0: float
    viscous: float
    order: float
    window_revs: int = 8
    windows: int = 5
    acc_min: float = 1e-3
    mass_min: float = 0.0
    mass_max: float = math.inf

    def __post_init__(self) -> None:
        require_positive("mass0", self.mass0)
        require_nonnegative("viscous", self.viscous)
        require_positive("order", self.order)
        if int(self.window_revs) != self.window_revs or self.window_revs < 1:
            raise ParameterError("window_revs", "an integer >= 1", self.window_revs)
        cycles = self.order * self.window_revs
        if abs(cycles - round(cycles)) > 1e-9 or abs(self.order - round(self.order)) < 1e-9:
            raise ParameterError(
                "order",
                f"a non-integer order with a whole number of cycles in {self.window_revs} "
                "revolutions",
                self.order,
            )
        if int(self.windows) != self.windows or self.windows < 1:
            raise ParameterError("windows", "an integer >= 1", self.windows)
        require_positive("acc_min", self.acc_min)
        require_nonnegative("mass_min", self.mass_min)
        if not self.mass_max > self.mass_min:
            raise ParameterError(
                "mass_max", f"a bound > mass_min ({self.mass_min:g})", self.mass_max
            )
        if not self.mass_min <= self.mass0 <= self.mass_max:
            raise ParameterError(
                "mass0", f"a mass in [{self.mass_min:g}, {self.mass_max:g}]", self.mass0
            )


@dataclass
class AxisMassState:
    """Explicit state: the estimate, the open window's DFT sums, the last windows' sums.

    ``sums`` = [Re A, Im A, Re V, Im V, Re Y, Im Y, samples] of the open window (not yet
    scaled); ``window`` its index (``-1``: none yet; the first window seen is partial
    or holds the start-up, and is discarded); ``aa``, ``ay`` per closed window
    :math:`|A|^2` and :math:`\\mathrm{Re}(\\bar A (Y - bV))` (ring of ``windows``).
    """

    mass: float
    sums: F64
    window: int
    first: int
    aa: F64
    ay: F64
    filled: int = 0
    head: int = 0
    updates: int = 0


@dataclass
class AxisMassRecord:
    """Per sample: the mass in effect; per closed window: its own estimate and |A|."""

    mass: F64
    window_mass: F64
    window_acc: F64


class AxisMassIdentifier:
    """The rectangular-window least squares of seed000 (9)-(13) at the excitation order."""

    def __init__(self, params: AxisMassParams) -> None:
        self.params = params

    def initial_state(self) -> AxisMassState:
        w = int(self.params.windows)
        return AxisMassState(
            mass=float(self.params.mass0),
            sums=np.zeros(7),
            window=-1,
            first=-1,
            aa=np.zeros(w),
            ay=np.zeros(w),
        )

    def step(
        self,
        state: AxisMassState,
        acc: ArrayLike,
        vel: ArrayLike,
        force: ArrayLike,
        psi: ArrayLike,
    ) -> tuple[AxisMassState, AxisMassRecord]:
        """One block of Q-filtered acceleration [m/s^2], velocity [m/s], motor force [N]
        and the spindle angle [rad] of each sample (unwrapped, increasing)."""
        arrs = [np.asarray(x, dtype=np.float64) for x in (acc, vel, force, psi)]
        n = arrs[0].size
        if any(a.ndim != 1 or a.size != n for a in arrs):
            raise ParameterError(
                "acc/vel/force/psi", "1-D arrays of one length", [a.shape for a in arrs]
            )
        a, v, f, ang = arrs
        p = self.params
        st = AxisMassState(
            mass=state.mass,
            sums=state.sums.copy(),
            window=state.window,
            first=state.first,
            aa=state.aa.copy(),
            ay=state.ay.copy(),
            filled=state.filled,
            head=state.head,
            updates=state.updates,
        )
        mass = np.empty(n)
        w_mass: list[float] = []
        w_acc: list[float] = []
        if n == 0:
            return st, AxisMassRecord(mass, np.empty(0), np.empty(0))
        win = np.floor(ang / (2.0 * math.pi * p.window_revs)).astype(np.int64)
        # sample boundaries where the window index changes
        cuts = np.concatenate([[0], np.nonzero(np.diff(win))[0] + 1, [n]])
        for i0, i1 in itertools.pairwise(cuts):
            wi = int(win[i0])
            if wi != st.window:
                if st.window >= 0 and st.window != st.first and st.sums[6] > 0:
                    m_w, acc_w = self._close(st)
                    w_mass.append(m_w)
                    w_acc.append(acc_w)
                if st.window < 0:
                    st.first = wi
                st.window = wi
                st.sums[:] = 0.0
            e = np.exp(-1j * p.order * ang[i0:i1])
            sa = np.dot(a[i0:i1], e)
            sv = np.dot(v[i0:i1], e)
            sy = np.dot(f[i0:i1], e)
            st.sums += (sa.real, sa.imag, sv.real, sv.imag, sy.real, sy.imag, i1 - i0)
            mass[i0:i1] = st.mass
        return st, AxisMassRecord(mass, np.asarray(w_mass), np.asarray(w_acc))

    def _close(self, st: AxisMassState) -> tuple[float, float]:
        """Close a window: its phasors, the PE condition, the sliding LS and projection."""
        p = self.params
        s = st.sums
        k = 2.0 / s[6]
        big_a = k * complex(s[0], s[1])
        big_v = k * complex(s[2], s[3])
        big_y = k * complex(s[4], s[5])
        y = big_y - p.viscous * big_v
        aa = abs(big_a) ** 2
        m_w = (big_a.conjugate() * y).real / aa if aa > 0 else math.nan
        # seed 000 III.C: update only when the acceleration is large enough (PE condition)
        if abs(big_a) >= p.acc_min:
            st.aa[st.head] = aa
            st.ay[st.head] = (big_a.conjugate() * y).real
            st.head = (st.head + 1) % st.aa.size
            st.filled = min(st.filled + 1, st.aa.size)
            # seed000 (9)-(12): least squares over the last L windows (rectangular window)
            m = float(st.ay.sum() / st.aa.sum())
            # seed000 (13): projection onto the feasible range
            st.mass = min(max(m, p.mass_min), p.mass_max)
            st.updates += 1
        return m_w, abs(big_a)


__all__ = [
    "AxisMassIdentifier",
    "AxisMassParams",
    "AxisMassRecord",
    "AxisMassState",
    "excitation_order",
]
