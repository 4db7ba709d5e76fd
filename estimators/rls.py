r"""Rectangular-window recursive least squares with projection (seed000 (9)-(15)) and
its switching variant (seed001 (11)-(12), Fig. 6).

Choices where the papers are ambiguous or garbled
-------------------------------------------------
* seed000 (11)-(12) as printed update and downdate with the same old regressor and with the
  same sign. We implement the rectangular window as intended: a Sherman-Morrison
  *downdate* of the sample leaving the window,
  :math:`P' = P + P\varphi_o\varphi_o^T P/(1 - \varphi_o^T P \varphi_o)`, then an
  *update* with the new sample, :math:`P = P' - P'\varphi\varphi^T P'/(1 + \varphi^T P'
  \varphi)`.
* The window holds the last ``L`` *accepted* samples (those for which the excitation
  condition held). Updates are skipped when it does not hold (P[k] = P[k-1], seed 000
  III.C); downdating "the sample L steps ago" in time would remove samples that never
  entered.
* Projection and the window's memory. seed000 (10) forms the increment against the previous
  estimate; once seed000 (13) clips a component, the estimate is no longer the window's
  least-squares solution and that error is carried forward unchanged by the recursion —
  it never leaves the window. We therefore keep the window's information vector beside P
  (both are downdated as samples leave) and take the increment against the solution it
  defines, :math:`E = P r - \hat\theta[k-1]`; seed000 (13) zeroes the components pushing
  past a bound and the result is clamped into the box so an update never crosses it.
* Conditioning. A 40 ms window of low-passed regressors is nearly collinear (sgn and the
  constant are identical between reversals; J_L and the constant while the acceleration
  is steady), so the window information matrix alone is singular most of the time and a
  pure window solution wanders (measured: it ran to the bounds). :math:`P_0^{-1} = I/p_0`
  is never downdated: it is a ridge, centred on the *previous estimate*:
  :math:`r = \hat\theta[k-1]/p_0 + \sum_{window}\varphi y`. Each update then moves to
  :math:`(I/p_0 + R)^{-1}(\hat\theta[k-1]/p_0 + \sum\varphi y)`, whose fixed point is
  exactly the window least-squares solution wherever the window determines it, while
  directions the window does not determine keep their value instead of drifting (or being
  pulled back to a nominal value). Without clipping and with a negligible ridge this is
  seed000 (10) exactly. Regressors are scaled by ``scale`` (the parameters' magnitudes) so
  that P_0 = p0 I is meaningful.
* Health. After every update P is symmetrised; a downdate denominator <= 1e-9 or a
  non-positive diagonal entry means P lost positive definiteness: the RLS is reset
  (P = P_0, window cleared, estimate kept) and the reset counted in the diagnostics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import NDArray

from common.arrays import F64
from estimators.errors import ParameterError, require_positive
from estimators.filters import DiscreteFilter, df2t_step, lowpass

I64 = NDArray[np.int64]


@dataclass(frozen=True)
class RLSParams:
    """Design of one rectangular-window RLS."""

    window: int  # L (seed 000 Table II: 100 samples)
    scale: tuple[float, ...]  # magnitude of each parameter (regressor scaling)
    lower: tuple[float, ...]  # projection bounds (seed000 (13))
    upper: tuple[float, ...]
    p0: float = 100.0  # initial covariance in scaled units (ridge 1/p0)

    def __post_init__(self) -> None:
        n = len(self.scale)
        if n < 1:
            raise ParameterError("scale", "at least one parameter", self.scale)
        if int(self.window) != self.window or self.window < n:
            raise ParameterError(
                "window", f"an integer >= the number of parameters ({n})", self.window
            )
        if len(self.lower) != n or len(self.upper) != n:
            raise ParameterError(
                "lower/upper", f"{n} bounds each", (len(self.lower), len(self.upper))
            )
        for s in self.scale:
            require_positive("scale", s)
        for lo, hi in zip(self.lower, self.upper, strict=True):
            if math.isnan(lo) or math.isnan(hi) or not lo < hi:
                raise ParameterError("lower/upper", "lower < upper for every parameter", (lo, hi))
        require_positive("p0", self.p0)

    @property
    def n(self) -> int:
        return len(self.scale)


@dataclass
class RLSState:
    """Explicit state: covariance, information vector, estimate (scaled) and window."""

    P: F64
    r: F64
    theta: F64  # scaled estimate
    buf_phi: F64  # (L, n) accepted scaled regressors
    buf_y: F64
    meta: I64  # [head, count, resets]

    @property
    def arrays(self) -> RLSArrays:
        """The same arrays as the kernels take them (updated in place by them)."""
        return RLSArrays(self.P, self.r, self.theta, self.buf_phi, self.buf_y, self.meta)


class RLSArrays(NamedTuple):
    """One window RLS's arrays, named, as its kernels take them (an :class:`RLSState`'s)."""

    P: F64  # covariance (scaled)
    r: F64  # information vector: theta / p0 + sum over the window of phi y
    theta: F64  # scaled estimate
    buf_phi: F64  # (L, n) the window's accepted scaled regressors (a ring)
    buf_y: F64  # the window's outputs
    meta: I64  # [head, count, resets] (META_*)


class Box(NamedTuple):
    """A model's parameter scaling and its projection bounds (seed000 (13)), scaled."""

    scale: F64  # magnitude of each parameter
    lower: F64  # lower bound / scale
    upper: F64  # upper bound / scale


class Ridge(NamedTuple):
    """How an RLS update treats its ridge: P_0 = p0 I, and whether it follows the
    estimate (1) or stays on the initial one (0) (module docstring, "Conditioning")."""

    p0: float
    follow: int


class IdentOut(NamedTuple):
    """An identifier kernel's per-sample outputs (filled in place)."""

    theta: F64  # (n, 4) J_L, B_L, F_CL, F_cut_DC after each sample
    mode: NDArray[np.int8]  # 0: no update, 3 or 4: the model updated
    excited: NDArray[np.bool_]  # the excitation condition held


def rls_adopt(p: RLSParams, state: RLSState) -> RLSState:
    """``state``, of a window RLS of another length (a rate change mid-stream: the
    window is a time, its length in samples follows the rate), in one of ``p``'s: the
    estimate, covariance and information kept, the window's newest rows kept in order;
    rows the shorter window no longer holds leave it as the kernel's downdate takes them
    (a downdate that would lose positive definiteness: the window starts empty on the
    kept estimate, as the kernel's reset)."""
    fresh = rls_init(p, np.zeros(p.n))
    L_old = state.buf_phi.shape[0]
    head, count = int(state.meta[META_HEAD]), int(state.meta[META_COUNT])
    order = [(head + j) % L_old for j in range(count)]
    P, r, th = state.P.copy(), state.r.copy(), state.theta.copy()
    drop = max(0, count - p.window)
    for i in order[:drop]:
        phi, y = state.buf_phi[i], float(state.buf_y[i])
        Pp = P @ phi
        d = 1.0 - float(phi @ Pp)
        if d <= 1e-9:  # the kernel's reset: an empty window on the estimate
            P, r, order, drop = np.eye(p.n) * p.p0, th / p.p0, [], 0
            break
        P = P + np.outer(Pp, Pp) / d
        r = r - phi * y
    kept = order[drop:]
    fresh.buf_phi[: len(kept)] = state.buf_phi[kept]
    fresh.buf_y[: len(kept)] = state.buf_y[kept]
    fresh.meta[:] = (0, len(kept), state.meta[META_RESETS])
    return RLSState(P=P, r=r, theta=th, buf_phi=fresh.buf_phi, buf_y=fresh.buf_y,
                    meta=fresh.meta)  # fmt: skip


def rls_init(p: RLSParams, theta0: F64) -> RLSState:
    """Fresh state with estimate ``theta0`` (physical units), clamped into the bounds."""
    sc = np.asarray(p.scale, dtype=np.float64)
    th0 = np.clip(np.asarray(theta0, dtype=np.float64), p.lower, p.upper) / sc
    P = np.eye(p.n) * p.p0
    return RLSState(
        P=P,
        r=th0 / p.p0,
        theta=th0,
        buf_phi=np.zeros((p.window, p.n)),
        buf_y=np.zeros(p.window),
        meta=np.zeros(3, dtype=np.int64),
    )


def rls_box(p: RLSParams) -> Box:
    """The kernels' scaling and scaled bounds of ``p``."""
    sc = np.array(p.scale)
    return Box(sc, np.array(p.lower) / sc, np.array(p.upper) / sc)


# Index of each entry of a buffered RLS's ``meta`` (RLSState.meta): the ring buffer's
# head, the samples it holds, the covariance resets so far
META_HEAD, META_COUNT, META_RESETS = 0, 1, 2
# Index of each entry of the switching identifier's ``sw`` (IdentState.sw): samples since
# the last velocity reversal, the regressor mode in charge (4 or 3), the F_CL used
# (physical) and the sign of the velocity
SW_SINCE_REVERSAL, SW_MODE, SW_F_CL, SW_SIGN = 0, 1, 2, 3


@njit(cache=True)
def _reset(P, r, th, meta, p0):  # pragma: no cover
    n = len(th)
    # P = p0 I, r = theta / p0: the window emptied
    for i in range(n):
        for j in range(n):
            P[i, j] = p0 if i == j else 0.0
        r[i] = th[i] / p0
    meta[META_HEAD] = 0
    meta[META_COUNT] = 0
    meta[META_RESETS] += 1


@njit(cache=True)
def rebuild_information(r, th, buf_phi, buf_y, meta, p0):  # pragma: no cover
    """Re-establish r = theta / p0 + sum over the window of phi y (after a hand-over)."""
    n = len(th)
    L = buf_phi.shape[0]
    for i in range(n):
        r[i] = th[i] / p0
    for q in range(meta[META_COUNT]):
        h = (meta[META_HEAD] + q) % L
        for i in range(n):
            r[i] += buf_phi[h, i] * buf_y[h]


@njit(cache=True)
def rebuild_covariance(P, buf_phi, meta, p0):  # pragma: no cover
    """P = (I / p0 + sum over the window of phi phi^T)^-1, from the window itself."""
    n = P.shape[0]
    L = buf_phi.shape[0]
    R = np.zeros((n, n))
    for i in range(n):
        R[i, i] = 1.0 / p0
    for q in range(meta[META_COUNT]):
        h = (meta[META_HEAD] + q) % L
        for i in range(n):
            for j in range(n):
                R[i, j] += buf_phi[h, i] * buf_phi[h, j]
    P[:, :] = np.linalg.inv(R)


# The matrix products of rls_update, written once. Each keeps the summation order of the
# scalar loops it replaced (the outputs are bit-identical); numpy's ``P @ phi`` and
# ``np.outer`` in their place allocate and call BLAS per sample: measured 4.5x slower for
# the update's products at n = 4, and not bit-identical (docs/benchmarks.md).


@njit(cache=True, inline="always")
def _mat_vec(A, v, out):  # pragma: no cover
    """out = A v."""
    n = len(v)
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += A[i, j] * v[j]
        out[i] = acc


@njit(cache=True, inline="always")
def _dot(u, v, start=0.0, sign=1.0):  # pragma: no cover
    """start + sign u^T v, summed term by term onto ``start`` (``sign`` is +-1)."""
    acc = start
    for i in range(len(u)):
        acc += sign * u[i] * v[i]
    return acc


@njit(cache=True, inline="always")
def _add_outer(A, u, d):  # pragma: no cover
    """A <- A + u u^T / d."""
    n = len(u)
    for i in range(n):
        for j in range(n):
            A[i, j] += u[i] * u[j] / d


@njit(cache=True, inline="always")
def _sub_outer(A, u, d):  # pragma: no cover
    """A <- A - u u^T / d."""
    n = len(u)
    for i in range(n):
        for j in range(n):
            A[i, j] -= u[i] * u[j] / d


@njit(cache=True, inline="always")
def _add_scaled(a, u, s):  # pragma: no cover
    """a <- a + s u."""
    for i in range(len(u)):
        a[i] += u[i] * s


@njit(cache=True, inline="always")
def _healthy_symmetrised(P):  # pragma: no cover
    """P <- (P + P^T) / 2; False (P left as is from the bad entry on) if a diagonal entry
    is not positive and finite."""
    n = P.shape[0]
    for i in range(n):
        if P[i, i] <= 0.0 or not np.isfinite(P[i, i]):
            return False
        for j in range(i + 1, n):
            s = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = s
            P[j, i] = s
    return True


@njit(cache=True)
def rls_update(w, box, ridge, phi, y):  # pragma: no cover
    """One accepted sample (scaled regressor ``phi``, output ``y``) into the window RLS
    ``w`` (:class:`RLSArrays`) with the bounds of ``box`` (:class:`Box`). Returns 1 on
    reset.

    ``ridge.follow`` = 1: the ridge follows the estimate (our default); 0: the ridge stays
    on the initial estimate (the papers' recursion, whose P_0 is never downdated either).
    """
    P, r, th, buf_phi, buf_y, meta = w.P, w.r, w.theta, w.buf_phi, w.buf_y, w.meta
    L = buf_phi.shape[0]
    Pp = np.empty(len(th))
    was_reset = 0
    if meta[META_COUNT] == L:
        # downdate: the oldest accepted sample leaves the window (seed000 (12), sign fixed)
        h = meta[META_HEAD]
        phi_o = buf_phi[h]
        _mat_vec(P, phi_o, Pp)  # P phi_o
        d = _dot(phi_o, Pp, 1.0, -1.0)  # 1 - phi_o^T P phi_o
        if d <= 1e-9:
            # P lost positive definiteness: reset (window emptied), then the new sample
            # is added below as the first of the fresh window
            _reset(P, r, th, meta, ridge.p0)
            was_reset = 1
        else:
            _add_outer(P, Pp, d)  # P <- P + P phi_o phi_o^T P / (1 - phi_o^T P phi_o)
            _add_scaled(r, phi_o, -buf_y[h])  # r <- r - phi_o y_o
            meta[META_HEAD] = (h + 1) % L
            meta[META_COUNT] -= 1
    # update with the new sample (seed000 (11))
    _mat_vec(P, phi, Pp)  # P phi
    d = _dot(phi, Pp, 1.0)  # 1 + phi^T P phi
    _sub_outer(P, Pp, d)  # P <- P - P phi phi^T P / (1 + phi^T P phi)
    _add_scaled(r, phi, y)  # r <- r + phi y
    h = (meta[META_HEAD] + meta[META_COUNT]) % L
    buf_phi[h, :] = phi
    buf_y[h] = y
    meta[META_COUNT] += 1
    if not _healthy_symmetrised(P):  # P <- (P + P^T) / 2, positive diagonal
        _reset(P, r, th, meta, ridge.p0)
        return 1
    # seed000 (9)-(10): increment towards the window's least-squares solution P r, row by
    # row: with the ridge following the estimate, r[i] moves before row i + 1 is formed
    # (as it always has; the outputs stay bit-identical)
    for i in range(len(th)):
        # theta <- clamp(theta + Proj(P r - theta), lo, hi)
        e = _dot(P[i], r) - th[i]
        # seed000 (13): discontinuous projection; then clamp so no update crosses a bound
        if (th[i] >= box.upper[i] and e > 0.0) or (th[i] <= box.lower[i] and e < 0.0):
            e = 0.0
        v = min(max(th[i] + e, box.lower[i]), box.upper[i])
        # the ridge follows the estimate: r = theta / p0 + sum phi y
        if ridge.follow:
            r[i] += (v - th[i]) / ridge.p0
        th[i] = v
    return was_reset


#: Q_RLS's cut-off (seed 000 Table II) [Hz] and the RLS window (100 samples at 2.5 kHz) [s]
Q_RLS_HZ = 12.0
WINDOW_S = 0.04


def q_rls_cutoff(sample_time: float) -> float:
    """Q_RLS's cut-off for a rate: seed 000's 12 Hz, at most a tenth of the rate."""
    return min(Q_RLS_HZ, 0.1 / require_positive("sample_time", sample_time))


@dataclass(frozen=True)
class IdentifierParams:
    """Load-side identification on the regression model of seed000 (14).

    Parameter order inside: ``[J_L, B_L, F_CL, F_cut_DC]``.
    """

    sample_time: float = 4e-4
    # seed 000 Table II (seed 001 Table 2: 40 Hz); nan: designed from the rate, 12 Hz or a
    # tenth of the rate below 120 Hz (q_rls_cutoff)
    q_rls_hz: float = math.nan
    # Q_RLS order. The papers name only "an LPF". A first-order Q_RLS at 12 Hz passes
    # 12 % of the 100 Hz force, which is strongly correlated with the 100 Hz load
    # acceleration it causes and biases J_L; second order passes 1.4 %, third 0.17 %.
    # Measured, batch LS over every excited sample of the seed-000 run: J_L = 2.59e-4
    # (second order), 2.82e-4 (third; truth 2.80e-4), negative (first).
    q_rls_order: int = 3
    # L (seed 000 Table II: 100 samples, 40 ms at 2.5 kHz); 0: designed from the rate,
    # the window's 40 ms (WINDOW_S)
    window: int = 0
    acc_threshold: float = 50.0  # |Q_RLS d omega_L/dt| above this: update [rad/s^2]
    scale: tuple[float, float, float, float] = (2.8e-4, 2e-3, 0.15, 1.0)
    # seed 000 IV.A: J_L, B_L, F_CL in (0, R), F_cut_DC in R
    lower: tuple[float, float, float, float] = (1e-6, 0.0, 0.0, -1e3)
    upper: tuple[float, float, float, float] = (1.0, 10.0, 50.0, 1e3)
    # Initial covariance (scaled units): the ridge 1/p0 = 10, centred on the previous
    # estimate (see the module docstring). Measured on the seed-000 run (20 s): p0 = 0.1
    # identifies J_L to -4 % (-2 % with the weight); p0 = 10 to -27 %; p0 = 100 to -48 %.
    p0: float = 0.1
    # "previous": the ridge follows the estimate (ours); "initial": it stays on the
    # initial estimate, as the papers' recursion (their P_0 is never downdated either)
    ridge: str = "previous"

    def __post_init__(self) -> None:
        require_positive("sample_time", self.sample_time)
        if math.isnan(self.q_rls_hz):
            object.__setattr__(self, "q_rls_hz", q_rls_cutoff(self.sample_time))
        if self.window == 0:
            object.__setattr__(self, "window", max(4, round(WINDOW_S / self.sample_time)))
        nyq = 0.5 / self.sample_time
        if not (0 < self.q_rls_hz < nyq):
            raise ParameterError("q_rls_hz", f"a cut-off in (0, {nyq:g}) Hz", self.q_rls_hz)
        if self.acc_threshold < 0 or not math.isfinite(self.acc_threshold):
            raise ParameterError("acc_threshold", "a finite value >= 0", self.acc_threshold)
        _ = self.rls4  # validates window, bounds, scale
        if self.ridge not in ("previous", "initial"):
            raise ParameterError("ridge", "'previous' or 'initial'", self.ridge)

    @property
    def rls4(self) -> RLSParams:
        return RLSParams(self.window, self.scale, self.lower, self.upper, self.p0)

    @property
    def rls3(self) -> RLSParams:
        idx = (0, 1, 3)
        return RLSParams(
            self.window,
            tuple(self.scale[i] for i in idx),
            tuple(self.lower[i] for i in idx),
            tuple(self.upper[i] for i in idx),
            self.p0,
        )


@dataclass
class IdentRecord:
    """Per-sample outputs of an identifier."""

    theta: F64  # (n, 4): J_L, B_L, F_CL, F_cut_DC used by the observer after this sample
    mode: NDArray[np.int8]  # 0: no update, 3: 3-parameter model, 4: 4-parameter model
    excited: NDArray[np.bool_]  # the excitation condition held
    resets: int  # covariance resets so far
    excitation_index: float  # seed000 (15) min eigenvalue over the window (block end)
    cov_trace: float


@njit(cache=True)
def _filter_regressors(zf, bq, aq, ts_hat, acc, vel, sgn, out_y, out_phi):  # pragma: no cover
    # y = Q_RLS{T_s}, phi = [Q_RLS{d omega_L/dt}, Q_RLS{omega_L}, Q_RLS{sgn omega_L}, 1] (seed000
    #  (14))
    for k in range(len(ts_hat)):
        out_y[k] = df2t_step(bq, aq, zf[0], ts_hat[k])
        out_phi[k, 0] = df2t_step(bq, aq, zf[1], acc[k])
        out_phi[k, 1] = df2t_step(bq, aq, zf[2], vel[k])
        out_phi[k, 2] = df2t_step(bq, aq, zf[3], sgn[k])
        out_phi[k, 3] = 1.0


#: Q_RLS on the torsional torque and the three regressors of eq. (14) (public name)
filter_regressors = _filter_regressors


@njit(cache=True)
def _ordinary_kernel(y, phi, thr, w, box, ridge, out):  # pragma: no cover
    """The ordinary identifier over a block: the window RLS ``w`` on the filtered output
    ``y`` and regressors ``phi`` of eq. (14), updated where ``|phi_acc| > thr``."""
    sc = box.scale
    n = len(w.theta)
    ph = np.empty(n)
    # theta[k] = window RLS update of theta[k-1] with (phi[k], y[k]) if |phi_acc[k]| > thr (seed000
    #  (15)), else theta[k-1]
    for k in range(len(y)):
        exc = abs(phi[k, 0]) > thr
        out.excited[k] = exc
        out.mode[k] = 0
        if exc:
            for i in range(n):
                ph[i] = phi[k, i] * sc[i]
            rls_update(w, box, ridge, ph, y[k])
            out.mode[k] = 4
        for i in range(n):
            out.theta[k, i] = w.theta[i] * sc[i]


@njit(cache=True)
def _switching_kernel(y, phi, rev, thr, L, w4, box4, w3, box3, ridge, sw, out):  # pragma: no cover
    """The switching identifier over a block (seed 001 Fig. 6): the 4-parameter RLS ``w4``
    while a velocity reversal (sign change of ``rev``) lies within the last ``L``
    samples, else the 3-parameter RLS ``w3`` with F_CL held; ``sw`` its switch state
    (SW_*)."""
    # sw = [samples since the last reversal, mode in charge, F_CL used (physical), sign]
    sc4, sc3 = box4.scale, box3.scale
    th4, th3 = w4.theta, w3.theta
    bp4, by4, bp3, by3 = w4.buf_phi, w4.buf_y, w3.buf_phi, w3.buf_y
    m4, m3 = w4.meta, w3.meta
    p0 = ridge.p0
    idx3 = np.array([0, 1, 3])
    ph4 = np.empty(4)
    ph3 = np.empty(3)
    # theta[k] = update of the model in charge: 4 parameters (seed001 (11)) while a reversal is in
    #  the window, else 3 (seed001 (12))
    for k in range(len(y)):
        s = 1.0 if rev[k] > 0 else (-1.0 if rev[k] < 0 else 0.0)
        if s != 0.0 and s != sw[SW_SIGN]:
            if sw[SW_SIGN] != 0.0:
                sw[SW_SINCE_REVERSAL] = 0.0
            sw[SW_SIGN] = s
        else:
            sw[SW_SINCE_REVERSAL] += 1.0
        exc = abs(phi[k, 0]) > thr
        out.excited[k] = exc
        # Fig. 6(a): the 4-parameter model while a reversal lies within the window
        # (its PE condition), the 3-parameter model on acceleration alone, else none
        mode = 0
        if exc:
            mode = 4 if sw[SW_SINCE_REVERSAL] < L else 3
        prev = int(sw[SW_MODE])
        if mode == 3 and prev == 4:
            # Fig. 6(b): hand over J_L, B_L, F_DC and the matching covariance to the
            # 3-parameter RLS. "Matching" is the covariance of the 3-parameter model over
            # the same window (F_CL now known): rebuilt from the window's regressors. The
            # sub-block of P4 still carries F_CL's uncertainty; handing it over made the
            # 3-parameter window inconsistent with its samples (measured: divergence).
            sw[SW_F_CL] = th4[2] * sc4[2]
            for q in range(bp4.shape[0]):
                for i in range(3):
                    bp3[q, i] = bp4[q, idx3[i]] / sc4[idx3[i]] * sc3[i]
                by3[q] = by4[q] - sw[SW_F_CL] * bp4[q, 2] / sc4[2]
            m3[0] = m4[0]
            m3[1] = m4[1]
            for i in range(3):
                th3[i] = th4[idx3[i]] * sc4[idx3[i]] / sc3[i]
            rebuild_covariance(w3.P, bp3, m3, p0)
            rebuild_information(w3.r, th3, bp3, by3, m3, p0)
        elif mode == 4 and prev == 3:
            # back to the 4-parameter RLS. It kept updating on the same samples
            # (seed 001 3.4), so its covariance already matches its window; it takes over
            # the 3-parameter estimate (J_L, B_L, F_DC) and keeps its own F_CL.
            for i in range(3):
                th4[idx3[i]] = th3[i] * sc3[i] / sc4[idx3[i]]
            rebuild_information(w4.r, th4, bp4, by4, m4, p0)
        if mode == 4:
            for i in range(4):
                ph4[i] = phi[k, i] * sc4[i]
            rls_update(w4, box4, ridge, ph4, y[k])
            sw[SW_F_CL] = th4[2] * sc4[2]
        elif mode == 3:
            # seed001 (12): y3 = Q_RLS(T_s - F_CL sgn(omega_L)) with the held F_CL
            y3 = y[k] - sw[SW_F_CL] * phi[k, 2]
            for i in range(3):
                ph3[i] = phi[k, idx3[i]] * sc3[i]
            rls_update(w3, box3, ridge, ph3, y3)
            # seed 001 3.4: the 4-parameter RLS keeps updating (not used by the observer)
            for i in range(4):
                ph4[i] = phi[k, i] * sc4[i]
            rls_update(w4, box4, ridge, ph4, y[k])
        if mode != 0:
            sw[SW_MODE] = mode
        out.mode[k] = mode
        if int(sw[SW_MODE]) == 3:
            out.theta[k, 0] = th3[0] * sc3[0]
            out.theta[k, 1] = th3[1] * sc3[1]
            out.theta[k, 2] = sw[SW_F_CL]
            out.theta[k, 3] = th3[2] * sc3[2]
        else:
            for i in range(4):
                out.theta[k, i] = th4[i] * sc4[i]


def excitation_index(state: RLSState) -> float:
    """seed000 (15): smallest eigenvalue of (1/L) sum phi phi^T over the window (scaled).

    While the window fills, the mean is over the samples it holds.
    """
    c = int(state.meta[META_COUNT])
    if c == 0:
        return 0.0
    h = int(state.meta[META_HEAD])
    L = state.buf_phi.shape[0]
    idx = (h + np.arange(c)) % L
    ph = state.buf_phi[idx]
    # over the samples the window holds (fewer than L while it fills)
    m = ph.T @ ph / c
    return float(np.linalg.eigvalsh(m)[0])


def _copy(s: RLSState) -> RLSState:
    return RLSState(
        s.P.copy(), s.r.copy(), s.theta.copy(), s.buf_phi.copy(), s.buf_y.copy(), s.meta.copy()
    )


@dataclass
class IdentState:
    zf: F64  # Q_RLS filter states (y, acc, vel, sgn)
    rls4: RLSState
    rls3: RLSState | None = None
    sw: F64 | None = None


class LoadIdentifier:
    """Adaptive identification of J_L, B_L, F_CL (seed 000 III.C; ``switching=True``:
    seed 001 3.4, Fig. 6)."""

    def __init__(self, params: IdentifierParams, switching: bool = False) -> None:
        self.params = params
        self.switching = switching
        self.q_rls: DiscreteFilter = lowpass(
            params.q_rls_hz, params.sample_time, params.q_rls_order
        )
        # the kernels' read-only arrays, built once (params are frozen), not per block:
        # (scale, lower / scale, upper / scale) of the 4- and 3-parameter models
        # arrays, not the records: a checkpoint (common.state_io) gives a kept NamedTuple
        # back as a plain tuple; the records are made per block in step()
        b4, b3 = rls_box(params.rls4), rls_box(params.rls3)
        self._sc4, self._lo4, self._hi4 = b4.scale, b4.lower, b4.upper
        self._sc3, self._lo3, self._hi3 = b3.scale, b3.lower, b3.upper

    def initial_state(self, J_L: float, B_L: float, F_CL: float, F_dc: float = 0.0) -> IdentState:
        p = self.params
        z = np.zeros((4, max(self.q_rls.order, 1)))
        s4 = rls_init(p.rls4, np.array([J_L, B_L, F_CL, F_dc]))
        if not self.switching:
            return IdentState(zf=z, rls4=s4)
        s3 = rls_init(p.rls3, np.array([J_L, B_L, F_dc]))
        return IdentState(zf=z, rls4=s4, rls3=s3, sw=np.array([1e9, 4.0, F_CL, 0.0]))

    def adopt(self, state: IdentState, sample_time: float) -> IdentState:
        """The state of an identifier at another ``sample_time`` carried into this one
        (a rate change mid-stream): the estimates, covariances and window rows kept (in
        physical units whatever the rate; :func:`rls_adopt`), the Q_RLS filters
        restarted; the switching identifier's mode, F_CL and sign kept, its samples since
        the last reversal converted to this rate's."""
        p = self.params
        z = np.zeros((4, max(self.q_rls.order, 1)))
        s4 = rls_adopt(p.rls4, state.rls4)
        if not self.switching or state.rls3 is None or state.sw is None:
            return IdentState(zf=z, rls4=s4)
        sw = state.sw.copy()
        sw[SW_SINCE_REVERSAL] *= sample_time / p.sample_time
        return IdentState(zf=z, rls4=s4, rls3=rls_adopt(p.rls3, state.rls3), sw=sw)

    def step(
        self,
        state: IdentState,
        t_s: F64,
        acc_l: F64,
        vel_l: F64,
        sgn_l: F64,
        omega_l: F64,
        *,
        excitation: bool = True,
    ) -> tuple[IdentState, IdentRecord]:
        """One block: filter by Q_RLS (seed000 (14)), test excitation, update, report.

        ``excitation=False`` skips the record's ``excitation_index`` (NaN then), an
        eigenvalue problem per block, for a caller that does not read it.
        """
        p = self.params
        n = len(t_s)
        new = IdentState(
            zf=state.zf.copy(),
            rls4=_copy(state.rls4),
            rls3=_copy(state.rls3) if state.rls3 is not None else None,
            sw=state.sw.copy() if state.sw is not None else None,
        )
        y = np.empty(n)
        phi = np.empty((n, 4))
        _filter_regressors(new.zf, self.q_rls.b, self.q_rls.a, t_s, acc_l, vel_l, sgn_l, y, phi)
        out = IdentOut(np.empty((n, 4)), np.empty(n, dtype=np.int8), np.empty(n, dtype=np.bool_))
        a = new.rls4
        box4 = Box(self._sc4, self._lo4, self._hi4)
        ridge = Ridge(p.p0, 1 if p.ridge == "previous" else 0)
        if not self.switching:
            _ordinary_kernel(y, phi, p.acc_threshold, a.arrays, box4, ridge, out)
            resets = int(a.meta[META_RESETS])
        else:
            assert new.rls3 is not None and new.sw is not None
            b = new.rls3
            _switching_kernel(
                y,
                phi,
                np.ascontiguousarray(omega_l),
                p.acc_threshold,
                float(p.window),
                a.arrays,
                box4,
                b.arrays,
                Box(self._sc3, self._lo3, self._hi3),
                ridge,
                new.sw,
                out,
            )
            resets = int(a.meta[META_RESETS] + b.meta[META_RESETS])
        return new, IdentRecord(
            theta=out.theta,
            mode=out.mode,
            excited=out.excited,
            resets=resets,
            excitation_index=excitation_index(a) if excitation else math.nan,
            cov_trace=float(np.trace(a.P)),
        )
