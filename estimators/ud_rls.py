r"""Recursive least squares with a forgetting factor (seed004 (20)-(21)).

Two implementations of the same recursion:

- :func:`covariance_update`: the covariance form as the paper writes it,

  .. math::
      \hat\theta(k) &= \hat\theta(k-1) + \frac{P\phi}{\beta + \phi^T P \phi}
                       [y(k) - \phi^T\hat\theta(k-1)]                     && (20)\\
      P &\leftarrow \frac1\beta\left[P - \frac{P\phi\phi^T P}{\beta + \phi^T P\phi}\right]
                                                                          && (21)

- :func:`ud_update`: the same update on the factors :math:`P = U D U^T` (U unit upper
  triangular, D diagonal), Bierman's measurement update, which the paper used (its
  ref. [32]) for its numerical robustness: P stays symmetric and positive definite by
  construction.

Both are numba kernels usable inside other kernels; :class:`ForgettingRLS` is
the block-step unit around them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from common.arrays import F64
from estimators.errors import ParameterError, require_in, require_positive


@njit(cache=True)
def covariance_update(
    theta: F64, P: F64, phi: F64, y: float, beta: float
) -> float:  # pragma: no cover - compiled
    """One step of seed004 (20)-(21) in place; returns the a-priori residual."""
    n = len(theta)
    Pphi = P @ phi
    den = beta + phi @ Pphi
    e = float(y - phi @ theta)
    # theta <- theta + P phi e / (beta + phi^T P phi), e = y - phi^T theta
    # seed004 (20)
    for i in range(n):
        theta[i] += Pphi[i] / den * e
    # P <- (P - P phi phi^T P / (beta + phi^T P phi)) / beta
    # seed004 (21)
    for i in range(n):
        for j in range(n):
            P[i, j] = (P[i, j] - Pphi[i] * Pphi[j] / den) / beta
    return e


@njit(cache=True)
def ud_update(
    theta: F64, U: F64, D: F64, phi: F64, y: float, beta: float
) -> float:  # pragma: no cover - compiled
    """seed004 (20)-(21) on the factors ``P = U diag(D) U^T`` (Bierman), in place.

    Returns the a-priori residual.
    """
    n = len(theta)
    f = U.T @ phi
    v = D * f
    K = np.zeros(n)
    # seed004 (21) denominator beta + phi^T P phi, accumulated column by column
    alpha = beta + v[0] * f[0]
    D[0] = D[0] * beta / alpha
    K[0] = v[0]
    # Bierman: U, D of P - P phi phi^T P / alpha, alpha_j = beta + sum_{i<=j} v_i f_i, f = U^T phi,
    #  v = D f
    for j in range(1, n):
        alpha_new = alpha + v[j] * f[j]
        D[j] = D[j] * alpha / alpha_new
        lam = -f[j] / alpha
        for i in range(j):
            uij = U[i, j]
            U[i, j] = uij + K[i] * lam
            K[i] = K[i] + v[j] * uij
        K[j] = v[j]
        alpha = alpha_new
    e = float(y - phi @ theta)
    # seed004 (20): the gain P phi / (beta + phi^T P phi) is K / alpha
    for i in range(n):
        theta[i] += K[i] / alpha * e
    # seed004 (21): the 1/beta of the forgetting factor
    for i in range(n):
        D[i] = D[i] / beta
    return e


@njit(cache=True)
def _rls_block(
    theta: F64,
    P: F64,
    U: F64,
    D: F64,
    Phi: F64,
    y: F64,
    beta: float,
    use_ud: bool,
    thetas: F64,
    resid: F64,
) -> None:  # pragma: no cover
    # theta[k] = RLS-with-forgetting update of theta[k-1] with (Phi[k], y[k]) (seed004 (20)-(21))
    for k in range(len(y)):
        if use_ud:
            resid[k] = ud_update(theta, U, D, Phi[k], y[k], beta)
        else:
            resid[k] = covariance_update(theta, P, Phi[k], y[k], beta)
        thetas[k] = theta


@dataclass(frozen=True)
class ForgettingRLSParams:
    """Parameters of :class:`ForgettingRLS`.

    Parameters
    ----------
    n : int
        Number of parameters.
    forgetting : float
        beta of seed004 (20)-(21), in (0, 1].
    p0 : float
        Initial covariance ``p0 * I``, > 0.
    method : {"ud", "plain"}
        U-D factorised (Bierman) or covariance form.
    """

    n: int
    forgetting: float = 0.95
    p0: float = 1e3
    method: Literal["ud", "plain"] = "ud"

    def __post_init__(self) -> None:
        if int(self.n) != self.n or self.n < 1:
            raise ParameterError("n", "an integer >= 1", self.n)
        require_in("forgetting", self.forgetting, 0.0, 1.0, lo_open=True)
        require_positive("p0", self.p0)
        if self.method not in ("ud", "plain"):
            raise ParameterError("method", "'ud' or 'plain'", self.method)


@dataclass(frozen=True, eq=False)
class ForgettingRLSState:
    """Estimate and covariance (as U-D factors and as the full matrix)."""

    theta: F64
    P: F64
    U: F64
    D: F64

    def covariance(self) -> F64:
        """The covariance P (from the factors when the U-D form is used)."""
        return np.asarray(self.U @ np.diag(self.D) @ self.U.T)


@dataclass(frozen=True, eq=False)
class ForgettingRLSRecord:
    """Per-sample outputs of a block: estimates and a-priori residuals."""

    theta: F64  # (n_samples, n)
    residual: F64  # (n_samples,)


class ForgettingRLS:
    """Block-step RLS with forgetting, seed004 (20)-(21), plain or U-D factorised."""

    def __init__(self, params: ForgettingRLSParams) -> None:
        self.params = params

    def initial_state(self, theta0: ArrayLike | None = None) -> ForgettingRLSState:
        n = self.params.n
        th = np.zeros(n) if theta0 is None else np.asarray(theta0, dtype=np.float64).copy()
        if th.shape != (n,):
            raise ParameterError("theta0", f"an array of shape ({n},)", th.shape)
        return ForgettingRLSState(
            theta=th, P=np.eye(n) * self.params.p0, U=np.eye(n), D=np.full(n, self.params.p0)
        )

    def step(
        self, state: ForgettingRLSState, phi: ArrayLike, y: ArrayLike
    ) -> tuple[ForgettingRLSState, ForgettingRLSRecord]:
        """Run the recursion over a block of regressors ``phi`` (m, n) and outputs ``y``."""
        Phi = np.ascontiguousarray(phi, dtype=np.float64)
        ya = np.ascontiguousarray(y, dtype=np.float64).reshape(-1)
        n = self.params.n
        if Phi.ndim != 2 or Phi.shape[1] != n or Phi.shape[0] != len(ya):
            raise ParameterError("phi", f"an array of shape ({len(ya)}, {n})", Phi.shape)
        th, P, U, D = (state.theta.copy(), state.P.copy(), state.U.copy(), state.D.copy())
        thetas = np.empty((len(ya), n))
        resid = np.empty(len(ya))
        use_ud = self.params.method == "ud"
        _rls_block(th, P, U, D, Phi, ya, float(self.params.forgetting), use_ud, thetas, resid)
        if use_ud:
            P = U @ np.diag(D) @ U.T
        new = ForgettingRLSState(theta=th, P=P, U=U, D=D)
        return new, ForgettingRLSRecord(theta=thetas, residual=resid)


__all__ = [
    "ForgettingRLS",
    "ForgettingRLSParams",
    "ForgettingRLSRecord",
    "ForgettingRLSState",
    "covariance_update",
    "ud_update",
]
