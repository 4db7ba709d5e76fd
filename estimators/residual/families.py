r"""The family registry of the rigid residual model (pure numpy).

Each family is a set of extra regressor columns of the rigid inverse dynamic model
(:mod:`estimators.idim`), linear in its coefficients, with *shape* parameters (a delay,
a period, a polynomial order) fixed beforehand from the residual of the current model.
:data:`FAMILIES` holds all of them, one :class:`Family` entry each (columns, column
names, shape search, derived figures, meaning): the canonical families (docs/design.md)
(:data:`CANONICAL`: offset, inertia, viscous, coulomb_asymmetry, stribeck,
position_periodic, harmonic, delay, drift; columns in the comment above it) and the
real-drive families (:data:`DRIVE`, below); :data:`OFFERED` is what
:class:`estimators.residual.rigid.RigidModel` offers, which refits the coefficients jointly
with the nominal ones. The real-drive families, with :math:`v = \dot q`,
:math:`a = \ddot q`, :math:`d_+ = 1[v > 0]`, :math:`d_- = 1[v < 0]`,
:math:`x = 2 (q - q_{min}) / (q_{max} - q_{min}) - 1` clipped to [-1, 1]:

===================== ============================================================ =========
name                  columns                                                      shape
===================== ============================================================ =========
viscous_asymmetry     :math:`v\,d_+` (with the nominal :math:`F_v v`: one viscous   —
                      coefficient per direction)
friction_curve        :math:`e^{-(v/v_s)^2} d_+`, :math:`-e^{-(v/v_s)^2} d_-`        v_s
                      (the Stribeck curve of each direction; positive coefficients
                      oppose the motion)
position_friction     :math:`P_k(x)\,d_+`, :math:`P_k(x)\,d_-`, k = 1..K            K, range
                      (Legendre polynomials: friction varying smoothly along the
                      travel, per direction)
position_harmonics    :math:`\cos, \sin(2\pi k q / P)` and (if supported) the same  P, K
                      times :math:`\mathrm{sign}(v)`, k = 1..K (a force periodic in
                      position: a part independent of direction — cogging, torque
                      ripple, lead error — and a friction part that follows the
                      direction)
drive_delay           :math:`E(t + d) - E(t)`, E the nominal effort                 d
                      :math:`M a + F_v v + F_c\,\mathrm{sign}(v) + \tau_{off}` with
                      the current nominal parameters (the commanded force acts d
                      late; coefficient 1 = all of it)
force_lag             :math:`M \dddot q + F_v a` (a first-order lag T of the force  —
                      loop: command :math:`= (1 + T s)` force, coefficient = T [s])
===================== ============================================================ =========

Orders (K, and whether the periodic force has a part that follows the direction) are
chosen by blocked cross-validation of the residual inside the data the shape search is
given (contiguous blocks in time; the fewest columns within 0.5 % of the best held-out
error), so a family does not grow columns the data cannot support; when no structure
beats the constant alone, the family has no shape (it is not scored). Where the data
supports only one or two harmonics independent of the direction, ``position_harmonics``
stands back (no shape): that is the canonical ``position_periodic``, offered under its name.

``force_lag`` is 0 within :data:`LAG_EDGE_S` of both ends of a record (the position
filter's edge transient, differentiated three times). ``viscous_asymmetry`` and
``friction_curve`` are built and tested but not offered (:data:`NOT_OFFERED` says why).
Measured on EMPS: ``docs/residual-emps.md``.

Nothing here imports the residual analysis: the signals are any object with the
attributes ``t, q, qd, qdd, qddd`` (:class:`Kin`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.polynomial import legendre
from numpy.typing import NDArray

from common.arrays import F64
from estimators.errors import ParameterError
from estimators.idim import rigid_regressor
from estimators.residual.shapes import (
    gap_filled,
    project_rss,
    refine_grid,
    search_frequency,
    search_period,
)


class Kin(Protocol):
    """Full-rate kinematics (the residual analysis's ``Signals`` satisfies it)."""

    @property
    def t(self) -> F64: ...
    @property
    def q(self) -> F64: ...
    @property
    def qd(self) -> F64: ...
    @property
    def qdd(self) -> F64: ...
    @property
    def qddd(self) -> F64: ...


Shape = Mapping[str, float]


@dataclass(frozen=True, eq=False)
class SearchData:
    """What a shape search is given: the full-rate signals and the current model's
    residual there, the rows it may use (``mask``), the evenly spaced subsample of them
    it searches (``idx``, time order; ``r`` the residual there), the current nominal
    parameters (M, Fv, Fc, offset) and the regressor's decimation."""

    sig: Kin
    residual: F64
    mask: NDArray[np.bool_]
    idx: NDArray[np.intp]
    r: F64
    nominal: F64 | None = None
    decimation: int = 1


@dataclass(frozen=True)
class Family:
    """One effect family of the rigid model: its columns, their names, its shape search,
    its derived figures (from the shape, the coefficients and the nominal parameters),
    its meaning, and whether it has a shape to search again inside each training fold."""

    name: str
    meaning: str
    columns: Callable[[Shape, Kin], F64]
    column_names: Callable[[Shape], tuple[str, ...]]
    search: Callable[[SearchData], dict[str, float]]
    derived: Callable[[Shape, Mapping[str, float], Mapping[str, float]], dict[str, float]]
    shaped: bool = False


#: the highest orders a shape search tries
MAX_LEGENDRE = 8
MAX_HARMONICS = 4
#: contiguous blocks of the order cross-validation
CV_BLOCKS = 5


def _dirs(v: F64) -> tuple[F64, F64]:
    return (v > 0).astype(np.float64), (v < 0).astype(np.float64)


def _lstsq_rss(cols: F64, r: F64) -> float:
    """Residual sum of squares of ``r`` after least squares on ``cols`` (normal equations
    for the few, well-scaled columns here; the robust solver when nearly singular)."""
    g = cols.T @ cols
    b = cols.T @ r
    if np.linalg.cond(g) < 1e10:
        return float(r @ r - b @ np.linalg.solve(g, b))
    coef, *_ = np.linalg.lstsq(cols, r, rcond=None)
    e = r - cols @ coef
    return float(e @ e)


def cv_select(cols: F64, subsets: Sequence[Sequence[int]], r: F64, blocks: int = CV_BLOCKS) -> int:
    """Index of the column subset (plus a constant) that predicts ``r`` best held out.

    ``r`` and the rows of ``cols`` are in time order; each of ``blocks`` contiguous
    blocks is predicted from the others (normal equations: the other blocks' Gram
    matrix is the total minus the block's). Among the subsets within 0.5 % of the best
    cross-validated sum of squares, the one with the fewest columns wins (the first of
    them in ``subsets`` on a tie): a hair of gain does not buy columns.
    """
    n = len(r)
    x = np.column_stack([np.ones(n), cols])
    edges = np.linspace(0, n, blocks + 1).astype(int)
    parts = [(x[i:j], r[i:j]) for i, j in itertools.pairwise(edges)]
    grams = [(xb.T @ xb, xb.T @ rb, float(rb @ rb)) for xb, rb in parts]
    g_all = sum(g for g, _, _ in grams)
    b_all = sum(b for _, b, _ in grams)
    errs = []
    for sub in subsets:
        k = np.concatenate([[0], 1 + np.asarray(sub, dtype=np.intp)])
        sse = 0.0
        for g, b, rr in grams:
            gt, bt = (g_all - g)[np.ix_(k, k)], (b_all - b)[k]
            coef = np.linalg.lstsq(gt, bt, rcond=None)[0]
            sse += rr - 2.0 * float(coef @ b[k]) + float(coef @ g[np.ix_(k, k)] @ coef)
        errs.append(sse)
    best = min(errs)
    ok = [i for i, e in enumerate(errs) if e <= best + 0.005 * abs(best)]
    return min(ok, key=lambda i: (len(subsets[i]), i))


def cv_order(cols: F64, sizes: Sequence[int], r: F64, blocks: int = CV_BLOCKS) -> int:
    """:func:`cv_select` over nested sets: order ``i`` is the first ``sizes[i]`` columns."""
    return cv_select(cols, [range(k) for k in sizes], r, blocks)


# ----------------------------------------------------------------- direction friction


def _viscous_asym_cols(shape: Shape, s: Kin) -> F64:
    v = s.qd
    return (v * (v > 0))[:, None].astype(np.float64)


def _friction_curve_cols(shape: Shape, s: Kin) -> F64:
    v = s.qd
    dp, dn = _dirs(v)
    g = np.exp(-((v / shape["v_s"]) ** 2))
    # signed so that a positive coefficient is friction opposing the motion
    return np.column_stack([g * dp, -g * dn])


def _friction_curve_search(
    s: SearchData,
) -> dict[str, float]:
    sig, r, idx = s.sig, s.r, s.idx
    sub = _Sub(sig, idx)
    vmax = float(np.max(np.abs(sub.qd))) if len(idx) else 0.0
    if not vmax > 0:
        return {"v_s": math.nan}
    dp, dn = _dirs(sub.qd)
    # the Coulomb levels of each direction are refitted with the curve (the nominal has
    # one level and an offset: two levels already)
    grid = np.geomspace(vmax * 1e-3, vmax * 0.5, 40)
    rss = [
        _lstsq_rss(np.column_stack([_friction_curve_cols({"v_s": float(vs)}, sub), dp, dn]), r)
        for vs in grid
    ]
    return {"v_s": float(grid[int(np.argmin(rss))])}


def _no_search(s: SearchData) -> dict[str, float]:
    return {}


# ------------------------------------------------------------------ position friction


def _unit_position(shape: Shape, q: F64) -> F64:
    lo, hi = shape["q_min"], shape["q_max"]
    return np.clip(2.0 * (q - lo) / max(hi - lo, 1e-300) - 1.0, -1.0, 1.0)


def _legendre(x: F64, order: int) -> F64:
    return np.column_stack([legendre.legval(x, np.eye(order + 1)[k]) for k in range(1, order + 1)])


def _position_friction_cols(shape: Shape, s: Kin) -> F64:
    dp, dn = _dirs(s.qd)
    p = _legendre(_unit_position(shape, s.q), int(shape["order"]))
    return np.hstack([p * dp[:, None], p * dn[:, None]])


def _position_friction_names(shape: Shape) -> tuple[str, ...]:
    k = int(shape["order"])
    return tuple(f"pos_P{j}" for j in range(1, k + 1)) + tuple(f"neg_P{j}" for j in range(1, k + 1))


def _position_friction_search(
    s: SearchData,
) -> dict[str, float]:
    sig, r, idx = s.sig, s.r, s.idx
    q = sig.q[idx]
    lo, hi = float(np.min(q)), float(np.max(q))
    if not hi > lo:
        return {"q_min": lo, "q_max": hi, "order": math.nan}
    shape = {"q_min": lo, "q_max": hi}
    sub = _Sub(sig, idx)
    full = _position_friction_cols({**shape, "order": float(MAX_LEGENDRE)}, sub)
    # interleave (P1+, P1-, P2+, P2-, ...) so that each order is a leading column set;
    # order 0 (no columns) when no order predicts the held-out blocks better
    m = MAX_LEGENDRE
    cols = full[:, np.ravel(np.column_stack([np.arange(m), m + np.arange(m)]))]
    order = cv_order(cols, [2 * k for k in range(m + 1)], r)
    return {**shape, "order": float(order) if order else math.nan}


def _position_friction_derived(
    shape: Shape, coef: Mapping[str, float], nominal: Mapping[str, float]
) -> dict[str, float]:
    # the friction profile along the travel, per direction: its peak-to-peak variation
    k = int(shape["order"])
    x = np.linspace(-1.0, 1.0, 201)
    p = _legendre(x, k)
    out = {}
    for d in ("pos", "neg"):
        prof = p @ np.array([coef.get(f"{d}_P{j}", 0.0) for j in range(1, k + 1)])
        out[f"{d}_peak_to_peak"] = float(np.ptp(prof))
    return out


# ---------------------------------------------------------------- position harmonics


def _harmonic_cols(shape: Shape, s: Kin) -> F64:
    w = 2.0 * np.pi * s.q / shape["period"]
    sv = np.sign(s.qd)
    cols = []
    for k in range(1, int(shape["harmonics"]) + 1):
        c, sn = np.cos(k * w), np.sin(k * w)
        cols.extend([c, sn, sv * c, sv * sn] if shape.get("direction", 1.0) else [c, sn])
    return np.column_stack(cols)


def _harmonic_names(shape: Shape) -> tuple[str, ...]:
    parts = ("c", "s", "dc", "ds") if shape.get("direction", 1.0) else ("c", "s")
    return tuple(f"{p}{k}" for k in range(1, int(shape["harmonics"]) + 1) for p in parts)


def position_periodogram(q: F64, v: F64, r: F64, bins: int = 1 << 15) -> tuple[F64, F64]:
    """Periods and amplitude spectrum of ``r`` as a function of position, per direction.

    The residual is averaged in ``bins`` equal position bins separately for each
    direction of motion (empty bins 0), each profile is Fourier transformed (zero padded
    4x) and the two power spectra are added, so a periodic force is found whether or not
    its phase follows the direction. Returns (periods, amplitude), longest period first.
    """
    lo, hi = float(np.min(q)), float(np.max(q))
    span = hi - lo
    if not span > 0:
        return np.empty(0), np.empty(0)
    h = span / bins
    k = np.minimum(((q - lo) / h).astype(np.int64), bins - 1)
    nfft = 4 * bins
    power = np.zeros(nfft // 2 + 1)
    for m in (v > 0, v < 0):
        if not m.any():
            continue
        cnt = np.bincount(k[m], minlength=bins)
        tot = np.bincount(k[m], weights=r[m] - float(np.mean(r[m])), minlength=bins)
        prof = np.where(cnt > 0, tot / np.maximum(cnt, 1), 0.0)
        fill = max(float(np.mean(cnt > 0)), 1e-12)
        power += (np.abs(np.fft.rfft(prof, nfft)) * 2.0 / (bins * fill)) ** 2
    freq = np.fft.rfftfreq(nfft, h)
    keep = (freq >= 2.0 / span) & (freq <= 1.0 / (8.0 * h))
    periods = np.asarray(1.0 / freq[keep][::-1], dtype=np.float64)
    return periods, np.asarray(np.sqrt(power[keep][::-1]), dtype=np.float64)


def _harmonic_search(
    s: SearchData,
) -> dict[str, float]:
    sig, r, idx = s.sig, s.r, s.idx
    q, v = sig.q[idx], sig.qd[idx]
    periods, amp = position_periodogram(q, v, r)
    # a period the drive's data can carry: at the fast end of the motion (90th
    # percentile of |v|) it passes at no more than a tenth of the sampling rate (the
    # bandwidth of the IDIM's position filter, 100 Hz at 1 kHz); shorter periods are
    # aliases and quantisation, not a force (the EMPS halves picked 0.125 mm = 1 kHz at
    # the top speed before this bound)
    ts = float(np.median(np.diff(sig.t))) if len(sig.t) > 1 else math.nan
    moving = np.abs(v[np.abs(v) > 0])
    if math.isfinite(ts) and ts > 0 and moving.size:
        p_min = float(np.percentile(moving, 90)) * 10.0 * ts
        keep = periods >= p_min
        periods, amp = periods[keep], amp[keep]
    if len(periods) == 0:
        return {"period": math.nan, "harmonics": math.nan}
    p0 = float(periods[int(np.argmax(amp))])
    sub = _Sub(sig, idx)
    # refine by least squares over +-2 bins of the 4x padded transform (a bin is
    # P / (4 span) of the period, relative), then again around the best of that grid
    step = 2.0 * p0 / (4.0 * float(np.ptp(q)))
    period = p0
    for _ in range(3):
        fine = period * np.linspace(1.0 - step, 1.0 + step, 9)
        rss = [_lstsq_rss(_harmonic_cols({"period": p, "harmonics": 1.0}, sub), r) for p in fine]
        period, step = float(fine[int(np.argmin(rss))]), step / 4.0
    cols = _harmonic_cols({"period": period, "harmonics": float(MAX_HARMONICS)}, sub)
    # structures: K harmonics independent of the direction, or with a part that follows
    # it; columns of harmonic k are 4(k-1) + (c, s, dc, ds)
    ks = range(1, MAX_HARMONICS + 1)
    common = [[4 * j + i for j in range(k) for i in (0, 1)] for k in ks]
    both = [list(range(4 * k)) for k in ks]
    choice = cv_select(cols, [*common, *both, []], r)
    if choice == 2 * MAX_HARMONICS:  # no structure predicts the held-out blocks better
        return {"period": math.nan, "harmonics": 0.0, "direction": 0.0}
    k, direction = 1 + choice % MAX_HARMONICS, float(choice >= MAX_HARMONICS)
    if not direction and k <= 2:
        # that is the canonical position_periodic (a period, harmonics 1-2): it is offered
        # under its own name, so this richer family stands back
        return {"period": math.nan, "harmonics": float(k), "direction": 0.0}
    return {"period": period, "harmonics": float(k), "direction": direction}


def _harmonic_derived(
    shape: Shape, coef: Mapping[str, float], nominal: Mapping[str, float]
) -> dict[str, float]:
    out = {}
    for k in range(1, int(shape["harmonics"]) + 1):
        c, s, dc, ds = (coef.get(f"{p}{k}", 0.0) for p in ("c", "s", "dc", "ds"))
        if shape.get("direction", 1.0):
            out[f"amplitude_{k}_pos"] = math.hypot(c + dc, s + ds)
            out[f"amplitude_{k}_neg"] = math.hypot(c - dc, s - ds)
        else:
            out[f"amplitude_{k}"] = math.hypot(c, s)
    return out


# ------------------------------------------------------------------- drive dynamics


def nominal_effort(shape: Shape, s: Kin) -> F64:
    """:math:`M a + F_v v + F_c \\mathrm{sign}(v) + \\tau_{off}` with the shape's values."""
    v = s.qd
    return np.asarray(
        shape["M"] * s.qdd + shape["Fv"] * v + shape["Fc"] * np.sign(v) + shape["offset"],
        dtype=np.float64,
    )


def _delay_cols(shape: Shape, s: Kin) -> F64:
    e = nominal_effort(shape, s)
    # E(t + d) by linear interpolation (sub-sample delays); the last d seconds hold E
    return (np.interp(s.t + shape["delay_s"], s.t, e) - e)[:, None]


def _nominal_shape(nominal: F64 | None) -> dict[str, float]:
    if nominal is None or len(nominal) < 4:
        return {"M": math.nan, "Fv": math.nan, "Fc": math.nan, "offset": math.nan}
    return dict(zip(("M", "Fv", "Fc", "offset"), map(float, nominal[:4])))


def _delay_search(s: SearchData) -> dict[str, float]:
    sig, r, idx = s.sig, s.r, s.idx
    base = _nominal_shape(s.nominal)
    if not all(math.isfinite(x) for x in base.values()):
        return {**base, "delay_s": math.nan}
    ts = float(np.median(np.diff(sig.t)))
    e = nominal_effort(base, sig)
    t_sub = sig.t[idx]
    one = np.ones(len(idx))

    def rss(d: float) -> float:
        col = np.interp(t_sub + d, sig.t, e) - e[idx]
        return _lstsq_rss(np.column_stack([col, one]), r)

    # a twentieth of a sample (a zero-order hold, a fast current loop) up to 20 samples
    grid = np.geomspace(0.05 * ts, 20.0 * ts, 24)
    k = int(np.argmin([rss(d) for d in grid]))
    fine = np.linspace(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)], 11)
    return {**base, "delay_s": float(fine[int(np.argmin([rss(d) for d in fine]))])}


def _delay_derived(
    shape: Shape, coef: Mapping[str, float], nominal: Mapping[str, float]
) -> dict[str, float]:
    # for a small delay the column is ~ d E'(t): gain * d is the delay the data shows
    return {"effective_delay_s": coef.get("gain", 0.0) * shape["delay_s"]}


#: the position filter's edge transient, differentiated three times, spoils the jerk
#: near both ends of a record (measured: > 40 % of the jerk's scale within 30 ms of the
#: ends with the 100 Hz filter at 1 kHz, < 1 % beyond 50 ms); the lag column is 0 there
LAG_EDGE_S = 0.05


def _lag_cols(shape: Shape, s: Kin) -> F64:
    col = shape["M"] * s.qddd + shape["Fv"] * s.qdd
    if len(s.t):
        col[(s.t < s.t[0] + LAG_EDGE_S) | (s.t > s.t[-1] - LAG_EDGE_S)] = 0.0
    return col[:, None]


def _lag_search(s: SearchData) -> dict[str, float]:
    base = _nominal_shape(s.nominal)
    return {"M": base["M"], "Fv": base["Fv"]}


class _Sub:
    """The samples ``idx`` of a :class:`Kin` (for searches on a subsample)."""

    def __init__(self, sig: Kin, idx: NDArray[np.intp]) -> None:
        self.t, self.q, self.qd = sig.t[idx], sig.q[idx], sig.qd[idx]
        self.qdd, self.qddd = sig.qdd[idx], sig.qddd[idx]


def _none(
    shape: Shape, coef: Mapping[str, float], nominal: Mapping[str, float]
) -> dict[str, float]:
    return {}


# ------------------------------------------------------------- the canonical families
# (the canonical names; columns with v = qd: offset 1, inertia qdd, viscous v,
# coulomb_asymmetry 1[v>0] and |v|, stribeck sign(v) exp(-(|v|/v_s)^2), position_periodic
# cos, sin(2 pi k q / P) for k = 1, 2, harmonic cos, sin(2 pi f t), delay P(t-d) - P(t)
# with P the nominal effort, drift (t - t0) / T)


def _ones_cols(shape: Shape, s: Kin) -> F64:
    return np.ones((len(s.qd), 1))


def _inertia_cols(shape: Shape, s: Kin) -> F64:
    return s.qdd[:, None].copy()


def _viscous_cols(shape: Shape, s: Kin) -> F64:
    return s.qd[:, None].copy()


def _coulomb_asym_cols(shape: Shape, s: Kin) -> F64:
    v = s.qd
    return np.column_stack([(v > 0).astype(np.float64), np.abs(v)])


def _stribeck_cols(shape: Shape, s: Kin) -> F64:
    v, vs = s.qd, shape["v_s"]
    return (np.sign(v) * np.exp(-((np.abs(v) / vs) ** 2)))[:, None]


def _periodic_cols(shape: Shape, s: Kin) -> F64:
    w = 2.0 * np.pi * s.q / shape["period"]
    return np.column_stack([np.cos(w), np.sin(w), np.cos(2 * w), np.sin(2 * w)])


def _time_harmonic_cols(shape: Shape, s: Kin) -> F64:
    w = 2.0 * np.pi * shape["frequency"] * s.t
    return np.column_stack([np.cos(w), np.sin(w)])


def _rigid_effort(shape: Shape, s: Kin) -> F64:
    return np.asarray(
        rigid_regressor(s.qd, s.qdd)
        @ np.array([shape["M"], shape["Fv"], shape["Fc"], shape["offset"]]),
        dtype=np.float64,
    )


def _late_effort_cols(shape: Shape, s: Kin) -> F64:
    """``P(t - d) - P(t)`` with ``P`` the nominal effort (linear interpolation in time)."""
    p = _rigid_effort(shape, s)
    # the first d seconds have no past: P is held at its first value there
    return np.asarray(np.interp(s.t - shape["delay_s"], s.t, p) - p, dtype=np.float64)[:, None]


def _drift_cols(shape: Shape, s: Kin) -> F64:
    return ((s.t - shape["t0"]) / shape["span"])[:, None]


def _stribeck_search(s: SearchData) -> dict[str, float]:
    sig, idx, r = s.sig, s.idx, s.r
    vmax = float(np.max(np.abs(sig.qd[idx])))
    sub = _Sub(sig, idx)

    def rss_vs(vs: float) -> float:
        cols = _stribeck_cols({"v_s": float(vs)}, sub)
        return project_rss(np.column_stack([cols, np.ones(len(idx))]), r)

    grid = np.geomspace(max(vmax * 1e-3, 1e-12), vmax * 0.5, 40)
    return {"v_s": refine_grid(rss_vs, grid, log=True)}


def _periodic_search(s: SearchData) -> dict[str, float]:
    q, r = s.sig.q, s.r
    dq = float(np.median(np.abs(np.diff(q)))) if len(q) > 1 else 0.0
    period, _ = search_period(q[s.idx], r - r.mean(), dq)
    return {"period": period}


def _time_harmonic_search(s: SearchData) -> dict[str, float]:
    t = s.sig.t
    tt, rr = gap_filled(t, s.residual, s.mask)
    # below the anti-alias filter of the decimation (the regressor is decimated: a
    # column above it is filtered away and its coefficient is meaningless)
    fs = 1.0 / float(np.median(np.diff(t)))
    freq, _ = search_frequency(tt, rr, f_max=0.9 * 0.4 * fs / s.decimation)
    if math.isfinite(freq) and freq > 0:
        # refine within +-1 bin of the padded FFT by least squares on the residual
        df = 1.0 / (4.0 * max(float(tt[-1] - tt[0]), 1e-12))
        ts_, rs_ = t[s.idx], s.r - s.r.mean()

        def rss(fr: float) -> float:
            w = 2.0 * np.pi * fr * ts_
            return project_rss(np.column_stack([np.cos(w), np.sin(w)]), rs_)

        fine = np.linspace(max(freq - df, df * 1e-3), freq + df, 41)
        freq = float(fine[int(np.argmin([rss(fr) for fr in fine]))])
    return {"frequency": freq}


def _late_effort_search(s: SearchData) -> dict[str, float]:
    if s.nominal is None:
        raise ParameterError("nominal", "the nominal parameters (M, Fv, Fc, offset)", None)
    sig, idx, r = s.sig, s.idx, s.r
    base = dict(zip(("M", "Fv", "Fc", "offset"), map(float, s.nominal[:4])))
    ts = float(np.median(np.diff(sig.t)))
    span = float(sig.t[-1] - sig.t[0])
    # lags from one sample to 5 % of the record (at most 0.5 s)
    grid = np.geomspace(ts, max(min(0.5, 0.05 * span), 2 * ts), 40)
    p_full = _rigid_effort(base, sig)
    t_sub = sig.t[idx]

    def rss_d(d: float) -> float:
        # the column of _late_effort_cols, evaluated on the search samples only
        col = np.interp(t_sub - d, sig.t, p_full) - p_full[idx]
        return project_rss(np.column_stack([col, np.ones(len(idx))]), r)

    return {**base, "delay_s": refine_grid(rss_d, grid, log=True)}


def _drift_search(s: SearchData) -> dict[str, float]:
    tt = s.sig.t[np.flatnonzero(s.mask)]
    return {"t0": float(tt[0]), "span": float(max(tt[-1] - tt[0], 1e-12))}


def _periodic_derived(
    shape: Shape, coef: Mapping[str, float], nominal: Mapping[str, float]
) -> dict[str, float]:
    return {
        "amplitude_1": math.hypot(coef["c1"], coef["s1"]),
        "amplitude_2": math.hypot(coef["c2"], coef["s2"]),
    }


def _time_harmonic_derived(
    shape: Shape, coef: Mapping[str, float], nominal: Mapping[str, float]
) -> dict[str, float]:
    return {"amplitude": math.hypot(coef["c"], coef["s"])}


def _coulomb_asym_derived(
    shape: Shape, coef: Mapping[str, float], nominal: Mapping[str, float]
) -> dict[str, float]:
    fv, fc, off = nominal["Fv"], nominal["Fc"], nominal["offset"]
    return {
        "Fv_pos": float(fv + coef["abs_v"]),
        "Fv_neg": float(fv - coef["abs_v"]),
        "Fc_pos": float(fc + off + coef["dir_pos"]),
        "Fc_neg": float(fc - off),
    }


def _named(*names: str) -> Callable[[Shape], tuple[str, ...]]:
    return lambda shape: names


CANONICAL: tuple[Family, ...] = (
    Family("offset", "a constant effort (a sensor or amplifier offset, gravity on a tilted "
           "axis)", _ones_cols, _named("offset"), _no_search, _none),
    Family("inertia", "mass / inertia not in the nominal model", _inertia_cols,
           _named("inertia"), _no_search, _none),
    Family("viscous", "viscous friction, proportional to speed", _viscous_cols,
           _named("viscous"), _no_search, _none),
    Family("coulomb_asymmetry", "friction that differs by direction: a Coulomb level and a "
           "viscous coefficient for each direction (Fc_pos/Fc_neg, Fv_pos/Fv_neg)",
           _coulomb_asym_cols, _named("dir_pos", "abs_v"), _no_search, _coulomb_asym_derived),
    Family("stribeck", "friction above the Coulomb level at low speed, fading over the "
           "Stribeck speed v_s (the same in both directions)", _stribeck_cols,
           _named("F_s"), _stribeck_search, _none, shaped=True),
    Family("position_periodic", "a force periodic in position (cogging, screw lead error)",
           _periodic_cols, _named("c1", "s1", "c2", "s2"), _periodic_search,
           _periodic_derived, shaped=True),
    Family("harmonic", "a force periodic in time (a vibration, a disturbance at fixed "
           "frequency)", _time_harmonic_cols, _named("c", "s"), _time_harmonic_search,
           _time_harmonic_derived, shaped=True),
    Family("delay", "the effort acts late relative to the motion (command-to-force lag)",
           _late_effort_cols, _named("gain"), _late_effort_search, _none, shaped=True),
    Family("drift", "a slow change over time (warm-up of the lubricant, a thermal drift)",
           _drift_cols, _named("slope"), _drift_search, _none),
)  # fmt: skip


#: the real-drive families (built and measured on EMPS)
DRIVE: tuple[Family, ...] = (
    Family(
        "viscous_asymmetry",
        "viscous friction that differs by direction: Fv for v < 0, Fv + coefficient "
        "for v > 0 (seals, preload or lubrication that depend on the direction)",
        _viscous_asym_cols,
        lambda s: ("dFv_pos",),
        _no_search,
        _none,
    ),
    Family(
        "friction_curve",
        "the friction-speed curve of each direction (Stribeck): friction at low "
        "speed above (coefficient > 0) or below the Coulomb + viscous line, fading "
        "over the Stribeck speed v_s; bounded, so it extrapolates as the line",
        _friction_curve_cols,
        lambda s: ("pos_Fs", "neg_Fs"),
        _friction_curve_search,
        _none,
    ),
    Family(
        "position_friction",
        "friction that varies smoothly along the travel, per direction (screw "
        "preload, alignment and wear of the guides and the nut along the stroke)",
        _position_friction_cols,
        _position_friction_names,
        _position_friction_search,
        _position_friction_derived,
    ),
    Family(
        "position_harmonics",
        "a force periodic in position with harmonics: the direction-independent part "
        "is cogging / torque ripple / lead error, the part that follows the "
        "direction is friction varying with the screw's turn (at one motor "
        "revolution of travel, 2.5 mm on EMPS: the motor and the screw)",
        _harmonic_cols,
        _harmonic_names,
        _harmonic_search,
        _harmonic_derived,
    ),
    Family(
        "drive_delay",
        "the drive's force acts late by a pure delay (the controller's zero-order "
        "hold, the current loop): the effort matches the motion a little later",
        _delay_cols,
        lambda s: ("gain",),
        _delay_search,
        _delay_derived,
    ),
    Family(
        "force_lag",
        "a first-order lag of the drive's force loop: command = force + T * "
        "d(force)/dt; the coefficient is the time constant T [s]",
        _lag_cols,
        lambda s: ("T_lag",),
        _lag_search,
        _none,
    ),
)


def _load_cols(shape: Shape, s: Kin) -> F64:
    load = getattr(s, "load", None)
    if load is None:
        return np.zeros((len(s.qd), 3))
    return np.column_stack([load, load * s.qd, load * np.sign(s.qd)])


#: a process load (cutting) on the rows marked as loaded: an effort during the cut, a part
#: proportional to the feed speed (chip thickness grows with the feed at a constant
#: spindle speed), a part by direction; offered only when the log marks those rows
LOAD = Family(
    "load",
    "a process load (cutting) on the rows where it acts: an offset F_0, a part k_v "
    "proportional to the speed (the chip thickness grows with the feed), a part F_c by "
    "direction of motion",
    _load_cols,
    lambda s: ("F_0", "k_v", "F_c"),
    _no_search,
    _none,
)

#: every family of the rigid model, in the order a round scores them
FAMILIES: dict[str, Family] = {f.name: f for f in (*CANONICAL, *DRIVE, LOAD)}

#: built and measured on EMPS, not offered by default, with the reason (docs/residual-emps.md)
NOT_OFFERED: dict[str, str] = {
    "load": "needs the rows where the load acts (--load-rows)",
    "viscous_asymmetry": "spanned by coulomb_asymmetry (the benchmark's asymmetric variant, "
    "which reports Fv_pos and Fv_neg): offering both names one effect twice",
    "friction_curve": "on EMPS no better than the symmetric Stribeck family (record halves "
    "1.96 / 2.24 % either way) and worse where the fit has low accelerations (scored at "
    "high |qdd|: 6.8 % against 2.9 %): its per-direction levels rest on the few reversals",
}
#: the real-drive families offered to the residual analysis
NAMES: tuple[str, ...] = tuple(f.name for f in DRIVE if f.name not in NOT_OFFERED)
#: THE REGISTRY of the rigid model: the families its analysis offers (a new family is
#: one entry of CANONICAL or DRIVE)
OFFERED: dict[str, Family] = {n: f for n, f in FAMILIES.items() if n not in NOT_OFFERED}
