r"""Milling stability by the semi-discretization method (Insperger & Stepan).

The milling model of :mod:`common.cut_geometry` in the modal coordinates of
:mod:`common.modes`: with :math:`y = [\eta; \dot\eta]` (one pair per mode) and
:math:`W(t) = M^{-1} U^T A(t) U`,

.. math::

    \dot y(t) = \big(A_0 - a B(t)\big) y(t) + a B(t)\, y(t-\tau), \qquad
    A_0 = \begin{bmatrix} 0 & I \\ -\Omega^2 & -2Z\Omega \end{bmatrix},\;
    B(t) = \begin{bmatrix} 0 & 0 \\ W(t) & 0 \end{bmatrix}.

First-order ("updated") semi-discretization (Insperger & Stepan, Int. J. Numer. Meth.
Engng 61 (2004) 117-141): the tooth period :math:`\tau` is cut into ``m`` intervals of
length :math:`\Delta t = \tau/m`; on interval ``i`` the periodic coefficient is replaced
by its average :math:`B_i` (exact, from :meth:`CutGeometry.interval_directional`), the
delayed state by the straight line through :math:`y_{i-m}` and :math:`y_{i-m+1}`, and
the resulting ODE is solved exactly:

.. math::

    y_{i+1} = P_i y_i + a R_{i,1}\, y_{i-m+1} + a R_{i,0}\, y_{i-m},\quad
    P_i = e^{L_i\Delta t},\; R_{i,1} = G_1 B_i,\; R_{i,0} = (G_0 - G_1) B_i

with :math:`L_i = A_0 - a B_i`, :math:`G_0 = \int_0^{\Delta t} e^{L_i(\Delta t-s)}ds`,
:math:`G_1 = \int_0^{\Delta t} e^{L_i(\Delta t-s)} s/\Delta t\,ds` (one exponential of
a block matrix, Van Loan's). Only the displacements :math:`\eta` of the delayed states
enter, so the state of the map is :math:`z_i = [y_i; \eta_{i-1}; \dots; \eta_{i-m}]`
(dimension :math:`(2+m)K` for ``K`` modes). The monodromy matrix :math:`\Phi` maps
:math:`z_0` to :math:`z_m`; the cut is stable when its spectral radius is below 1.
The critical multiplier tells the kind of loss of stability: complex (Hopf, a new
frequency) or real and negative (period doubling, "flip").
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from common.arrays import F64
from common.cut_geometry import CutGeometry
from common.modes import ModalModel
from estimators.errors import ParameterError, require_positive

#: the intervals per tooth period the reference uses (converged: see docs/chatter.md)
DEFAULT_INTERVALS = 100


@njit(cache=True)
def _expm(a: F64) -> F64:  # pragma: no cover
    """Matrix exponential of a small matrix: scaling and squaring of a Taylor series."""
    n = a.shape[0]
    norm = 0.0
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += abs(a[i, j])
        norm = max(norm, s)
    j = 0
    while norm > 0.5:
        norm *= 0.5
        j += 1
    x = a / 2.0**j
    out = np.eye(n)
    term = np.eye(n)
    for k in range(1, 24):
        term = term @ x / k
        out = out + term
        if np.max(np.abs(term)) <= 1e-17 * np.max(np.abs(out)):
            break
    for _ in range(j):
        out = out @ out
    return out


@njit(cache=True)
def _interval_terms(
    omega: F64, zeta: F64, w: F64, a: float, dt: float
) -> tuple[F64, F64, F64]:  # pragma: no cover
    """``P, R1, R0`` of one interval (``w`` the K x K matrix :math:`W_i`); ``R1, R0``
    are ``2K x K`` (they act on displacements only) and already carry the depth ``a``."""
    k = omega.shape[0]
    n = 2 * k
    big = np.zeros((3 * n, 3 * n))
    for p in range(k):
        big[p, k + p] = 1.0
        big[k + p, p] = -omega[p] * omega[p]
        big[k + p, k + p] = -2.0 * zeta[p] * omega[p]
        for q in range(k):
            # Insperger-Stepan (2004): L_i = A_0 - a B_i, B_i = [[0, 0], [W_i, 0]]
            big[k + p, q] -= a * w[p, q]
    for r in range(n):
        big[r, n + r] = 1.0
        big[n + r, 2 * n + r] = 1.0 / dt
    e = _expm(big * dt)
    p_mat = e[:n, :n].copy()
    g0 = e[:n, n : 2 * n]
    g1 = e[:n, 2 * n : 3 * n]
    r1 = np.zeros((n, k))
    r0 = np.zeros((n, k))
    for r in range(n):
        for q in range(k):
            s1 = 0.0
            s0 = 0.0
            for p in range(k):
                # B_i y keeps the displacement part: column q of [0; W_i]
                s1 += g1[r, k + p] * w[p, q]
                s0 += (g0[r, k + p] - g1[r, k + p]) * w[p, q]
            # Insperger-Stepan (2004): R_{i,1} = G_1 B_i (y_{i-m+1}), R_{i,0} = (G_0 - G_1) B_i
            r1[r, q] = a * s1
            r0[r, q] = a * s0
    return p_mat, r1, r0


@njit(cache=True)
def _monodromy(omega: F64, zeta: F64, wmat: F64, a: float, dt: float) -> F64:  # pragma: no cover
    """The monodromy matrix of the semi-discretized map over one tooth period.

    ``wmat`` is ``(m, K, K)``, the :math:`W_i` of each interval. The map's state is
    :math:`z = [y; \\eta_{-1}; \\dots; \\eta_{-m}]`; every column of the identity is
    carried through the ``m`` steps at once.
    """
    m = wmat.shape[0]
    k = omega.shape[0]
    n = 2 * k
    dim = n + m * k
    y = np.zeros((n, dim))
    hist = np.zeros((m, k, dim))  # ring: hist[(head + r) % m] is eta_{i-1-r}
    for c in range(n):
        y[c, c] = 1.0
    for r in range(m):
        for p in range(k):
            hist[r, p, n + r * k + p] = 1.0
    head = 0
    for i in range(m):
        p_mat, r1, r0 = _interval_terms(omega, zeta, wmat[i], a, dt)
        # eta_{i-m+1} is eta_{i-1-(m-2)} (or y's own eta when m == 1); eta_{i-m} the last
        if m >= 2:
            d1 = hist[(head + m - 2) % m]
        else:
            d1 = y[:k]
        d0 = hist[(head + m - 1) % m]
        y_new = p_mat @ y + r1 @ d1 + r0 @ d0
        # shift: eta_i (from y_i) becomes the newest delayed entry
        head = (head - 1) % m
        hist[head] = y[:k]
        y = y_new
    out = np.zeros((dim, dim))
    out[:n] = y
    for r in range(m):
        out[n + r * k : n + (r + 1) * k] = hist[(head + r) % m]
    return out


#: above this dimension the largest eigenvalue comes from ARPACK (a few ms) instead of
#: LAPACK's full eigen-decomposition (0.2 s at dimension 400 on this machine)
DENSE_EIG_MAX = 64


def largest_eigenvalue(mat: F64) -> complex:
    """The eigenvalue of largest modulus of a square matrix.

    Small matrices: all eigenvalues (LAPACK). Larger: ARPACK's implicitly restarted
    Arnoldi for the 6 of largest modulus, from a fixed start vector (deterministic);
    LAPACK again if ARPACK does not converge.
    """
    n = mat.shape[0]
    if n <= DENSE_EIG_MAX:
        mu = np.linalg.eigvals(mat)
    else:
        from scipy.sparse.linalg import ArpackNoConvergence, eigs

        try:
            mu = eigs(mat, k=6, which="LM", v0=np.ones(n), return_eigenvectors=False)
        except ArpackNoConvergence:
            mu = np.linalg.eigvals(mat)
    return complex(mu[int(np.argmax(np.abs(mu)))])


@dataclass(frozen=True)
class Multiplier:
    """The critical characteristic multiplier of a cut (largest modulus)."""

    modulus: float
    angle: float

    @property
    def kind(self) -> str:
        """``"flip"`` (period doubling: real, negative), ``"fold"`` (real, positive) or
        ``"hopf"`` (complex pair: a new frequency)."""
        if abs(abs(self.angle) - math.pi) < 1e-6:
            return "flip"
        if abs(self.angle) < 1e-6:
            return "fold"
        return "hopf"


class SemiDiscretization:
    """Stability of one cut at any speed and depth: the monodromy of the SD map.

    Parameters
    ----------
    modal : ModalModel
        The modes at the cutting point.
    cut : CutGeometry
        Flutes, immersion, up/down milling, cutting coefficients.
    intervals : int
        ``m``, the intervals per tooth period (>= 2).
    averaged : bool
        Replace :math:`A(t)` by its mean (the zero-order term): a check, since the SD of
        the averaged system must give the ZOA's lobes.

    Examples
    --------
    >>> from common.cut_geometry import CutGeometry
    >>> from common.modes import BENCHMARK_1DOF
    >>> sd = SemiDiscretization(BENCHMARK_1DOF, CutGeometry(2, 1.0, True, 6e8, 2e8), 40)
    >>> sd.multiplier(10000.0, 0.1e-3).modulus < 1.0
    True
    """

    def __init__(
        self,
        modal: ModalModel,
        cut: CutGeometry,
        intervals: int = DEFAULT_INTERVALS,
        *,
        averaged: bool = False,
    ) -> None:
        if int(intervals) != intervals or intervals < 2:
            raise ParameterError("intervals", "an integer >= 2", intervals)
        self.modal = modal
        self.cut = cut
        self.intervals = int(intervals)
        packed = modal.packed()
        self._omega = np.ascontiguousarray(packed[:, 0])
        self._zeta = np.ascontiguousarray(packed[:, 1])
        u = packed[:, 3:5]
        a_dir = cut.interval_directional(self.intervals)
        if averaged:
            a_dir = np.broadcast_to(a_dir.mean(axis=0), a_dir.shape)
        # W_i = M^-1 U^T A_i U (modal force per unit modal displacement per unit depth)
        self._w = np.ascontiguousarray(
            np.einsum("pi,mij,qj->mpq", u, a_dir, u) / packed[:, 2][None, :, None]
        )

    def monodromy(self, rpm: float, depth: float) -> F64:
        """The monodromy matrix at spindle speed ``rpm`` and axial depth ``depth`` [m]."""
        tau = self.cut.tooth_period(rpm)
        a = float(depth)
        if not math.isfinite(a) or a < 0.0:
            raise ParameterError("depth", "a finite depth >= 0 [m]", depth)
        return _monodromy(self._omega, self._zeta, self._w, a, tau / self.intervals)

    def multiplier(self, rpm: float, depth: float) -> Multiplier:
        """The critical multiplier (largest modulus) at ``rpm`` and ``depth``."""
        top = largest_eigenvalue(self.monodromy(rpm, depth))
        return Multiplier(float(abs(top)), float(np.angle(top)))

    def spectral_radius(self, rpm: float, depth: float) -> float:
        return self.multiplier(rpm, depth).modulus

    def chatter_frequency(self, rpm: float, depth: float) -> float:
        """The frequency [Hz] of the critical multiplier's harmonic series
        :math:`(\\arg\\mu/2\\pi + k)/\\tau` nearest the modes (the one a structure
        amplifies most: the largest receptance among the series' members)."""
        mult = self.multiplier(rpm, depth)
        tau = self.cut.tooth_period(require_positive("rpm", rpm))
        base = abs(mult.angle) / (2.0 * math.pi * tau)
        cands = [base + kk / tau for kk in range(0, 200)]
        cands += [-base + kk / tau for kk in range(1, 200)]
        gains = [np.max(np.abs(self.modal.frf(f))) for f in cands]
        return float(cands[int(np.argmax(gains))])


__all__ = ["DEFAULT_INTERVALS", "Multiplier", "SemiDiscretization", "largest_eigenvalue"]
