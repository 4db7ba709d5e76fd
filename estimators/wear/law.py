r"""Remaining tool life from a reduced wear law with on-line scale factors (seed 004 form).

Beyond seed 004. A straight line or a parabola through the flank wear cannot follow
the accelerating diffusive wear: before mid-life the curve is nearly straight (the
decelerating break-in tail hides the accelerating diffusion), after it the rate grows
by a third. This module extrapolates with the *form* of the paper's wear model instead,
re-expressed here because ``estimators`` may not import ``machine``. At constant speed
``v``, feed ``f`` and depth ``d`` seed004 (3)-(8) reduce to

.. math::

    \dot w_1 &= (-w_1 + \kappa F / (f d)) / \tau_1                         && (3)\\
    \dot w_2 &= k_2 \exp[-A / (\Theta_0 + c_\theta w_2)]                   && (4), (6)\\
    \dot C  &= g_c F \exp[-A_c / (273 + c_c F)]                            && (5), (7), (8)\\
    F &= F_s + s (w_1 + w_2) - C                                           && (8)

with the flank wear ``VB = w1 + w2`` and ``C = K14 w_c`` the force lost to the crater.
Off-line knowledge (the model's constants at the cutting condition): ``tau_1 = l0/v``,
``A = K3``, ``Theta_0 = 273 + K6 v^n1 f^n2``, ``c_theta = K7`` (seed004 (6) with
``n3 = 1``), ``g_c = K14 K4 v``, ``A_c = K5``, ``c_c = K8 v^n4 f^n5 d^n6``, and
``s = K13 d``. Fitted on line: the two scale factors ``kappa`` (abrasive, ``K1
cos(alpha_r)``) and ``k2`` (diffusive, ``K2 sqrt(v)``) — the magnitudes of the two wear
mechanisms, which change from tool to tool and batch to batch.

Fit. With ``z`` the measured force ``F/(f d)`` low-passed with ``tau_1`` (seed004 (3) is
linear in ``w1``, so ``w1 = kappa z`` exactly for a sharp tool) and ``W2(tau)`` the
diffusive land of a sharp tool after the "diffusion time" ``tau = k2 t`` (a table of
the integral of seed004 (4)), the flank wear of pass ``j`` is

.. math:: VB_j = \kappa \bar z_j + W_2(k_2 t_j),

linear in ``kappa`` and one-dimensional in ``log k2`` (a coarse and a fine grid, then
the vertex of a parabola).

Prediction. The fitted law is integrated forward (RK4) from the present state until
``VB`` reaches the limit.

Uncertainty (1 sigma), two parts combined in quadrature:

- parametric: the least-squares covariance of ``(kappa, log k2)`` (residual variance
  times ``(J^T J)^-1``), propagated to the crossing time by finite differences;
- model form: the off-line constants are not exact. The fit is repeated with the
  diffusion's activation temperature ``A`` at ``(1 +- activation_rel_sd)`` and with the
  crater law's gain at ``(1 +- crater_rel_sd)`` (each of which also changes the flank
  wear derived from the force), and half of each pair's spread of crossing times is
  one standard deviation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from common.arrays import F64
from estimators.errors import ParameterError, require_in, require_positive

#: flank-wear grid of the W2 table [mm]
_W_MAX = 2.0
_N_TABLE = 4001


@dataclass(frozen=True)
class WearLawParams:
    r"""Off-line constants of the reduced wear law at one cutting condition.

    Parameters
    ----------
    feed : float
        Feed the constants hold for [mm/rev]; passes at another feed are not predicted.
    depth : float
        Depth of cut [mm].
    tau_abrasive : float
        Break-in time constant ``l0 / v`` [min] (seed004 (3)).
    kappa0 : float
        Nominal abrasive scale ``K1 cos(alpha_r)`` [mm^3/N] (start of the fit).
    k2_0 : float
        Nominal diffusion rate ``K2 sqrt(v)`` [mm/min] (centre of the search).
    activation : float
        Activation temperature ``A = K3`` of the diffusive wear [K] (seed004 (4)).
    theta0 : float
        Tool-work temperature of the sharp tool ``273 + K6 v^n1 f^n2`` [K] (seed004 (6)).
    theta_per_wear : float
        Temperature rise per mm of diffusive land ``K7`` [K/mm] (seed004 (6), ``n3 = 1``).
    crater_gain : float
        ``K14 K4 v`` [1/min]: the crater's force-loss rate per newton (seed004 (5), (8)).
    crater_activation : float
        ``K5`` [K] (seed004 (5)).
    crater_theta_per_newton : float
        ``K8 v^n4 f^n5 d^n6`` [K/N] (seed004 (7)).
    activation_rel_sd, crater_rel_sd : float
        Relative 1-sigma uncertainty of ``A`` and of ``crater_gain`` (model-form part of
        the remaining-life S.D.). Choice: 5 % on an activation temperature (it sets the
        curvature of the wear curve; literature values for WC-Co on steel spread by
        more, but the fitted ``k2`` absorbs the level), 50 % on the crater gain.
    step : float
        RK4 step of the forward prediction [min].
    horizon : float
        Longest remaining life predicted [min]; beyond it the life is reported as inf.
    """

    feed: float
    depth: float
    tau_abrasive: float
    kappa0: float
    k2_0: float
    activation: float
    theta0: float
    theta_per_wear: float
    crater_gain: float = 0.0
    crater_activation: float = 0.0
    crater_theta_per_newton: float = 0.0
    activation_rel_sd: float = 0.05
    crater_rel_sd: float = 0.5
    step: float = 0.05
    horizon: float = 600.0

    def __post_init__(self) -> None:
        for name in (
            "feed",
            "depth",
            "tau_abrasive",
            "kappa0",
            "k2_0",
            "activation",
            "theta0",
            "step",
            "horizon",
        ):
            require_positive(name, getattr(self, name))
        for name in (
            "theta_per_wear",
            "crater_gain",
            "crater_activation",
            "crater_theta_per_newton",
        ):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v < 0.0:
                raise ParameterError(name, "a finite value >= 0", v)
        require_in("activation_rel_sd", self.activation_rel_sd, 0.0, 0.5, hi_open=True)
        require_in("crater_rel_sd", self.crater_rel_sd, 0.0, 1.0, hi_open=True)


def w2_table(activation: float, theta0: float, theta_per_wear: float) -> F64:
    r"""Diffusion time ``tau`` [mm] at which a sharp tool's diffusive land reaches ``w``.

    seed004 (4), (6): ``dw/dtau = exp(-A/(Theta_0 + c w))`` with ``tau = k2 t``, so
    ``tau(w) = int_0^w exp(A/(Theta_0 + c s)) ds`` (trapezoid on a fine grid of ``w``).
    Returns the ``tau`` grid matching :func:`w_grid`.
    """
    w = w_grid()
    inv_rate = np.exp(activation / (theta0 + theta_per_wear * w))
    tau = np.empty_like(w)
    tau[0] = 0.0
    tau[1:] = np.cumsum(0.5 * (inv_rate[1:] + inv_rate[:-1]) * np.diff(w))
    return tau


def w_grid() -> F64:
    """Grid of diffusive land of the W2 tables [mm]."""
    return np.linspace(0.0, _W_MAX, _N_TABLE)


@njit(cache=True)
def _law_rhs(
    x: F64,
    kappa: float,
    k2: float,
    q: F64,
    out: F64,
) -> None:
    # q = [tau1, fd, Fs, s, A, theta0, c_theta, g_c, A_c, c_c]
    # seed004 (8)
    F = q[2] + q[3] * (x[0] + x[1]) - x[2]
    # seed004 (3)
    out[0] = (-x[0] + kappa * F / q[1]) / q[0]
    # seed004 (4), (6) with n3 = 1
    out[1] = k2 * math.exp(-q[4] / (q[5] + q[6] * x[1]))
    # seed004 (5), (7), (8): force lost to the crater (K14 w_c)
    if q[7] > 0.0:
        out[2] = q[7] * F * math.exp(-q[8] / (273.0 + q[9] * F))
    else:
        out[2] = 0.0


@njit(cache=True)
def _crossing_time(
    x0: F64,
    kappa: float,
    k2: float,
    q: F64,
    vb_limit: float,
    h: float,
    horizon: float,
) -> float:
    """Time from now until w1 + w2 reaches ``vb_limit`` (inf beyond ``horizon``)."""
    x = x0.copy()
    if x[0] + x[1] >= vb_limit:
        return 0.0
    k1 = np.empty(3)
    k2v = np.empty(3)
    k3 = np.empty(3)
    k4 = np.empty(3)
    xt = np.empty(3)
    t = 0.0
    # RK4 on dx/dt = f(x) (the reduced law, seed004 (3)-(8)) until w1 + w2 >= vb_limit
    while t < horizon:
        _law_rhs(x, kappa, k2, q, k1)
        for i in range(3):
            xt[i] = x[i] + 0.5 * h * k1[i]
        _law_rhs(xt, kappa, k2, q, k2v)
        for i in range(3):
            xt[i] = x[i] + 0.5 * h * k2v[i]
        _law_rhs(xt, kappa, k2, q, k3)
        for i in range(3):
            xt[i] = x[i] + h * k3[i]
        _law_rhs(xt, kappa, k2, q, k4)
        vb0 = x[0] + x[1]
        for i in range(3):
            x[i] += h / 6.0 * (k1[i] + 2.0 * k2v[i] + 2.0 * k3[i] + k4[i])
        vb1 = x[0] + x[1]
        if vb1 >= vb_limit:
            # linear interpolation inside the step
            return t + h * (vb_limit - vb0) / max(vb1 - vb0, 1e-300)
        t += h
    return math.inf


class WearLawPredictor:
    """Fits the two scale factors to a flank-wear history and predicts the remaining life.

    Stateless between calls (the history is the caller's state); the W2 tables of the
    nominal and the perturbed activation temperatures are built once here.
    """

    def __init__(self, params: WearLawParams) -> None:
        self.params = params
        p = params
        self._w = w_grid()
        self._tables = {
            s: w2_table(p.activation * (1.0 + s * p.activation_rel_sd), p.theta0, p.theta_per_wear)
            for s in (-1, 0, 1)
        }

    def _q(self, force_sharp: float, s: float, act_sign: int, crater_scale: float) -> F64:
        p = self.params
        return np.array(
            [
                p.tau_abrasive,
                p.feed * p.depth,
                force_sharp,
                s,
                p.activation * (1.0 + act_sign * p.activation_rel_sd),
                p.theta0,
                p.theta_per_wear,
                p.crater_gain * crater_scale,
                p.crater_activation,
                p.crater_theta_per_newton,
            ]
        )

    def crater_rate(self, force: float | F64) -> float | F64:
        """Force lost to the crater per minute at ``force`` [N/min] (seed004 (5), (7), (8))."""
        p = self.params
        F = np.asarray(force, dtype=np.float64)
        if p.crater_gain == 0.0:
            return np.zeros_like(F) if F.ndim else 0.0
        r = (
            p.crater_gain
            * F
            * np.exp(-p.crater_activation / (273.0 + p.crater_theta_per_newton * F))
        )
        return r if F.ndim else float(r)

    def _w2(self, tau: F64, act_sign: int) -> F64:
        return np.interp(tau, self._tables[act_sign], self._w)

    def _fit(self, t: F64, y: F64, zbar: F64, act_sign: int) -> tuple[float, float, float]:
        """Least squares of ``y = kappa zbar + W2(k2 t)`` over ``kappa`` and ``u = log k2``."""
        table = self._tables[act_sign]
        zz = float(zbar @ zbar)

        def sse_of(u: F64) -> tuple[F64, F64]:
            tau = np.exp(u)[:, None] * t[None, :]
            r = y[None, :] - np.interp(tau.ravel(), table, self._w).reshape(tau.shape)
            kap = (r @ zbar) / zz
            e = r - kap[:, None] * zbar[None, :]
            return np.einsum("ij,ij->i", e, e), kap

        # coarse grid over +-3 decades of k2, a fine grid around its best point, then the
        # vertex of the parabola through the fine grid's best three points
        u = math.log(self.params.k2_0)
        half = math.log(1e3)
        for _ in range(2):
            grid = u + np.linspace(-half, half, 61)
            sse, _ = sse_of(grid)
            i = int(np.clip(np.argmin(sse), 1, len(grid) - 2))
            u, half = float(grid[i]), 2.0 * (grid[1] - grid[0])
        f0, f1, f2 = sse[i - 1], sse[i], sse[i + 1]
        h = grid[1] - grid[0]
        den = f0 - 2.0 * f1 + f2
        if den > 0.0:
            u += float(np.clip(0.5 * h * (f0 - f2) / den, -h, h))
        s2, kap = sse_of(np.array([u]))
        return float(kap[0]), u, float(s2[0])

    def _rate(self, kappa: float, k2: float, x: F64, q: F64) -> float:
        out = np.empty(3)
        _law_rhs(x, kappa, k2, q, out)
        return float(out[0] + out[1])

    def predict(
        self,
        t_mid: F64,
        vb: F64,
        zbar: F64,
        crater_mid: F64,
        *,
        t_now: float,
        z_now: float,
        crater_now: float,
        force_sharp: float,
        force_per_flank_wear: float,
        vb_limit: float,
        with_sd: bool = True,
    ) -> tuple[float, float, float, float]:
        r"""Fit the history and predict the remaining life.

        Parameters
        ----------
        t_mid, vb, zbar, crater_mid : arrays
            Per pass: mid-time [min], flank wear from the force [mm], pass mean of the
            low-passed ``F/(f d)`` [N/mm^2], force lost to the crater at mid-pass [N]
            (nominal crater law; ``vb`` already contains ``crater_mid / s``).
        t_now, z_now, crater_now : float
            Time, low-passed ``F/(f d)`` and crater force loss at the end of the last
            pass.
        force_sharp : float
            Force of the sharp tool ``F_s`` [N] (seed004 (25)).
        force_per_flank_wear : float
            ``s`` [N/mm].
        vb_limit : float
            Tool-life criterion [mm].
        with_sd : bool
            False: skip the spread of the remaining life (returned as NaN); the other
            three values are the same.

        Returns
        -------
        vb_fit, rate, remaining, remaining_sd : float
            Fitted flank wear now [mm], its rate [mm/min], remaining life and its 1-sigma
            S.D. [min].
        """
        p = self.params
        s = force_per_flank_wear

        def fit_predict(
            act_sign: int, cscale: float
        ) -> tuple[float, float, float, F64, F64, float]:
            # the flank wear from the force depends on the crater law assumed (seed004 (8))
            y = vb + (cscale - 1.0) * crater_mid / s
            kap, u, sse = self._fit(t_mid, y, zbar, act_sign)
            w2_now = float(self._w2(np.array([math.exp(u) * t_now]), act_sign)[0])
            x0 = np.array([kap * z_now, w2_now, cscale * crater_now])
            q = self._q(force_sharp, s, act_sign, cscale)
            rem = _crossing_time(x0, kap, math.exp(u), q, vb_limit, p.step, p.horizon)
            return kap, u, sse, x0, q, rem

        kap, u, sse, x0, q, rem = fit_predict(0, 1.0)
        k2 = math.exp(u)
        vb_fit = float(x0[0] + x0[1])
        rate = self._rate(kap, k2, x0, q)
        if not math.isfinite(rem):
            return vb_fit, rate, math.inf, math.inf
        if not with_sd:
            return vb_fit, rate, rem, math.nan
        # parametric part: LS covariance of (kappa, u = log k2), t* by finite differences
        tau = k2 * t_mid
        w2 = self._w2(tau, 0)
        J = np.column_stack(
            [zbar, np.exp(-p.activation / (p.theta0 + p.theta_per_wear * w2)) * tau]
        )
        JtJ = J.T @ J
        var_par = math.inf
        if np.linalg.cond(JtJ) < 1e14:
            C = sse / max(len(t_mid) - 2, 1) * np.linalg.inv(JtJ)
            steps = (
                max(math.sqrt(max(C[0, 0], 0.0)), 1e-9 * kap),
                max(math.sqrt(max(C[1, 1], 0.0)), 1e-9),
            )
            grad = np.zeros(2)
            for i, dd in enumerate(steps):
                kk, uu = (kap + dd, u) if i == 0 else (kap, u + dd)
                w2k = float(self._w2(np.array([math.exp(uu) * t_now]), 0)[0])
                xx = np.array([kk * z_now, w2k, crater_now])
                r_plus = _crossing_time(xx, kk, math.exp(uu), q, vb_limit, p.step, p.horizon)
                grad[i] = (r_plus - rem) / dd
            if np.all(np.isfinite(grad)):
                var_par = float(grad @ C @ grad)
        # model-form part: half the spread of each +-1 sigma pair of off-line constants
        var_form = 0.0
        for lo, hi in (
            ((-1, 1.0), (1, 1.0)),
            ((0, 1.0 - p.crater_rel_sd), (0, 1.0 + p.crater_rel_sd)),
        ):
            r_lo, r_hi = fit_predict(*lo)[5], fit_predict(*hi)[5]
            var_form += (0.5 * (r_hi - r_lo)) ** 2 if math.isfinite(r_lo + r_hi) else math.inf
        return vb_fit, rate, rem, math.sqrt(var_par + var_form)


__all__ = ["WearLawParams", "WearLawPredictor", "w2_table", "w_grid"]
