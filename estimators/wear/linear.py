r"""Linear models for the wear observer (seed004 appendix and (11)-(16)).

- :func:`linearise_along_path`: the appendix's "gross" linearisation, seed004 (A9)-(A14):
  the Jacobians of a nonlinear model averaged over ``n'`` intervals of the straight
  path from the origin to an end point of the trajectory.
- :func:`zoh`: zero-order-hold discretisation, seed004 (11)-(12).
- :func:`transfer_function`: the :math:`a_i, b_i` of seed004 (13).
- :func:`observer_form` and :func:`observer_transform`: seed004 (15)-(16) and the matrix
  :math:`T` of seed004 (14), :math:`x = T x_0`.

The estimators never see the simulator: the nonlinear model enters only as a callable
returning its partial derivatives.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from common.arrays import F64
from common.linalg import expm
from estimators.errors import ParameterError, require_positive

#: ``jacobian(x, u) -> (df/dx (n, n), df/du (n,), dg/dx (n,), dg/du)``
Jacobian = Callable[[F64, float], tuple[F64, F64, F64, float]]


@dataclass(frozen=True, eq=False)
class LinearModel:
    """Continuous linear model seed004 (A7)-(A8): ``x' = A x + b u``, ``y = c x + D u``."""

    A: F64
    b: F64
    c: F64
    D: float


@dataclass(frozen=True, eq=False)
class DiscreteModel:
    """Discrete model seed004 (11)-(12): ``x(k+1) = P x(k) + q u(k)``, ``y = c x + D u``."""

    P: F64
    q: F64
    c: F64
    D: float
    sample_time: float


def linearise_along_path(
    jacobian: Jacobian,
    x_end: ArrayLike,
    u_end: float,
    *,
    n_intervals: int = 200,
    input_path: Literal["hold", "ramp"] = "hold",
    static_gain: float | None = None,
) -> LinearModel:
    r"""Average the Jacobians along the path from the origin, seed004 (A9)-(A14).

    .. math:: A = \frac{1}{n'} \sum_{i=0}^{n'-1}
              \left.\frac{\partial f'}{\partial x}\right|_{x = i\Delta x,\ u = u_i},
              \quad \Delta x = x_1/n' \quad \text{(A9), (A11)}

    and likewise ``b`` (A12), ``c`` (A13) and ``D`` (A14).

    Parameters
    ----------
    jacobian : callable
        ``jacobian(x, u)`` returning ``(df/dx, df/du, dg/dx, dg/du)``.
    x_end, u_end : array_like, float
        The end point :math:`x_1, u_1` on the trajectory.
    n_intervals : int
        :math:`n'` (the paper uses 200).
    input_path : {"hold", "ramp"}
        ``"ramp"``: :math:`u_i = i\,u_1/n'` as seed004 (A10) writes. ``"hold"``: the input
        stays at :math:`u_1` while the state runs from the origin. Choice: "hold" is the
        default because the wear model's seed004 (3) divides by the feed, so its Jacobian
        does not exist at u = 0 (the first point of the ramp) and its average over the
        ramp diverges as n' grows; the feed is a step applied at the start of the cut,
        so the physical trajectory from the sharp tool runs at u = u_1 anyway.
    static_gain : float, optional
        Use this D instead of seed004 (A14) (e.g. the secant ``y(0)/u(0)`` of seed004 (25)).
    """
    if int(n_intervals) != n_intervals or n_intervals < 1:
        raise ParameterError("n_intervals", "an integer >= 1", n_intervals)
    if input_path not in ("hold", "ramp"):
        raise ParameterError("input_path", "'hold' or 'ramp'", input_path)
    x1 = np.asarray(x_end, dtype=np.float64).reshape(-1)
    u1 = float(u_end)
    n = int(n_intervals)
    # seed004 (A9), (A10)
    dx = x1 / n
    du = u1 / n
    nx = len(x1)
    A = np.zeros((nx, nx))
    b = np.zeros(nx)
    c = np.zeros(nx)
    D = 0.0
    for i in range(n):
        u_i = i * du if input_path == "ramp" else u1
        jx, ju, gx, gu = jacobian(i * dx, u_i)
        A += jx
        b += ju
        c += gx
        D += gu
    # seed004 (A11)-(A14)
    return LinearModel(
        A=A / n, b=b / n, c=c / n, D=float(D / n) if static_gain is None else float(static_gain)
    )


def zoh(model: LinearModel, sample_time: float) -> DiscreteModel:
    r"""Zero-order-hold discretisation, seed004 (11)-(12).

    :math:`P = e^{AT}`, :math:`q = \int_0^T e^{As}\,ds\; b`, from one matrix exponential
    of the augmented matrix ``[[A, b], [0, 0]]``.
    """
    ts = require_positive("sample_time", sample_time)
    n = len(model.b)
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = model.A
    M[:n, n] = model.b
    E = expm(M * ts)
    return DiscreteModel(
        P=E[:n, :n], q=E[:n, n].copy(), c=model.c.copy(), D=model.D, sample_time=ts
    )


def transfer_function(model: DiscreteModel) -> tuple[F64, F64]:
    r"""The :math:`a_i, b_i` of seed004 (13) (``b_0 = 0``, ``m = n``).

    .. math:: \frac{Y(z)}{U(z)} - D = \frac{\sum_{j=1}^n b_j z^{-j}}
              {1 + \sum_{i=1}^n a_i z^{-i}}

    with :math:`a` from the characteristic polynomial of :math:`P` and :math:`b` from
    the Markov parameters :math:`h_j = c^T P^{j-1} q`: :math:`b_j = h_j + \sum_{i<j}
    a_i h_{j-i}`.
    """
    P, q, c = model.P, model.q, model.c
    n = len(q)
    a = np.poly(P)[1:].real.astype(np.float64)
    h = np.empty(n)
    Pk = np.eye(n)
    for j in range(n):
        h[j] = float(c @ Pk @ q)
        Pk = Pk @ P
    b = np.empty(n)
    for j in range(n):
        b[j] = h[j] + sum(a[i] * h[j - 1 - i] for i in range(j))
    return a, b


def observer_form(a: ArrayLike, b: ArrayLike) -> tuple[F64, F64, F64]:
    """Matrices of the observer form, seed004 (15)-(16): ``(A_o, b_o, c_o)``."""
    aa = np.asarray(a, dtype=np.float64).reshape(-1)
    bb = np.asarray(b, dtype=np.float64).reshape(-1)
    n = len(aa)
    Ao = np.zeros((n, n))
    # seed004 (15): first column -a, ones on the super-diagonal
    Ao[:, 0] = -aa
    Ao[: n - 1, 1:] = np.eye(n - 1)
    co = np.zeros(n)
    # seed004 (16)
    co[0] = 1.0
    return Ao, bb.copy(), co


def observer_transform(model: DiscreteModel) -> F64:
    r"""The matrix :math:`T` of seed004 (14), :math:`x = T x_0`.

    Both realisations share the output, so their observability matrices satisfy
    :math:`O_o = O\,T`, hence :math:`T = O^{-1} O_o`.
    """
    a, b = transfer_function(model)
    Ao, _, co = observer_form(a, b)
    n = len(a)
    O = np.empty((n, n))
    Oo = np.empty((n, n))
    r = model.c.copy()
    ro = co.copy()
    for i in range(n):
        O[i] = r
        Oo[i] = ro
        r = r @ model.P
        ro = ro @ Ao
    if np.linalg.matrix_rank(O) < n:
        raise ParameterError("model", "an observable (P, c) pair", "rank-deficient O")
    return np.asarray(np.linalg.solve(O, Oo), dtype=np.float64)


__all__ = [
    "DiscreteModel",
    "Jacobian",
    "LinearModel",
    "linearise_along_path",
    "observer_form",
    "observer_transform",
    "transfer_function",
    "zoh",
]
