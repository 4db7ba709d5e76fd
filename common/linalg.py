"""Small dense linear algebra shared by the machine models and the estimators (no scipy
on the hot path).

:func:`expm` is scaling and squaring of a Taylor series; it agrees with
``scipy.linalg.expm`` to ~1e-13 on the plants here (tested) and costs ~0.1 ms for a 6x6
matrix, where scipy's costs ~10 ms on this machine (its Pade path goes through threaded
BLAS) — which matters because the live loop re-discretises whenever a workpiece's
inertia changes. It lives in :mod:`common` so that machine and estimators share one copy
and still import nothing of each other.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from common.arrays import F64


def expm(m: ArrayLike) -> F64:
    """Matrix exponential of a small matrix (scaling and squaring of a Taylor series)."""
    a = np.asarray(m, dtype=np.float64)
    norm = float(np.max(np.sum(np.abs(a), axis=1))) if a.size else 0.0
    j = max(0, math.ceil(math.log2(norm / 0.25))) if norm > 0.25 else 0
    a = a / 2.0**j
    out = np.eye(a.shape[0])
    term = np.eye(a.shape[0])
    for k in range(1, 20):
        term = term @ a / k
        out = out + term
        if float(np.max(np.abs(term))) <= 1e-18 * float(np.max(np.abs(out))):
            break
    for _ in range(j):
        out = out @ out
    return np.asarray(out, dtype=np.float64)


def zoh(f: ArrayLike, g: ArrayLike, h: float) -> tuple[F64, F64]:
    r"""Zero-order-hold discretisation of :math:`\dot x = F x + G u` over ``h``:
    :math:`e^{F h}` and :math:`\int_0^h e^{F r}\,dr\,G` (``G`` keeps its shape), from
    one exponential of the augmented matrix."""
    fa = np.asarray(f, dtype=np.float64)
    ga = np.asarray(g, dtype=np.float64)
    g2 = ga.reshape(fa.shape[0], -1)
    n, m = g2.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n] = fa
    big[:n, n:] = g2
    e = expm(big * h)
    return np.ascontiguousarray(e[:n, :n]), np.ascontiguousarray(e[:n, n:]).reshape(ga.shape)
