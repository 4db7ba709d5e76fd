r"""A fast eccentricity tuner: identify the 1x force response to the modulation, solve.

Beyond seed 003. The spindle-frequency harmonics of the measured forces
(:func:`estimators.esc.spindle_harmonic` of X and Y, 4 real numbers) depend on the
modulation phasor :math:`u = a_m e^{j\theta_m}` through the feed drives' response and the
chip-thickness mechanics. For the small motions involved (microns against a feed of tens
of microns per tooth) the dependence is affine in the real and imaginary parts of
:math:`u`:

.. math:: y = f_0 + M u, \qquad y \in \mathbb{R}^4,\; u \in \mathbb{R}^2,\;
          M \in \mathbb{R}^{4\times 2}

(affine in :math:`u` and :math:`\bar u`, which also covers mismatched axes that turn the
circle into an ellipse). The tuner

1. measures :math:`y` at the current :math:`u_0` and at two probes :math:`u_0 + \delta`,
   :math:`u_0 + j\delta` (each held ``settle_revs`` revolutions for the drives and the
   previous-tooth memory to settle, then measured over ``measure_revs``);
2. fits :math:`(f_0, M)` by least squares over the points of the current speed and solves
   :math:`u^* = \arg\min\|f_0 + Mu\|` (Gauss-Newton on the affine model), clamped to
   ``a_max_um``;
3. applies :math:`u^*`, measures, adds the point, refits and solves again until the step is
   below ``tol_um``, then holds :math:`u^*` and watches the cost;
4. on a spindle-speed change (the revolution time changes by more than 1 %) it drops the
   old points but keeps :math:`M` for a quasi-Newton first step from one measurement, then
   refits from new points; when the cost rises above ``rise_ratio`` times the converged
   cost it re-probes around the held value.

With ``ellipse=True`` the unknown is :math:`(u, v)`, :math:`v = b_m e^{j\phi_m}` a
counter-rotating circle, so the commanded motion is an ellipse; 4 equations in 4 unknowns
then zero the 1x force of both axes even when the axes' dynamics differ (the paper's
suggested "additional optimization variables", section 4). It probes 4 directions.

It never sees the eccentricity or the drive response.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from common.arrays import F64
from estimators.errors import ParameterError, require_in, require_positive
from estimators.esc import spindle_harmonic


@dataclass(frozen=True)
class FastTunerParams:
    """Parameters of the fast tuner.

    Parameters
    ----------
    probe_um : float
        Probe step :math:`\\delta` [um] (> 0, < ``a_max_um``).
    settle_revs, measure_revs : int
        Revolutions held before measuring (>= 0) and measured (>= 1) at each point.
    tol_um : float
        Convergence: solution step below this [um].
    max_points : int
        Points kept for the fit (>= 3).
    a_max_um : float
        Largest modulation radius [um]; solutions beyond are clamped and reported.
    rise_ratio : float
        Re-probe when the cost exceeds this times the cost at convergence (> 1).
    ellipse : bool
        Also tune a counter-rotating circle :math:`v = b_m e^{j\\phi_m}` (4 unknowns: the
        modulation becomes an ellipse), which can cancel the 1x force of both axes when
        their dynamics differ. ``max_points`` must then be >= 5.
    """

    probe_um: float = 5.0
    settle_revs: int = 1
    measure_revs: int = 1
    tol_um: float = 0.3
    max_points: int = 5
    a_max_um: float = 60.0
    rise_ratio: float = 3.0
    ellipse: bool = False

    @property
    def dim(self) -> int:
        """Number of real unknowns: 2 (circle) or 4 (ellipse)."""
        return 4 if self.ellipse else 2

    def __post_init__(self) -> None:
        require_positive("a_max_um", self.a_max_um)
        require_in("probe_um", self.probe_um, 0.0, self.a_max_um, lo_open=True, hi_open=True)
        for name, lo in (("settle_revs", 0), ("measure_revs", 1), ("max_points", 3)):
            v = getattr(self, name)
            if int(v) != v or v < lo:
                raise ParameterError(name, f"an integer >= {lo}", v)
        require_positive("tol_um", self.tol_um)
        require_in("rise_ratio", self.rise_ratio, 1.0, math.inf, lo_open=True)
        if self.max_points < self.dim + 1:
            raise ParameterError(
                "max_points", f"an integer >= {self.dim + 1} (ellipse)", self.max_points
            )


@dataclass(frozen=True)
class FastTunerState:
    """Explicit state. ``u`` is the modulation [um]: (re, im) of the co-rotating phasor,
    then (re, im) of the counter-rotating one when tuning an ellipse."""

    mode: str  # "probe", "solve", "hold"
    u: tuple[float, ...]  # applied now
    u_best: tuple[float, ...]
    rev_in_point: int
    acc: tuple[float, ...]  # summed measurement over the point's measured revolutions
    n_acc: int
    points_u: tuple[tuple[float, ...], ...]
    points_y: tuple[tuple[float, ...], ...]
    probes_left: tuple[tuple[float, ...], ...]
    jac: tuple[float, ...] | None  # last M (row major, 4 x dim) if any
    rev_time: float
    hold_cost: float
    iterations: int
    revolutions: int

    @property
    def a_um(self) -> float:
        return math.hypot(self.u[0], self.u[1])

    @property
    def theta_deg(self) -> float:
        return math.degrees(math.atan2(self.u[1], self.u[0])) % 360.0

    @property
    def b_um(self) -> float:
        return math.hypot(self.u[2], self.u[3]) if len(self.u) == 4 else 0.0

    @property
    def phi_deg(self) -> float:
        if len(self.u) < 4:
            return 0.0
        return math.degrees(math.atan2(self.u[3], self.u[2])) % 360.0


@dataclass(frozen=True)
class FastTunerRecord:
    """One revolution of the tuner: cost measured [N], modulation for the next revolution,
    best solution so far, mode, whether the last solve was clamped, the fit residual."""

    cost: float
    a_um: float
    theta_deg: float
    a_best_um: float
    theta_best_deg: float
    mode: str
    saturated: bool
    iterations: int
    fit_residual: float
    b_um: float = 0.0
    phi_deg: float = 0.0


def _clamp(u: F64, a_max: float) -> tuple[F64, bool]:
    # the largest excursion of co- plus counter-rotating circles is |u| + |v|
    r = float(np.hypot(u[0], u[1]))
    if u.size == 4:
        r += float(np.hypot(u[2], u[3]))
    if r > a_max:
        return u * (a_max / r), True
    return u, False


class FastTuner:
    """Identify-and-solve tuner of the modulation phasor (see module docstring)."""

    def __init__(self, params: FastTunerParams | None = None) -> None:
        self.params = params if params is not None else FastTunerParams()

    def initial_state(self, a_um: float = 0.0, theta_deg: float = 0.0) -> FastTunerState:
        """Start probing around ``a_um e^{j theta}``."""
        p = self.params
        a = float(a_um)
        if not math.isfinite(a) or abs(a) > p.a_max_um - p.probe_um:
            raise ParameterError(
                "a_um", f"|a| <= a_max_um - probe_um = {p.a_max_um - p.probe_um:g}", a_um
            )
        th = math.radians(float(theta_deg))
        u0: tuple[float, ...] = (a * math.cos(th), a * math.sin(th))
        if p.ellipse:
            u0 = (*u0, 0.0, 0.0)
        return FastTunerState(
            mode="probe",
            u=u0,
            u_best=u0,
            rev_in_point=0,
            acc=(0.0,) * 4,
            n_acc=0,
            points_u=(),
            points_y=(),
            probes_left=self._probes(u0),
            jac=None,
            rev_time=0.0,
            hold_cost=0.0,
            iterations=0,
            revolutions=0,
        )

    def _probes(self, u0: tuple[float, ...]) -> tuple[tuple[float, ...], ...]:
        d = self.params.probe_um
        return tuple(
            tuple(v + (d if i == k else 0.0) for i, v in enumerate(u0)) for k in range(len(u0))
        )

    def fit(self, us: ArrayLike, ys: ArrayLike) -> tuple[F64, F64, float]:
        """Least-squares fit of ``y = f0 + M u``; returns ``(f0, M, rms residual)``.

        Raises
        ------
        ParameterError
            With fewer than ``d + 1`` points (``d`` unknowns) or points in a lower
            dimension (e.g. on one line for the circle: no information on M).
        """
        u = np.asarray(us, dtype=np.float64)
        y = np.asarray(ys, dtype=np.float64)
        d = u.shape[1] if u.ndim == 2 else 0
        if d not in (2, 4) or y.shape[0] != u.shape[0] or u.shape[0] < d + 1:
            raise ParameterError(
                "points", ">= 3 points (u: n x 2, y: n x m), or >= 5 for n x 4", (u.shape, y.shape)
            )
        a = np.hstack([np.ones((u.shape[0], 1)), u])
        if np.linalg.matrix_rank(a, tol=1e-9 * max(1.0, float(np.abs(u).max()))) < d + 1:
            raise ParameterError("points", "modulation points not all on one line", u.tolist())
        coef, *_ = np.linalg.lstsq(a, y, rcond=None)
        res = y - a @ coef
        f0 = np.asarray(coef[0], dtype=np.float64)
        m = np.asarray(coef[1:].T, dtype=np.float64).copy()
        return f0, m, float(np.sqrt(np.mean(res**2)))

    @staticmethod
    def solve(f0: F64, m: F64) -> F64:
        r"""The modulation minimising :math:`\|f_0 + M u\|`."""
        sol, *_ = np.linalg.lstsq(m, -f0, rcond=None)
        return np.asarray(sol, dtype=np.float64)

    def step(
        self, state: FastTunerState, forces: ArrayLike, angle: ArrayLike, rev_time: float
    ) -> tuple[FastTunerState, FastTunerRecord]:
        """One revolution of force (rows: X, Y [N]) and spindle angle [rad] measured with
        ``state.u`` applied; returns the state whose ``u`` is to be applied next."""
        p = self.params
        dt = require_positive("rev_time", rev_time)
        f = np.atleast_2d(np.asarray(forces, dtype=np.float64))
        if f.shape[0] != 2:
            raise ParameterError("forces", "an array of 2 rows (X, Y force)", f.shape)
        h = [spindle_harmonic(f[i], angle) for i in range(2)]
        y = np.array([h[0].real, h[0].imag, h[1].real, h[1].imag])
        cost = abs(h[0])
        # what the tuner drives to zero and watches: the 1x of both axes
        level = float(np.linalg.norm(y))
        s = state
        sat = False
        fit_res = math.nan
        # a spindle-speed change invalidates the points (drive response, phase reference)
        if s.rev_time > 0 and abs(dt - s.rev_time) > 0.01 * s.rev_time:
            s = replace(
                s,
                mode="solve" if s.jac is not None else "probe",
                points_u=(),
                points_y=(),
                rev_in_point=0,
                acc=(0.0,) * 4,
                n_acc=0,
                probes_left=() if s.jac is not None else self._probes(s.u),
            )
            s = replace(s, rev_time=dt, revolutions=s.revolutions + 1)
            return s, self._record(s, cost, sat, fit_res)
        s = replace(s, rev_time=dt, revolutions=s.revolutions + 1)
        if s.mode == "hold":
            if level > p.rise_ratio * max(s.hold_cost, 1e-9):
                s = replace(
                    s,
                    mode="probe",
                    points_u=(),
                    points_y=(),
                    rev_in_point=0,
                    acc=(0.0,) * 4,
                    n_acc=0,
                    probes_left=self._probes(s.u),
                )
            return s, self._record(s, cost, sat, fit_res)
        rip = s.rev_in_point + 1
        acc = s.acc
        n_acc = s.n_acc
        if rip > p.settle_revs:
            acc = tuple(float(a + b) for a, b in zip(acc, y, strict=True))
            n_acc += 1
        if n_acc < p.measure_revs:
            s = replace(s, rev_in_point=rip, acc=acc, n_acc=n_acc)
            return s, self._record(s, cost, sat, fit_res)
        # the point is measured
        y_mean = tuple(a / n_acc for a in acc)
        pu = (*s.points_u, s.u)[-p.max_points :]
        py = (*s.points_y, y_mean)[-p.max_points :]
        s = replace(s, points_u=pu, points_y=py, rev_in_point=0, acc=(0.0,) * 4, n_acc=0)
        if s.probes_left:
            s = replace(s, u=s.probes_left[0], probes_left=s.probes_left[1:])
            return s, self._record(s, cost, sat, fit_res)
        u_now = np.array(s.u)
        dim = len(s.u)
        m_prev = np.array(s.jac).reshape(4, dim) if s.jac is not None else None
        f0: F64 | None = None
        m: F64 | None = None
        ua = np.array(pu)
        spread = (
            float(np.linalg.svd(ua - ua.mean(axis=0), compute_uv=False)[-1])
            if len(pu) >= dim + 1
            else 0.0
        )
        if spread >= 0.2 * p.probe_um:
            f0, m, fit_res = self.fit(pu, py)
        elif m_prev is not None:
            # points too close for a fit: Broyden's rank-one update of the last slope
            m = m_prev
            if len(pu) >= 2:
                du = np.array(pu[-1]) - np.array(pu[-2])
                dy = np.array(py[-1]) - np.array(py[-2])
                nd = float(du @ du)
                if nd > 1e-6:
                    m = m + np.outer(dy - m @ du, du) / nd
            f0 = np.array(y_mean) - m @ u_now
        if m is None or f0 is None:
            s = replace(s, probes_left=self._probes(s.u))
            s = replace(s, u=s.probes_left[0], probes_left=s.probes_left[1:])
            return s, self._record(s, cost, sat, fit_res)
        u_new, sat = _clamp(self.solve(f0, m), p.a_max_um)
        step = float(np.linalg.norm(u_new - u_now))
        u_t = tuple(float(v) for v in u_new)
        s = replace(
            s,
            jac=tuple(float(v) for v in m.ravel()),
            iterations=s.iterations + 1,
            u=u_t,
            u_best=u_t,
            mode="solve",
        )
        if step < p.tol_um:
            s = replace(s, mode="hold", hold_cost=max(level, 1e-9))
        return s, self._record(s, cost, sat, fit_res)

    @staticmethod
    def _record(s: FastTunerState, cost: float, sat: bool, fit_res: float) -> FastTunerRecord:
        ab = math.hypot(s.u_best[0], s.u_best[1])
        tb = math.degrees(math.atan2(s.u_best[1], s.u_best[0])) % 360.0
        return FastTunerRecord(
            cost=cost,
            a_um=s.a_um,
            theta_deg=s.theta_deg,
            a_best_um=ab,
            theta_best_deg=tb,
            mode=s.mode,
            saturated=sat,
            iterations=s.iterations,
            fit_residual=fit_res,
            b_um=s.b_um,
            phi_deg=s.phi_deg,
        )


__all__ = ["FastTuner", "FastTunerParams", "FastTunerRecord", "FastTunerState"]
