r"""Discrete linear filters, from one discretisation helper.

Every continuous transfer function in the project (Q(s), Q_RLS(s), high-pass filters,
the IMBDO Q-filter, ...) becomes a discrete filter through :func:`discretize`: the
bilinear (Tustin) transform, pre-warped at a chosen frequency so the discrete filter's
response matches the continuous one exactly there (for low-pass filters: the cut-off).

The filters run as transposed direct form II with an explicit state vector, so a block
step is ``y, z = filt.run(x, z)`` and a numba kernel can step sample by sample with
:func:`df2t_step`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from common.arrays import F64
from estimators.errors import ParameterError, require_positive


@dataclass(frozen=True, eq=False)
class DiscreteFilter:
    """A discrete filter ``B(z)/A(z)`` in powers of ``z^-1`` with ``a[0] == 1``."""

    b: F64
    a: F64
    sample_time: float

    @property
    def order(self) -> int:
        return len(self.a) - 1

    def initial_state(self, x0: float = 0.0) -> F64:
        """The state of a filter that has seen the constant input ``x0`` forever."""
        n = self.order
        z = np.zeros(max(n, 1))
        if n == 0 or x0 == 0.0:
            return z
        dc = float(np.sum(self.b) / np.sum(self.a))
        y0 = dc * x0
        # transposed DF-II steady state: z[i] = sum_{k>i} (b[k] x0 - a[k] y0)
        for i in range(n):
            z[i] = float(np.sum(self.b[i + 1 :]) * x0 - np.sum(self.a[i + 1 :]) * y0)
        return z

    def run(self, x: ArrayLike, z: F64 | None = None) -> tuple[F64, F64]:
        """Filter a block; returns the output and the new state (input state untouched)."""
        xa = np.ascontiguousarray(x, dtype=np.float64)
        zz = self.initial_state() if z is None else np.array(z, dtype=np.float64)
        y = np.empty_like(xa)
        _df2t_block(self.b, self.a, zz, xa, y)
        return y, zz

    def response(self, f_hz: ArrayLike) -> NDArray[np.complex128]:
        """Exact frequency response of the discrete filter at ``f_hz``."""
        f = np.asarray(f_hz, dtype=np.float64)
        zinv = np.exp(-2j * np.pi * f * self.sample_time)
        num = np.polyval(self.b[::-1], zinv)
        den = np.polyval(self.a[::-1], zinv)
        return np.asarray(num / den, dtype=np.complex128)


def discretize(
    num: ArrayLike, den: ArrayLike, sample_time: float, *, prewarp_hz: float | None = None
) -> DiscreteFilter:
    r"""Tustin discretisation of ``num(s)/den(s)`` (coefficients, highest power first).

    With ``prewarp_hz`` the substitution is :math:`s = \frac{\omega_p}{\tan(\omega_p T/2)}
    \frac{1 - z^{-1}}{1 + z^{-1}}`, which maps the frequency ``prewarp_hz`` exactly.
    """
    ts = require_positive("sample_time", sample_time)
    nyq = 0.5 / ts
    if prewarp_hz is not None:
        fp = require_positive("prewarp_hz", prewarp_hz)
        if fp >= nyq:
            raise ParameterError("prewarp_hz", f"a frequency below Nyquist {nyq:g} Hz", fp)
        wp = 2 * math.pi * fp
        k = wp / math.tan(wp * ts / 2)
    else:
        k = 2.0 / ts
    nb = np.atleast_1d(np.asarray(num, dtype=np.float64))
    na = np.atleast_1d(np.asarray(den, dtype=np.float64))
    if not (np.all(np.isfinite(nb)) and np.all(np.isfinite(na))) or na[0] == 0:
        raise ParameterError("den", "finite coefficients with a non-zero leading one", list(na))
    n = len(na) - 1
    if len(nb) - 1 > n:
        raise ParameterError("num", f"degree <= {n} (proper)", len(nb) - 1)
    nb = np.concatenate([np.zeros(n + 1 - len(nb)), nb])
    # sum_i c_i s^(n-i) with s = k (1-q)/(1+q), q = z^-1; multiply through by (1+q)^n
    pm = np.polynomial.polynomial
    b = np.zeros(n + 1)
    a = np.zeros(n + 1)
    for i in range(n + 1):
        p = n - i  # power of s
        term = pm.polymul(pm.polypow([1.0, -1.0], p), pm.polypow([1.0, 1.0], n - p)) * k**p
        b += nb[i] * term
        a += na[i] * term
    return DiscreteFilter(b=b / a[0], a=a / a[0], sample_time=ts)


def lowpass(cutoff_hz: float, sample_time: float, order: int = 1) -> DiscreteFilter:
    r"""Multiple-root low-pass :math:`Q(s) = \left(\frac{\omega_c}{s+\omega_c}\right)^n`.

    Pre-warped at the cut-off. Raises :class:`ParameterError` for a cut-off at or above
    Nyquist.
    """
    ts = require_positive("sample_time", sample_time)
    fc = require_positive("cutoff_hz", cutoff_hz)
    if fc >= 0.5 / ts:
        raise ParameterError("cutoff_hz", f"a frequency below Nyquist {0.5 / ts:g} Hz", fc)
    if int(order) != order or order < 1:
        raise ParameterError("order", "an integer >= 1", order)
    wc = 2 * math.pi * fc
    den = np.polynomial.polynomial.polypow([wc, 1.0], int(order))[::-1]
    return discretize([wc ** int(order)], den, ts, prewarp_hz=fc)


def highpass(cutoff_hz: float, sample_time: float) -> DiscreteFilter:
    r"""First-order high-pass :math:`s/(s+\omega_c)`, pre-warped at the cut-off."""
    ts = require_positive("sample_time", sample_time)
    fc = require_positive("cutoff_hz", cutoff_hz)
    if fc >= 0.5 / ts:
        raise ParameterError("cutoff_hz", f"a frequency below Nyquist {0.5 / ts:g} Hz", fc)
    wc = 2 * math.pi * fc
    return discretize([1.0, 0.0], [1.0, wc], ts, prewarp_hz=fc)


@njit(cache=True)
def df2t_step(b: F64, a: F64, z: F64, x: float) -> float:  # pragma: no cover
    """One sample of a transposed direct form II filter; updates ``z`` in place."""
    n = len(a) - 1
    if n == 0:
        return b[0] * x
    y = b[0] * x + z[0]
    # y = b0 x + z0; z_i <- b_{i+1} x - a_{i+1} y + z_{i+1} (transposed direct form II of B(z)/A(z))
    for i in range(n - 1):
        z[i] = b[i + 1] * x - a[i + 1] * y + z[i + 1]
    z[n - 1] = b[n] * x - a[n] * y
    return y


@njit(cache=True)
def _df2t_block(b: F64, a: F64, z: F64, x: F64, y: F64) -> None:  # pragma: no cover
    # y[k] = (B(z)/A(z)) x[k], one df2t_step per sample
    for k in range(len(x)):
        y[k] = df2t_step(b, a, z, x[k])
