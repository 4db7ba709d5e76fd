r"""Adaptive observer for tool wear from the cutting force (seed 004, section 4).

Per sample ``k`` (feed ``u(k)`` [mm/rev], cutting force ``y(k)`` [N]):

1. Static gain ``D`` (seed004 (25)): at the start of the cut (sharp tool, first sample with
   a feed) ``D = y(0)/u(0)``; on a feed change, re-estimated from the ratio of the
   change in output to the change in input (section 4.3.1).
2. Static output removed (seed004 (24)): ``dy(k) = y(k) - D u(k)`` (plus the offset that
   keeps ``dy`` continuous across a feed change, see :func:`_observer_block`).
3. RLS with forgetting (seed004 (20)-(21)), U-D factorised, on the scaled regressor and
   parameters of seed004 (26)-(29), projected onto the constraints of Table 2.
4. Deadbeat state observer (seed004 (17)-(19), ``g_i = -a_i``) in observer form, with the
   current estimates.
5. Optionally the observer-form states mapped back to the physical wear states with a
   transformation ``T`` of seed004 (14) known off line (:class:`WearObserverParams.transform`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from common.arrays import F64
from estimators.errors import ParameterError, require_in, require_positive
from estimators.ud_rls import covariance_update, ud_update

#: Table 2 of seed 004: bounds of a1, a2, a3 and of the ratios b2/b1, b3/b1
TABLE2_A_BOUNDS = ((-3.2, -2.8), (2.8, 3.2), (-1.2, -0.8))
TABLE2_B_RATIO_BOUNDS = ((-2.5, -1.5), (0.8, 1.2))

# Index of each entry of WearObserverState.misc: the static gain D and the offset of
# seed004 (24)-(25), the previous sample's feed u and force y, whether the cut has started
# (1.0) and the samples so far
MISC_D, MISC_OFFSET, MISC_FEED, MISC_FORCE, MISC_STARTED, MISC_SAMPLES = range(6)


@dataclass(frozen=True)
class WearConstraints:
    """Parameter constraints of Table 2: boxes on a_i, on b_2/b_1 and b_3/b_1."""

    a_bounds: tuple[tuple[float, float], ...] = TABLE2_A_BOUNDS
    b_ratio_bounds: tuple[tuple[float, float], ...] = TABLE2_B_RATIO_BOUNDS

    def __post_init__(self) -> None:
        if len(self.a_bounds) != 3 or len(self.b_ratio_bounds) != 2:
            raise ParameterError(
                "constraints",
                "3 bounds on a and 2 on b ratios",
                (len(self.a_bounds), len(self.b_ratio_bounds)),
            )
        for name, bounds in (("a_bounds", self.a_bounds), ("b_ratio_bounds", self.b_ratio_bounds)):
            for lo, hi in bounds:
                if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                    raise ParameterError(name, "finite (lo, hi) pairs with lo < hi", (lo, hi))

    def as_array(self) -> F64:
        return np.array([list(b) for b in (*self.a_bounds, *self.b_ratio_bounds)], dtype=np.float64)

    def violations(self, theta: ArrayLike) -> list[str]:
        """Names of the constraints the unscaled ``theta`` (a1..a3, b1..b3) violates."""
        th = np.asarray(theta, dtype=np.float64)
        out = []
        for i, (lo, hi) in enumerate(self.a_bounds):
            if not lo <= th[i] <= hi:
                out.append(f"a{i + 1} in [{lo:g}, {hi:g}]")
        if th[3] <= 0:
            out.append("b1 > 0 (the ratio bounds of Table 2 assume it)")
        else:
            for j, (lo, hi) in enumerate(self.b_ratio_bounds):
                r = th[4 + j] / th[3]
                if not lo <= r <= hi:
                    out.append(f"b{j + 2}/b1 in [{lo:g}, {hi:g}]")
        return out


@dataclass(frozen=True, eq=False)
class WearObserverParams:
    """Parameters of :class:`AdaptiveWearObserver`.

    Parameters
    ----------
    theta0 : array_like
        Initial estimate ``[a1, a2, a3, b1, b2, b3]`` (unscaled); must satisfy the
        constraints.
    forgetting : float
        beta of seed004 (20)-(21), in (0, 1]; the paper uses 0.95.
    scale_output, scale_input : float
        s1 and s2 of seed004 (28)-(29), non-zero.
    p0 : float or array_like of 6
        Initial covariance of the scaled parameters, ``diag(p0)``. The paper gives no
        value. Choice: a small variance on the a's (the poles near z = 1 are known from
        the design linearisation) and a large one on the b's, which the initial step of
        the feed identifies in the first three samples (section 4.3.1.2).
    p_max : float
        Anti-windup: when the largest diagonal entry of P exceeds this, P is scaled down
        to it. Choice: with beta = 0.95 and a constant feed the regressor carries no new
        information and P grows as 0.95^-k (overflow after ~14 000 samples); the paper
        does not say how it avoided this.
    constraints : WearConstraints or None
        Table 2 (default) or None for an unconstrained RLS.
    transform : (3, 3) array or None
        ``T`` of seed004 (14) (``x = T x0``) known off line, to map the observer-form
        states to flank (``x1 + x2``) and crater (``x3``) wear.
    use_ud : bool
        U-D factorised covariance update (True, the paper's choice) or the plain one.
    feed_tolerance : float
        A relative feed change larger than this is a feed change (D re-estimated).
    """

    theta0: F64
    forgetting: float = 0.95
    scale_output: float = 10.0
    scale_input: float = 100.0
    p0: float | tuple[float, ...] = (1e-6, 1e-6, 1e-6, 100.0, 100.0, 100.0)
    p_max: float = 1e4
    constraints: WearConstraints | None = field(default_factory=WearConstraints)
    transform: F64 | None = None
    use_ud: bool = True
    feed_tolerance: float = 1e-6

    def __post_init__(self) -> None:
        th = np.asarray(self.theta0, dtype=np.float64).reshape(-1)
        if th.shape != (6,) or not np.all(np.isfinite(th)):
            raise ParameterError("theta0", "6 finite values [a1, a2, a3, b1, b2, b3]", self.theta0)
        object.__setattr__(self, "theta0", th)
        require_in("forgetting", self.forgetting, 0.0, 1.0, lo_open=True)
        for name in ("scale_output", "scale_input"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v == 0.0:
                raise ParameterError(name, "a finite non-zero scale factor", v)
        p0 = np.broadcast_to(np.asarray(self.p0, dtype=np.float64), (6,)).copy()
        if not np.all(np.isfinite(p0)) or np.any(p0 <= 0.0):
            raise ParameterError("p0", "initial variances > 0 (a scalar or 6 values)", self.p0)
        object.__setattr__(self, "p0", tuple(float(v) for v in p0))
        require_positive("p_max", self.p_max)
        require_positive("feed_tolerance", self.feed_tolerance)
        if self.constraints is not None:
            bad = self.constraints.violations(th)
            if bad:
                raise ParameterError(
                    "theta0",
                    f"an initial estimate inside the constraints ({'; '.join(bad)} violated)",
                    th.tolist(),
                )
        if self.transform is not None:
            T = np.asarray(self.transform, dtype=np.float64)
            if T.shape != (3, 3) or not np.all(np.isfinite(T)):
                raise ParameterError("transform", "a finite 3x3 matrix", T.shape)
            object.__setattr__(self, "transform", T)


@dataclass(frozen=True, eq=False)
class WearObserverState:
    """Explicit state of the adaptive observer."""

    theta: F64  # scaled parameters seed004 (29)
    P: F64  # covariance (plain form)
    U: F64  # U-D factors
    Dd: F64
    dy_hist: F64  # dy(k-1), dy(k-2), dy(k-3)
    u_hist: F64  # u(k-1), u(k-2), u(k-3)
    x0_hat: F64  # observer-form state estimate for the next sample
    misc: F64  # [D, offset, u_prev, y_prev, started, samples]: the MISC_* indices

    @property
    def static_gain(self) -> float:
        return float(self.misc[MISC_D])


@dataclass(frozen=True, eq=False)
class WearObserverRecord:
    """Per-sample outputs of one block."""

    x0_hat: F64  # (n, 3) observer-form state estimate at each sample (seed004 (17))
    theta: F64  # (n, 6) unscaled estimates a1, a2, a3, b1, b2, b3
    dy: F64  # (n,) force with the static value removed, seed004 (24)
    static_gain: F64  # (n,) D
    residual: F64  # (n,) a-priori RLS residual [N]
    cov_trace: F64  # (n,) trace of P (scaled)
    wear: F64 | None  # (n, 3) T x0_hat, physical wear states, if T is given

    @property
    def flank(self) -> F64 | None:
        return None if self.wear is None else np.asarray(self.wear[:, 0] + self.wear[:, 1])

    @property
    def crater(self) -> F64 | None:
        return None if self.wear is None else np.asarray(self.wear[:, 2])


@njit(cache=True)
def _project(th: F64, bounds: F64) -> None:  # pragma: no cover - compiled
    # Table 2: box on a1..a3 ...
    # a_i <- clamp(a_i, Table 2); b_j <- clamp(b_j, [lo_j b1, hi_j b1]) (seed004 (29))
    for i in range(3):
        th[i] = min(max(th[i], bounds[i, 0]), bounds[i, 1])
    # ... and b2, b3 within ratios of b1. Choice: the ratio bounds only make sense for
    # b1 > 0 (the paper's b1 is ~14-16); with b1 <= 0 the b's are left as they are.
    if th[3] > 0.0:
        for j in range(2):
            th[4 + j] = min(max(th[4 + j], bounds[3 + j, 0] * th[3]), bounds[3 + j, 1] * th[3])


@njit(cache=True)
def _limit_covariance(
    P: F64, U: F64, Dd: F64, use_ud: bool, p_max: float
) -> None:  # pragma: no cover - compiled
    # anti-windup (see WearObserverParams.p_max): scale P so max diag(P) <= p_max; the
    # same uniform scaling in both forms keeps the U-D and plain updates equivalent
    n = len(Dd)
    m = 0.0
    # P <- P p_max / max diag(P) when max diag(P) > p_max
    for i in range(n):
        if use_ud:
            s = 0.0
            for j in range(i, n):
                s += U[i, j] * U[i, j] * Dd[j]
        else:
            s = P[i, i]
        m = max(m, s)
    if m > p_max:
        r = p_max / m
        for i in range(n):
            Dd[i] *= r
            for j in range(n):
                P[i, j] *= r


@njit(cache=True)
def _covariance_trace(P: F64, U: F64, Dd: F64, use_ud: bool) -> float:  # pragma: no cover
    """Trace of the RLS covariance (``P``, or ``U diag(Dd) U^T`` of the UD form)."""
    tr = 0.0
    if use_ud:
        for i in range(6):
            s = 0.0
            for j in range(i, 6):
                s += U[i, j] * U[i, j] * Dd[j]
            tr += s
    else:
        for i in range(6):
            tr += P[i, i]
    return tr


class ObserverSettings(NamedTuple):
    """The observer's settings as :func:`_observer_block` reads them (read only)."""

    beta: float  # forgetting factor
    s1: float  # output scale of the regressor (seed004 (28))
    s2: float  # input scale of the regressor
    use_ud: bool  # U-D factorised update, else the plain covariance update
    constrained: bool  # project the estimate on ``bounds`` (seed004 (29))
    p_max: float  # ceiling of the covariance
    bounds: F64  # (5, 2) Table 2's bounds (unused unless ``constrained``)
    ftol: float  # relative feed change taken as a feed change


class ObserverArrays(NamedTuple):
    """The observer's state arrays, updated in place by :func:`_observer_block`."""

    theta: F64  # (6,) scaled estimate
    P: F64  # (6, 6) covariance (plain update)
    U: F64  # (6, 6) its U factor (U-D update)
    Dd: F64  # (6,) its D factor (U-D update)
    dy_hist: F64  # (3,) past dy, newest first
    u_hist: F64  # (3,) past feeds, newest first
    xh: F64  # (3,) x0_hat
    misc: F64  # D, offset, last u, last y, started, samples (the MISC_* indices)


class ObserverOut(NamedTuple):
    """The kernel's per-sample outputs (filled in place)."""

    x: F64  # (n, 3) x0_hat(k) as estimated at k-1
    theta: F64  # (n, 6) unscaled a1..a3, b1..b3
    dy: F64  # (n,) y - D u
    D: F64  # (n,) the static gain D
    res: F64  # (n,) the a-priori residual (0 where no update was made)
    tr: F64  # (n,) trace of the covariance


@njit(cache=True)
def _observer_block(
    y: F64, u: F64, st: ObserverArrays, m: ObserverSettings, out: ObserverOut
) -> None:  # pragma: no cover
    """The observer over the block (``y`` force, ``u`` feed): ``st`` updated in place,
    ``out`` filled."""
    theta, P, U, Dd = st.theta, st.P, st.U, st.Dd
    dy_hist, u_hist, xh, misc = st.dy_hist, st.u_hist, st.xh, st.misc
    beta, s1, s2, use_ud, constrained = m.beta, m.s1, m.s2, m.use_ud, m.constrained
    p_max, bounds, ftol = m.p_max, m.bounds, m.ftol
    out_x, out_th, out_dy, out_D, out_res, out_tr = (
        out.x, out.theta, out.dy, out.D, out.res, out.tr
    )  # fmt: skip
    phi = np.empty(6)
    th_u = np.empty(6)
    # dy = y - D u (seed004 (24)); RLS (seed004 (20)-(21)) on phi(k-1) (seed004 (28)); deadbeat
    #  x0_hat (seed004 (17)-(19))
    for k in range(len(y)):
        uk = u[k]
        yk = y[k]
        started = misc[MISC_STARTED] > 0.5
        if not started and uk > 0.0:
            # seed004 (25): at the start of the cut the tool is sharp, x = 0, y(0) = D u(0)
            misc[MISC_D] = yk / uk
            misc[MISC_OFFSET] = 0.0
            misc[MISC_STARTED] = 1.0
            started = True
        elif started and abs(uk - misc[MISC_FEED]) > ftol * max(abs(misc[MISC_FEED]), 1e-12):
            # section 4.3.1: D re-estimated on a feed change from the change of output
            # over the change of input, measured right before/after (no time for wear).
            # Choice: the offset keeps dy continuous across the change, so the wear
            # force already observed is not reinterpreted as static force.
            d_new = (yk - misc[MISC_FORCE]) / (uk - misc[MISC_FEED])
            misc[MISC_OFFSET] += (misc[MISC_D] - d_new) * misc[MISC_FEED]
            misc[MISC_D] = d_new
        # seed004 (24): dy(k) = y(k) - D u(k)
        dyk = yk - misc[MISC_D] * uk - misc[MISC_OFFSET] if started else 0.0
        # seed004 (28): scaled regressor phi(k-1)
        nz = False
        for i in range(3):
            phi[i] = -dy_hist[i] / s1
            phi[3 + i] = u_hist[i] * s2
            if phi[i] != 0.0 or phi[3 + i] != 0.0:
                nz = True
        res = 0.0
        if started and nz:
            # seed004 (20)-(21) (no update on an all-zero regressor: it carries no
            # information and would only inflate P by 1/beta)
            if use_ud:
                res = ud_update(theta, U, Dd, phi, dyk, beta)
            else:
                res = covariance_update(theta, P, phi, dyk, beta)
            _limit_covariance(P, U, Dd, use_ud, p_max)
            if constrained:
                # seed004 (29): unscale, project on Table 2, rescale
                for i in range(3):
                    th_u[i] = theta[i] / s1
                    th_u[3 + i] = theta[3 + i] * s2
                _project(th_u, bounds)
                for i in range(3):
                    theta[i] = th_u[i] * s1
                    theta[3 + i] = th_u[3 + i] / s2
        a1 = theta[0] / s1
        a2 = theta[1] / s1
        a3 = theta[2] / s1
        b1 = theta[3] * s2
        b2 = theta[4] * s2
        b3 = theta[5] * s2
        # record the estimate of x0(k) made at k-1 by seed004 (17)
        for i in range(3):
            out_x[k, i] = xh[i]
        out_th[k, 0] = a1
        out_th[k, 1] = a2
        out_th[k, 2] = a3
        out_th[k, 3] = b1
        out_th[k, 4] = b2
        out_th[k, 5] = b3
        out_dy[k] = dyk
        out_D[k] = misc[MISC_D]
        out_res[k] = res
        out_tr[k] = _covariance_trace(P, U, Dd, use_ud)
        # seed004 (18) without the static part: y_hat = x0_hat_1; seed004 (17) with the
        # deadbeat gains g_i = -a_i (seed004 (19) then has all eigenvalues at z = 0)
        e = dyk - xh[0]
        x1 = -a1 * xh[0] + xh[1] + b1 * uk - a1 * e
        x2 = -a2 * xh[0] + xh[2] + b2 * uk - a2 * e
        x3 = -a3 * xh[0] + b3 * uk - a3 * e
        xh[0] = x1
        xh[1] = x2
        xh[2] = x3
        # shift the histories for phi(k)
        dy_hist[2] = dy_hist[1]
        dy_hist[1] = dy_hist[0]
        dy_hist[0] = dyk
        u_hist[2] = u_hist[1]
        u_hist[1] = u_hist[0]
        u_hist[0] = uk if started else 0.0
        misc[MISC_FEED] = uk
        misc[MISC_FORCE] = yk
        misc[MISC_SAMPLES] += 1.0


class AdaptiveWearObserver:
    """RLS parameter estimator + deadbeat observer, block by block (seed 004)."""

    def __init__(self, params: WearObserverParams) -> None:
        self.params = params
        self._settings_of: tuple[WearObserverParams, ObserverSettings] | None = None

    def _settings(self) -> ObserverSettings:
        """The kernel's settings of :attr:`params` (built once per params object: the
        params are frozen, and a block is only ~60 us)."""
        p = self.params
        if self._settings_of is None or self._settings_of[0] is not p:
            bounds = p.constraints.as_array() if p.constraints is not None else np.zeros((5, 2))
            settings = ObserverSettings(
                beta=float(p.forgetting),
                s1=float(p.scale_output),
                s2=float(p.scale_input),
                use_ud=bool(p.use_ud),
                constrained=p.constraints is not None,
                p_max=float(p.p_max),
                bounds=bounds,
                ftol=float(p.feed_tolerance),
            )
            self._settings_of = (p, settings)
        return self._settings_of[1]

    def initial_state(self) -> WearObserverState:
        p = self.params
        s1, s2 = float(p.scale_output), float(p.scale_input)
        th = p.theta0.copy()
        # seed004 (29): scaled parameters
        th[:3] *= s1
        th[3:] /= s2
        p0 = np.asarray(p.p0, dtype=np.float64)
        return WearObserverState(
            theta=th,
            P=np.diag(p0),
            U=np.eye(6),
            Dd=p0.copy(),
            dy_hist=np.zeros(3),
            u_hist=np.zeros(3),
            x0_hat=np.zeros(3),
            misc=np.zeros(MISC_SAMPLES + 1),
        )

    def step(
        self, state: WearObserverState, force: ArrayLike, feed: ArrayLike
    ) -> tuple[WearObserverState, WearObserverRecord]:
        """Run a block of force samples ``force`` [N] at feeds ``feed`` [mm/rev].

        A feed <= 0 before the first cutting sample means "not cutting yet"; once the
        cut has started every feed must be > 0.
        """
        y = np.ascontiguousarray(np.atleast_1d(np.asarray(force, dtype=np.float64)))
        u = np.ascontiguousarray(np.atleast_1d(np.asarray(feed, dtype=np.float64)))
        if y.ndim != 1 or y.shape != u.shape:
            raise ParameterError("force", f"a 1-D array shaped like feed {u.shape}", y.shape)
        if not (np.all(np.isfinite(y)) and np.all(np.isfinite(u))):
            raise ParameterError("force/feed", "finite values", "NaN or inf")
        started = state.misc[MISC_STARTED] > 0.5
        cutting = np.flatnonzero(u > 0.0)
        first = 0 if started else (int(cutting[0]) if len(cutting) else len(u))
        if np.any(u[first:] <= 0.0):
            bad = float(u[first:][u[first:] <= 0.0][0])
            raise ParameterError("feed", "a feed > 0 mm/rev during the cut", bad)
        p = self.params
        th, P, U, Dd = (state.theta.copy(), state.P.copy(), state.U.copy(), state.Dd.copy())
        dyh, uh, xh, misc = (
            state.dy_hist.copy(),
            state.u_hist.copy(),
            state.x0_hat.copy(),
            state.misc.copy(),
        )
        n = len(y)
        out = ObserverOut(
            x=np.empty((n, 3)),
            theta=np.empty((n, 6)),
            dy=np.empty(n),
            D=np.empty(n),
            res=np.empty(n),
            tr=np.empty(n),
        )
        arrays = ObserverArrays(th, P, U, Dd, dyh, uh, xh, misc)
        _observer_block(y, u, arrays, self._settings(), out)
        out_x, out_th, out_dy, out_D, out_res, out_tr = out
        wear = None if p.transform is None else out_x @ np.asarray(p.transform).T
        new = WearObserverState(
            theta=th, P=P, U=U, Dd=Dd, dy_hist=dyh, u_hist=uh, x0_hat=xh, misc=misc
        )
        rec = WearObserverRecord(
            x0_hat=out_x,
            theta=out_th,
            dy=out_dy,
            static_gain=out_D,
            residual=out_res,
            cov_trace=out_tr,
            wear=wear,
        )
        return new, rec


def deadbeat_observer_step(
    a: ArrayLike, b: ArrayLike, x0_hat: ArrayLike, u: float, y: float
) -> F64:
    """One step of seed004 (17) with the deadbeat gains ``g = -a`` (for fixed parameters).

    ``y`` is the output with the static part removed (seed004 (23)).
    """
    aa = np.asarray(a, dtype=np.float64)
    bb = np.asarray(b, dtype=np.float64)
    x = np.asarray(x0_hat, dtype=np.float64)
    Ao = np.zeros((3, 3))
    Ao[:, 0] = -aa
    Ao[0, 1] = 1.0
    Ao[1, 2] = 1.0
    # seed004 (17)-(18), g_i = -a_i
    return np.asarray(Ao @ x + bb * u + (-aa) * (y - x[0]))


__all__ = [
    "TABLE2_A_BOUNDS",
    "TABLE2_B_RATIO_BOUNDS",
    "AdaptiveWearObserver",
    "WearConstraints",
    "WearObserverParams",
    "WearObserverRecord",
    "WearObserverState",
    "deadbeat_observer_step",
]
