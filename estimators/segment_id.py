r"""Gated segment identification of J_L, B_L, F_CL with 95 % intervals and excitation flags.

The papers' rectangular-window RLS (seed 000 eq. (9)-(15), seed 001 Fig. 6, in
:mod:`estimators.rls`) fits seed 000 eq. (14),

.. math:: Q_{RLS} \hat T_s = J_L\,Q_{RLS} s\omega_L + B_L\,Q_{RLS}\omega_L
          + F_{CL}\,Q_{RLS}\mathrm{sgn}\,\omega_L + F_{DC},

over the last 100 *accepted* samples (40 ms). On the default live scenario that window
is ill posed for three reasons (measured in ``docs/live-identification.md``): inside one
reversal ramp the acceleration is constant, so J_L and F_DC are collinear; B_L and F_CL
differ only by the shape of one ramp; and a cutting-force DC that changes between
windows (wear, spindle speed, tool change) is absorbed by whichever regressor happens to
be constant in the window. This module estimates what the data can determine and says
how sure it is:

1. **Segments.** Identification is gated to *reversal segments*: from ``pre`` seconds
   before the first sample whose filtered acceleration exceeds ``acc_threshold`` to
   ``post`` seconds after the last one. A segment with a known change of the cutting
   condition inside it (:func:`mark_disturbance`: spindle step, tool change) is
   discarded, since a DC step there is indistinguishable from friction.
2. **Batch LS per segment** on eq. (14)'s regressors with two nuisance columns, a DC and
   a DC slope *of this segment* (the cutting force's DC is a different unknown in every
   segment; a smooth wear drift is its slope). The plateaus before and after the ramp
   make the acceleration pulse distinct from the DC, so J_L is determined by one reversal;
   B_L and F_CL are separated by the ramp's shape only (weakly).
3. **Segment covariance.** :math:`\mathrm{Cov}\,\hat\theta = s^2 (A^T A)^{-1}\,n/n_{eff}`:
   the classical LS covariance with the residual variance :math:`s^2 = e^Te/(n-5)`,
   corrected for the residual's autocorrelation. The residual is low-passed by Q_RLS
   (12 Hz, third order), so neighbouring samples are not independent; the effective
   sample count :math:`n_{eff} = n/(1 + 2\sum_{l\ge1}\rho_l)` sums the residual's sample
   autocorrelation up to its first non-positive lag (Geyer's initial-positive-sequence
   rule). This assumes the regressors vary slowly against the residual's correlation
   time (they are low-passed by the same filter), so the score :math:`\varphi e` is
   correlated like :math:`e`. The interval uses Student's t with :math:`n_{eff}-5`
   degrees of freedom.
4. **Tracking across segments** by a Kalman filter per parameter on the segment
   estimates (measurement = segment estimate, its variance from 3.): J_L with a locally
   linear drift (state value and slope; white noise on the slope), B_L and F_CL as
   random walks. Between segments the estimate is the filter's prediction and its
   variance grows with the time since the last segment, so the interval says that an
   old estimate is less certain. An innovation beyond ``gate`` standard deviations is a
   change the model did not expect (a fresh workpiece, a log with no events): the
   parameter restarts from that segment. :func:`restart` does the same on a known event.
5. **Model error.** An error that is the same in every segment does not show in the
   residual (measured: the cutting force's harmonics during the reversal bias B_L and
   F_CL). ``model_error`` is a Type B standard uncertainty relative to the estimate,
   added to each segment's variance and to the streamed variance (it does not average
   out over segments).
6. **Excitation.** A parameter is *excited* when its 95 % half-width is at most
   ``excited_rel`` times its estimate (the data determine it to that fraction). Before
   its first segment and after a restart it is not excited and its interval is the
   prior (nominal +- z ``prior_rel`` nominal, clipped at 0); while its own interval is
   wider than that fraction it keeps its interval and is flagged not excited.

The per-sample work is the Q_RLS filter (numba, shared with :mod:`estimators.rls`) and
the output (a numba kernel evaluating the Kalman prediction per sample); the segment fit
runs once per segment (every reversal, a few seconds) on the segment's samples, kept at
one in ``decimation``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy import stats

from common.arrays import F64
from estimators.errors import ParameterError, require_positive
from estimators.filters import DiscreteFilter, lowpass
from estimators.rls import filter_regressors, q_rls_cutoff

NAMES = ("J_L", "B_L", "F_CL")
#: the rows per second the segment fit keeps (every 10th sample at 2.5 kHz)
HISTORY_HZ = 250.0


@dataclass(frozen=True)
class SegmentIdentifierParams:
    """Design of the segment identifier (units: J_L kg m^2, B_L N m s/rad, F_CL N m)."""

    nominal: tuple[float, float, float]  # prior estimate (the drive's nominal model)
    sample_time: float = 4e-4
    q_rls_hz: float = math.nan  # seed 000 Table II, as the RLS (nan: q_rls_cutoff)
    q_rls_order: int = 3  # as estimators.rls.IdentifierParams (why: there)
    acc_threshold: float = 50.0  # |Q_RLS d omega_L/dt| that opens a segment [rad/s^2]
    pre: float = 0.3  # s of data kept before the first gated sample
    post: float = 0.5  # s after the last gated sample (Q_RLS's settling, ~3 x 13 ms x 3)
    max_segment: float = 2.0  # a gated stretch longer than this is not a reversal [s]
    # the segment fit keeps one sample in ``decimation``: its signals are low-passed at
    # 12 Hz (third order), so 250 Hz loses nothing, and the kept history stays small;
    # 0: designed from the rate, rows at about HISTORY_HZ (10 at 2.5 kHz)
    decimation: int = 0
    level: float = 0.95  # interval coverage
    # Kalman filter across segments. J_L: white noise on its slope, relative to the
    # nominal, [1/s^1.5]; B_L, F_CL: random walk, relative [1/s^0.5]
    slope_noise_J: float = 2e-3
    walk: tuple[float, float] = (2e-3, 2e-3)
    gate: float = 5.0  # innovation (in standard deviations) that restarts a parameter
    excited_rel: tuple[float, float, float] = (0.1, 0.3, 0.2)  # 95 % half-width / |value|
    prior_rel: float = 1.0  # prior standard deviation, relative to the nominal
    # Model error (a Type B standard uncertainty, relative to the estimate) that the
    # segment's residual cannot show: it is the same in every segment. Measured in
    # docs/live-identification.md: the cutting force's 100/200 Hz harmonics during the
    # reversals bias B_L by +4..+12 % and F_CL by -2..-5 %, J_L by ~1 % (without them
    # all three are within 0.3 %).
    model_error: tuple[float, float, float] = (0.015, 0.07, 0.03)
    slope_prior: float = 0.03  # sd of J_L's slope after a restart, nominal per second

    def __post_init__(self) -> None:
        if len(self.nominal) != 3:
            raise ParameterError("nominal", "3 values (J_L, B_L, F_CL)", self.nominal)
        for v in self.nominal:
            require_positive("nominal", v)
        require_positive("sample_time", self.sample_time)
        if math.isnan(self.q_rls_hz):
            object.__setattr__(self, "q_rls_hz", q_rls_cutoff(self.sample_time))
        if self.decimation == 0:
            dec = max(1, round(1.0 / (self.sample_time * HISTORY_HZ)))
            object.__setattr__(self, "decimation", dec)
        nyq = 0.5 / self.sample_time
        if not (0 < self.q_rls_hz < nyq):
            raise ParameterError("q_rls_hz", f"a cut-off in (0, {nyq:g}) Hz", self.q_rls_hz)
        if int(self.q_rls_order) != self.q_rls_order or self.q_rls_order < 1:
            raise ParameterError("q_rls_order", "an integer >= 1", self.q_rls_order)
        for name in ("acc_threshold", "pre", "post", "max_segment", "slope_noise_J"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ParameterError(name, "a finite value >= 0", v)
        if not 0.5 < self.level < 1.0:
            raise ParameterError("level", "a coverage in (0.5, 1)", self.level)
        if len(self.walk) != 2 or not all(math.isfinite(w) and w >= 0 for w in self.walk):
            raise ParameterError("walk", "2 finite values >= 0 (B_L, F_CL)", self.walk)
        if int(self.decimation) != self.decimation or self.decimation < 1:
            raise ParameterError("decimation", "an integer >= 1", self.decimation)
        require_positive("gate", self.gate)
        if len(self.excited_rel) != 3 or not all(0 < x < 10 for x in self.excited_rel):
            raise ParameterError("excited_rel", "3 fractions in (0, 10)", self.excited_rel)
        require_positive("prior_rel", self.prior_rel)
        if len(self.model_error) != 3 or not all(0 <= x < 1 for x in self.model_error):
            raise ParameterError("model_error", "3 fractions in [0, 1)", self.model_error)
        require_positive("slope_prior", self.slope_prior)

    @property
    def z(self) -> float:
        """Two-sided normal quantile of ``level`` (1.96 for 95 %)."""
        return float(stats.norm.ppf(0.5 + 0.5 * self.level))


# Index of each entry of SegmentState.seg: a segment open (1) or not, its first and last
# gated times, the time of the last known disturbance
SEG_OPEN, SEG_FIRST, SEG_LAST, SEG_DISTURBANCE = 0, 1, 2, 3
# Index of each entry of SegmentState.counts
COUNT_USED, COUNT_DISCARDED, COUNT_RESTARTS, COUNT_SAMPLES = 0, 1, 2, 3
# Index of each entry of the kernel's packed design ``d`` (SegmentIdentifier._design): the
# J_L slope noise^2 (walk_B^2, walk_F^2 follow it), the model errors (3), z, the relative
# excitation thresholds (3), the prior's relative spread
D_SLOPE, D_MODEL_ERROR, D_Z, D_EXCITED, D_PRIOR = 0, 3, 6, 7, 10


@dataclass
class SegmentState:
    """Explicit state of the segment identifier."""

    zf: F64  # Q_RLS filter states (y, acc, vel, sgn)
    hist: F64  # (m, 5) decimated samples t, y, acc, vel, sgn (the last pre+max+post s)
    seg: F64  # [open flag, first gated t, last gated t, last known disturbance t]
    x: F64  # (4,) scaled: J_L, dJ_L/dt, B_L, F_CL
    P: F64  # (4, 4) block diagonal: J_L (2x2), B_L, F_CL
    t_upd: F64  # (3,) time of each parameter's last update (nan: never, restarted)
    counts: NDArray[np.int64]  # [segments used, discarded, restarts, samples seen]
    last: F64  # (3,) physical estimate of the last segment used (nan: none)


@dataclass
class SegmentRecord:
    """Per-sample outputs (n samples) and the block's diagnostics."""

    theta: F64  # (n, 3) J_L, B_L, F_CL
    lower: F64  # (n, 3) 95 % interval
    upper: F64
    excited: NDArray[np.bool_]  # (n, 3)
    segments: int  # segments used so far
    discarded: int  # segments discarded (known disturbance inside, ill posed)
    restarts: int  # parameters restarted by the innovation gate
    last_segment: F64  # (3,) estimate of the last segment used (nan: none)


def _kf_blocks(P: F64) -> None:
    """Keep the cross terms between parameters at zero (independent filters)."""
    P[0:2, 2:] = 0.0
    P[2:, 0:2] = 0.0
    P[2, 3] = P[3, 2] = 0.0


class SegmentIdentifier:
    """Gated segment LS + Kalman tracking with intervals (module docstring)."""

    def __init__(self, params: SegmentIdentifierParams) -> None:
        self.params = params
        self.q_rls: DiscreteFilter = lowpass(
            params.q_rls_hz, params.sample_time, params.q_rls_order
        )
        p = params
        span = (p.pre + p.max_segment + p.post) / (p.sample_time * p.decimation)
        self._keep = int(math.ceil(span)) + 1
        self._scale = np.asarray(p.nominal, dtype=np.float64)
        # [slope noise^2, walk_B^2, walk_F^2, model error x3, z, excited_rel x3, prior]
        self._design = np.array(
            [
                p.slope_noise_J**2,
                p.walk[0] ** 2,
                p.walk[1] ** 2,
                *p.model_error,
                p.z,
                *p.excited_rel,
                p.prior_rel,
            ]
        )

    # ------------------------------------------------------------------ state
    def initial_state(self) -> SegmentState:
        prior = self.params.prior_rel**2
        return SegmentState(
            zf=np.zeros((4, max(self.q_rls.order, 1))),
            hist=np.zeros((0, 5)),
            seg=np.array([0.0, math.nan, math.nan, -math.inf]),
            x=np.array([1.0, 0.0, 1.0, 1.0]),
            P=np.diag([prior, 0.0, prior, prior]),
            t_upd=np.full(3, math.nan),
            counts=np.zeros(4, dtype=np.int64),
            last=np.full(3, math.nan),
        )

    # ------------------------------------------------------------------ step
    def step(
        self, state: SegmentState, t: F64, t_s: F64, acc_l: F64, vel_l: F64, sgn_l: F64
    ) -> tuple[SegmentState, SegmentRecord]:
        """One block: filter by Q_RLS (eq. 14), close a finished segment, report.

        ``t`` is the time each front-end sample refers to; ``t_s``, ``acc_l``, ``vel_l``,
        ``sgn_l`` are :class:`estimators.force_observer.TorsionRecord`'s fields.
        """
        p = self.params
        n = len(t_s)
        if not (len(t) == len(acc_l) == len(vel_l) == len(sgn_l) == n):
            raise ParameterError("block", "t, t_s, acc_l, vel_l, sgn_l of equal length", n)
        new = SegmentState(
            zf=state.zf.copy(),
            hist=state.hist,
            seg=state.seg.copy(),
            x=state.x.copy(),
            P=state.P.copy(),
            t_upd=state.t_upd.copy(),
            counts=state.counts.copy(),
            last=state.last.copy(),
        )
        y = np.empty(n)
        phi = np.empty((n, 4))
        filter_regressors(new.zf, self.q_rls.b, self.q_rls.a, t_s, acc_l, vel_l, sgn_l, y, phi)
        blk = np.column_stack([np.asarray(t, dtype=np.float64), y, phi[:, :3]])
        first = (-int(new.counts[COUNT_SAMPLES])) % p.decimation
        new.counts[COUNT_SAMPLES] += n
        new.hist = np.concatenate([state.hist, blk[first :: p.decimation]])[-self._keep :]
        gated = np.abs(phi[:, 0]) > p.acc_threshold
        seg = new.seg
        # the fit of a segment that closes in this block applies from this sample on
        k_close = n
        if gated.any():
            tg = blk[gated, 0]
            if seg[SEG_OPEN] == 0.0:
                seg[SEG_OPEN], seg[SEG_FIRST] = 1.0, tg[0]
            seg[SEG_LAST] = tg[-1]
        if seg[SEG_OPEN] == 1.0:
            t_end = seg[SEG_LAST] + p.post
            if blk[-1, 0] >= t_end:
                k_close = int(np.searchsorted(blk[:, 0], t_end))
                self._close(new, seg[SEG_FIRST] - p.pre, t_end)
                seg[SEG_OPEN], seg[SEG_FIRST], seg[SEG_LAST] = 0.0, math.nan, math.nan
            elif blk[-1, 0] - seg[SEG_FIRST] > p.max_segment + p.post:
                # gated for too long: not a reversal (drop it, start afresh)
                new.counts[COUNT_DISCARDED] += 1
                seg[SEG_OPEN], seg[SEG_FIRST], seg[SEG_LAST] = 0.0, math.nan, math.nan
        th, lo, hi, ex = self._evaluate(state if k_close > 0 else new, blk[:k_close, 0])
        if k_close < n:
            th2, lo2, hi2, ex2 = self._evaluate(new, blk[k_close:, 0])
            th, lo, hi = np.vstack([th, th2]), np.vstack([lo, lo2]), np.vstack([hi, hi2])
            ex = np.vstack([ex, ex2])
        return new, SegmentRecord(
            theta=th,
            lower=lo,
            upper=hi,
            excited=ex,
            segments=int(new.counts[COUNT_USED]),
            discarded=int(new.counts[COUNT_DISCARDED]),
            restarts=int(new.counts[COUNT_RESTARTS]),
            last_segment=new.last.copy(),
        )

    # ------------------------------------------------------------------ segment fit
    def fit_segment(self, seg: F64) -> tuple[F64, F64, bool]:
        """Batch LS of one segment (rows t, y, acc, vel, sgn).

        Returns the scaled estimate (J_L, B_L, F_CL), its covariance (3 x 3, corrected
        for the residual's autocorrelation and for the t quantile) and whether the
        segment holds a velocity reversal (without one, B_L and F_CL are not determined).
        """
        p = self.params
        tt, y = seg[:, 0], seg[:, 1]
        n = len(y)
        tau = tt - tt.mean()
        A = np.column_stack(
            [
                seg[:, 2] * self._scale[0],
                seg[:, 3] * self._scale[1],
                seg[:, 4] * self._scale[2],
                np.ones(n),
                tau,
            ]
        )
        # column equilibration keeps the normal matrix well conditioned
        cn = np.sqrt(np.sum(A * A, axis=0))
        cn[cn == 0.0] = 1.0
        As = A / cn
        G = As.T @ As
        try:
            Gi = np.linalg.inv(G)
        except np.linalg.LinAlgError:
            return np.full(3, math.nan), np.full((3, 3), math.inf), False
        beta = Gi @ (As.T @ y)
        e = y - As @ beta
        k = A.shape[1]
        s2 = float(e @ e) / max(n - k, 1)
        n_eff = _effective_samples(e)
        dof = max(n_eff - k, 1.0)
        infl = (float(stats.t.ppf(0.5 + 0.5 * p.level, dof)) / p.z) ** 2
        cov = s2 * Gi * (n / n_eff) * infl
        cov = cov / np.outer(cn, cn)
        theta = beta / cn
        reversal = bool(np.ptp(seg[:, 4]) > 1.0)
        return theta[:3], cov[:3, :3], reversal

    def _close(self, st: SegmentState, t0: float, t1: float) -> None:
        p = self.params
        h = st.hist
        m = (h[:, 0] >= t0) & (h[:, 0] <= t1)
        if st.seg[SEG_DISTURBANCE] >= t0 - 1e-12 and st.seg[SEG_DISTURBANCE] <= t1 + 1e-12:
            st.counts[COUNT_DISCARDED] += 1  # a known change of the cutting condition inside
            return
        if m.sum() < 20:
            st.counts[COUNT_DISCARDED] += 1
            return
        th, cov, reversal = self.fit_segment(h[m])
        if not np.all(np.isfinite(th)):
            st.counts[COUNT_DISCARDED] += 1
            return
        st.last[:] = th * self._scale
        tc = float(t1)
        st.counts[COUNT_USED] += 1
        var = np.diag(cov)
        for i in range(3):
            if i > 0 and not reversal:
                continue
            # a segment that does not determine the parameter to its prior's width
            # carries no information worth a Kalman update
            if not (var[i] < p.prior_rel**2):
                continue
            r = float(var[i]) + (p.model_error[i] * float(th[i])) ** 2
            self._kf_update(st, i, tc, float(th[i]), r)
        _kf_blocks(st.P)

    def _kf_update(self, st: SegmentState, i: int, tc: float, z: float, r: float) -> None:
        p = self.params
        if math.isnan(st.t_upd[i]):
            self._kf_reset(st, i, tc, z, r)
            return
        dt = max(tc - float(st.t_upd[i]), 0.0)
        if i == 0:
            F = np.array([[1.0, dt], [0.0, 1.0]])
            q = p.slope_noise_J**2
            Q = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
            x = F @ st.x[0:2]
            P = F @ st.P[0:2, 0:2] @ F.T + Q
            S = P[0, 0] + r
            nu = z - x[0]
            if nu * nu > p.gate**2 * S:
                st.counts[COUNT_RESTARTS] += 1
                self._kf_reset(st, i, tc, z, r)
                return
            K = P[:, 0] / S
            st.x[0:2] = x + K * nu
            st.P[0:2, 0:2] = P - np.outer(K, P[0, :])
        else:
            j = i + 1
            Pp = st.P[j, j] + p.walk[i - 1] ** 2 * dt
            S = Pp + r
            nu = z - st.x[j]
            if nu * nu > p.gate**2 * S:
                st.counts[COUNT_RESTARTS] += 1
                self._kf_reset(st, i, tc, z, r)
                return
            K = Pp / S
            st.x[j] += K * nu
            st.P[j, j] = (1.0 - K) * Pp
        st.t_upd[i] = tc

    def _kf_reset(self, st: SegmentState, i: int, tc: float, z: float, r: float) -> None:
        if i == 0:
            st.x[0:2] = (z, 0.0)
            # the slope is unknown after a restart (learnt from the next segments)
            st.P[0:2, 0:2] = np.diag([r, self.params.slope_prior**2])
        else:
            st.x[i + 1] = z
            st.P[i + 1, i + 1] = r
        st.t_upd[i] = tc

    # ------------------------------------------------------------------ output
    def _evaluate(self, st: SegmentState, t: F64) -> tuple[F64, F64, F64, NDArray[np.bool_]]:
        n = len(t)
        th, lo, hi = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
        ex = np.empty((n, 3), dtype=np.bool_)
        _evaluate_kernel(
            np.ascontiguousarray(t), st.x, st.P, st.t_upd, self._design, self._scale, th, lo, hi, ex
        )
        return th, lo, hi, ex


@njit(cache=True)
def _evaluate_kernel(t, x, P, t_upd, d, scale, o_th, o_lo, o_hi, o_ex):  # pragma: no cover
    """Per sample: the Kalman prediction at ``t``, its 95 % interval and the excited flag
    (module docstring, 4.-5.). Before a parameter's first segment: the prior."""
    z = d[D_Z]
    for k in range(len(t)):
        for i in range(3):
            if np.isnan(t_upd[i]):
                th = 1.0
                v = d[D_PRIOR] * d[D_PRIOR]
                exc = False
            else:
                dt = max(t[k] - t_upd[i], 0.0)
                if i == 0:
                    th = x[0] + x[1] * dt
                    v = P[0, 0] + 2.0 * dt * P[0, 1] + dt * dt * P[1, 1] + d[D_SLOPE] * dt**3 / 3.0
                else:
                    th = x[i + 1]
                    v = P[i + 1, i + 1] + d[D_SLOPE + i] * dt
                # the model error does not average out over segments: added at the output
                v += (d[D_MODEL_ERROR + i] * th) ** 2
                exc = True
            half = z * math.sqrt(max(v, 0.0))
            o_ex[k, i] = exc and half <= d[D_EXCITED + i] * abs(th)
            o_th[k, i] = th * scale[i]
            o_lo[k, i] = max(th - half, 0.0) * scale[i]
            o_hi[k, i] = (th + half) * scale[i]


def _effective_samples(e: F64) -> float:
    """n / (1 + 2 sum of the autocorrelation up to its first non-positive lag)."""
    n = len(e)
    ec = e - e.mean()
    var = float(ec @ ec)
    if n < 4 or var <= 0.0:
        return float(max(n, 1))
    m = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(ec, m)
    ac = np.fft.irfft(f * np.conj(f), m)[:n] / var
    neg = np.nonzero(ac[1:] <= 0.0)[0]
    last = int(neg[0]) if len(neg) else n - 1
    tau = 1.0 + 2.0 * float(np.sum(ac[1 : last + 1]))
    return float(min(max(n / max(tau, 1.0), 1.0), n))


def mark_disturbance(state: SegmentState, t: float) -> SegmentState:
    """A known change of the cutting condition at ``t`` (spindle step, tool change): the
    segment around it is discarded (its DC step would read as friction)."""
    seg = state.seg.copy()
    seg[SEG_DISTURBANCE] = float(t)
    return SegmentState(
        state.zf, state.hist, seg, state.x, state.P, state.t_upd, state.counts, state.last
    )


def restart(state: SegmentState, which: tuple[bool, bool, bool]) -> SegmentState:
    """A known change of the named parameters (e.g. a fresh workpiece: J_L): they restart
    from the prior, flagged not excited, until the next segment."""
    t_upd = state.t_upd.copy()
    x = state.x.copy()
    P = state.P.copy()
    for i, w in enumerate(which):
        if w:
            t_upd[i] = math.nan
            j = 0 if i == 0 else i + 1
            x[j] = 1.0
            if i == 0:
                x[1] = 0.0
    return SegmentState(state.zf, state.hist, state.seg, x, P, t_upd, state.counts, state.last)


__all__ = [
    "NAMES",
    "SegmentIdentifier",
    "SegmentIdentifierParams",
    "SegmentRecord",
    "SegmentState",
    "mark_disturbance",
    "restart",
]
