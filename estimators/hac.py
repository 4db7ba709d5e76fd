r"""Least-squares covariance robust to the residuals' autocorrelation (Newey-West HAC).

A drive's residual is never white: the part of the effort no rigid model explains (a
friction that varies along the travel, a ripple periodic in position, the lag of a
filter) is correlated over many regression rows, and the plain least-squares covariance
:math:`s^2 (X^T X)^{-1}` is then too small (its half-widths measured 1.7-3.4x narrower
than this estimator's on EMPS, 1.5-2.2x on a simulated axis, covering 62-71 % instead of
95 %: docs/live-axis.md). The heteroskedasticity- and autocorrelation-
consistent estimator of Newey and West (1987) replaces :math:`s^2 X^T X` by the long-run
covariance of the scores :math:`u_t = w_t x_t e_t`:

.. math::

    \hat S = \sum_{|l| < L} \left(1 - \frac{|l|}{L}\right) \hat\Gamma_l,\qquad
    \hat\Gamma_l = \sum_t u_t u_{t-l}^T,\qquad
    \mathrm{Cov}\,\hat\theta = G^{-1} \hat S G^{-1},\quad G = \sum_t w_t x_t x_t^T

(Bartlett kernel, bandwidth ``L``; weighted least squares with weights :math:`w_t`, e.g.
exponential forgetting). The kernel sum is computed exactly as overlapping sums of ``L``
consecutive scores, :math:`\hat S = \frac{1}{L}\sum_j B_j B_j^T` with
:math:`B_j = \sum_{t=j}^{j+L-1} u_t` over the scores padded with ``L - 1`` zeros on each
side (each pair of rows ``l`` apart shares ``L - |l|`` windows): :math:`O(n p^2)`, not
:math:`O(n L p^2)`.

The bandwidth is Andrews' (1991) plug-in for the Bartlett kernel with an AR(1) fitted to
the residual: :math:`L = 1.1447\,(\alpha\,n)^{1/3}`,
:math:`\alpha = 4\rho^2 / ((1-\rho)^2 (1+\rho)^2)`, with ``n`` the effective number of
rows of the weights (Kish), bounded to ``[1, n/2]``.
"""

from __future__ import annotations

import math

import numpy as np

from common.arrays import F64
from estimators.errors import ParameterError

#: the largest lag-1 autocorrelation the bandwidth rule takes (beyond, L would exceed
#: the record: the residual is then a trend the model misses, and the interval says so
#: through L = n/2)
RHO_MAX = 0.98


def effective_rows(w: F64) -> float:
    """Kish's effective sample size of weights: :math:`(\\sum w)^2 / \\sum w^2`."""
    s2 = float(np.sum(w * w))
    return float(np.sum(w)) ** 2 / s2 if s2 > 0 else 0.0


def andrews_bandwidth(e: F64, n_eff: float) -> int:
    """Andrews' Bartlett bandwidth from the residual's lag-1 autocorrelation (module
    docstring), at least 1 and at most ``n_eff / 2``."""
    n = len(e)
    if n < 3:
        return 1
    ec = e - e.mean()
    den = float(ec @ ec)
    rho = float(ec[1:] @ ec[:-1]) / den if den > 0 else 0.0
    rho = min(max(rho, 0.0), RHO_MAX)
    alpha = 4.0 * rho * rho / ((1.0 - rho) ** 2 * (1.0 + rho) ** 2)
    # Andrews (1991) eq. (6.4), Bartlett kernel
    band = 1.1447 * (alpha * n_eff) ** (1.0 / 3.0)
    return int(min(max(math.ceil(band), 1), max(n_eff / 2.0, 1.0)))


def newey_west(scores: F64, bandwidth: int) -> F64:
    """:math:`\\hat S` of the module docstring from the scores (rows in time order)."""
    u = np.asarray(scores, dtype=np.float64)
    if u.ndim != 2:
        raise ParameterError("scores", "an (n, p) array", u.shape)
    L = int(bandwidth)
    if L < 1:
        raise ParameterError("bandwidth", "an integer >= 1", bandwidth)
    p = u.shape[1]
    pad = np.zeros((L - 1, p))
    c = np.cumsum(np.vstack([np.zeros((1, p)), pad, u, pad]), axis=0)
    # B_j: sums of L consecutive (padded) scores; (1/L) sum_j B_j B_j^T is the Bartlett sum
    b = c[L:] - c[:-L]
    return np.asarray(b.T @ b / L, dtype=np.float64)


def hac_covariance(
    x: F64, e: F64, w: F64 | None = None, bandwidth: int | None = None
) -> tuple[F64, F64, int]:
    """Weighted least squares' covariance, Newey-West and plain, and the bandwidth.

    Parameters
    ----------
    x : (n, p) array
        Regressors, rows in time order.
    e : (n,) array
        Residuals of the (weighted) least-squares fit.
    w : (n,) array, optional
        Row weights (default 1).
    bandwidth : int, optional
        Bartlett bandwidth; default :func:`andrews_bandwidth`.

    Returns
    -------
    cov_hac, cov_plain, bandwidth
        ``cov_plain`` is the least-squares covariance for white residuals,
        :math:`G^{-1} (\\sum_t w_t^2 x_t x_t^T e_t^2) G^{-1}` (the sandwich with
        :math:`L = 1`), the figure the robust one is compared with.

    Raises
    ------
    ParameterError
        Shapes that disagree, or a singular :math:`G`.
    """
    X = np.asarray(x, dtype=np.float64)
    E = np.asarray(e, dtype=np.float64)
    W = np.ones(len(E)) if w is None else np.asarray(w, dtype=np.float64)
    if X.ndim != 2 or X.shape[0] != len(E) or len(W) != len(E):
        raise ParameterError("x, e, w", "(n, p), (n,), (n,)", (X.shape, E.shape, W.shape))
    G = (X * W[:, None]).T @ X
    try:
        Gi = np.linalg.inv(G)
    except np.linalg.LinAlgError:
        raise ParameterError("x", "regressors of full column rank", "singular") from None
    u = X * (W * E)[:, None]
    L = andrews_bandwidth(E, effective_rows(W)) if bandwidth is None else int(bandwidth)
    S = newey_west(u, L)
    S0 = u.T @ u
    return Gi @ S @ Gi, Gi @ S0 @ Gi, L
