r"""Sensorless tool-life monitor: flank wear and remaining life from per-pass forces.

Beyond seed 004: the force the monitor is fed is whatever the caller has — a
dynamometer, or the cutting force estimated from the drive signals — averaged over each
tool pass. Per pass ``j`` (cutting time ``t_j`` on the wear clock [min], mean force
``F_j`` [N], feed ``f_j`` [mm/rev]):

1. Static gain, seed004 (25): ``D = F_1 / f_1`` on the first pass (sharp tool);
   on a feed change, re-estimated from the change of force over the change of feed
   (section 4.3.1), with an offset that keeps the wear force continuous.
2. Wear force, seed004 (24): ``dy_j = F_j - D f_j``.
3. Flank wear ``VB_j = dy_j / s`` with ``s = dF/dVB`` [N/mm], the sensitivity of the
   force to the flank land known off line (seed004 (8): ``K13 d``). Choice: the paper's
   back-transformation ``x = T x0`` (seed004 (14)) is too ill-conditioned to use here (see
   docs/reproductions/seed004-tool-wear.md); the wear force itself is the well-observed
   quantity. The
   crater lowers the force (``-K14 w_c``), so VB is underestimated by
   ``K14 w_c / (K13 d)``.
4. Trend: with ``law`` given (default of the live machine and the reproduction), the
   reduced wear law of :mod:`estimators.wear.law` — the form of seed004 (3)-(8)
   with its two scale factors fitted to the passes after the break-in
   (``t >= trend_start``); the crater's force loss of step 3 then follows the crater
   law driven by the measured force instead of a constant rate. Without ``law``:
   exponentially weighted least squares of a straight line or a parabola in time,
   forgetting ``trend_forgetting`` per pass (also the fallback at a feed other than
   the law's).
5. Remaining life until ``VB = vb_limit`` (ISO 3685: 0.3 mm): the law integrated forward
   with an S.D. from the fit's covariance and the off-line constants' uncertainty (see
   :mod:`estimators.wear.law`); or the polynomial trend extrapolated, with an S.D. from
   its covariance (delta method).
6. Flags: with the predicted tool life ``L = t + RUL`` (the learned reference),
   warning when ``t >= warning_fraction L`` and alarm when ``t >= alarm_fraction L``;
   the alarm is also raised once the trend reaches the limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from common.arrays import F64
from estimators.errors import ParameterError, require_in, require_positive
from estimators.wear.law import WearLawParams, WearLawPredictor

#: passes of history kept for the wear-law fit (the oldest are dropped beyond it)
MAX_HISTORY = 4000


@dataclass(frozen=True)
class ToolLifeParams:
    """Parameters of :class:`ToolLifeMonitor`.

    Parameters
    ----------
    force_per_flank_wear : float
        ``s = dF/dVB`` [N/mm] at the cutting condition (off-line knowledge).
    vb_limit : float
        Tool-life criterion [mm]; ISO 3685: 0.3 mm.
    warning_fraction, alarm_fraction : float
        Fractions of the predicted tool life at which to warn and to alarm,
        ``0 < warning_fraction < alarm_fraction <= 1``.
    trend_start : float
        Cutting time [min] after which passes enter the trend (skips the break-in).
    trend_forgetting : float
        Per-pass forgetting of the trend fit, in (0, 1].
    min_trend_passes : int
        Passes in the trend before a remaining life is predicted.
    feed_tolerance : float
        Relative feed change treated as a feed change.
    trend_order : int
        1: straight-line trend (default); 2: quadratic. Choice: after the break-in the
        flank wear first decelerates (abrasive tail) and then accelerates (diffusion,
        seed004 (4), (6)); a parabola fitted across the inflection often never reaches the
        limit, the straight line is biased (late) but usable.
    crater_force_rate : float
        Force lost to crater wear per minute of cutting [N/min], from the design model
        (``K14`` times its crater-wear rate), added back to the wear force. Choice: the
        crater enters the force through the same output as the flank land, so it cannot
        be separated from the force alone; 0 ignores it. Not used when ``law`` is given
        (the crater law replaces it).
    extrapolate_sharp_force : bool
        seed004 (25) needs the force of the sharp tool, but a pass mean already contains the
        break-in wear of that pass. True: the sharp-tool force is extrapolated back to
        t = 0 from the first two pass means (linear in the pass mid-times); False:
        the first pass mean is used as is.
    law : WearLawParams or None
        Off-line constants of the reduced wear law (:mod:`estimators.wear.law`) for the
        remaining-life prediction; None: the polynomial trend.
    life_sd : bool
        Compute ``remaining_life_sd`` (True, default). With the wear law it costs four
        more fits and up to six more integrations per pass (about 4/5 of the monitor's
        time); False leaves it NaN and every other output exactly as with True (for a
        caller that does not read it, e.g. the live pipeline).
    """

    force_per_flank_wear: float
    vb_limit: float = 0.3
    warning_fraction: float = 0.8
    alarm_fraction: float = 0.95
    trend_start: float = 2.0
    trend_forgetting: float = 0.98
    min_trend_passes: int = 5
    feed_tolerance: float = 1e-6
    crater_force_rate: float = 0.0
    extrapolate_sharp_force: bool = True
    trend_order: int = 1
    law: WearLawParams | None = None
    life_sd: bool = True

    def __post_init__(self) -> None:
        require_positive("force_per_flank_wear", self.force_per_flank_wear)
        require_positive("vb_limit", self.vb_limit)
        require_in("alarm_fraction", self.alarm_fraction, 0.0, 1.0, lo_open=True)
        require_in(
            "warning_fraction",
            self.warning_fraction,
            0.0,
            self.alarm_fraction,
            lo_open=True,
            hi_open=True,
        )
        if not math.isfinite(self.trend_start) or self.trend_start < 0:
            raise ParameterError("trend_start", "a finite time >= 0 min", self.trend_start)
        require_in("trend_forgetting", self.trend_forgetting, 0.0, 1.0, lo_open=True)
        if int(self.min_trend_passes) != self.min_trend_passes or self.min_trend_passes < 3:
            raise ParameterError("min_trend_passes", "an integer >= 3", self.min_trend_passes)
        require_positive("feed_tolerance", self.feed_tolerance)
        if self.trend_order not in (1, 2):
            raise ParameterError("trend_order", "1 or 2", self.trend_order)
        if not math.isfinite(self.crater_force_rate) or self.crater_force_rate < 0:
            raise ParameterError(
                "crater_force_rate", "a finite value >= 0 N/min", self.crater_force_rate
            )


# Index of each entry of ToolLifeState.misc: the static gain D and the offset of seed004
# (24)-(25), the previous pass's feed f and mean force F, the passes so far, the previous
# pass's end time and the first pass's
MISC_D, MISC_OFFSET, MISC_FEED, MISC_FORCE, MISC_PASSES, MISC_T, MISC_T_FIRST = range(7)


@dataclass(frozen=True, eq=False)
class ToolLifeState:
    """Explicit state: static gain, offset, last pass, and the trend's weighted sums."""

    misc: F64  # [D, offset, f_prev, F_prev, passes, t_prev, t_first]: the MISC_* indices
    sums: F64  # weighted sums of t^0..t^4, t^0..t^2 VB, VB^2; pass count
    # wear law: [z (low-passed F/(f d)), force lost to the crater C [N]]
    law: F64 = field(default_factory=lambda: np.zeros(2))
    # wear law: one row per pass [t_mid, VB, pass mean of z, C at mid-pass]
    hist: F64 = field(default_factory=lambda: np.zeros((0, 4)))


@dataclass(frozen=True, eq=False)
class ToolLifeRecord:
    """Per-pass outputs."""

    t: F64  # cutting time at the end of each pass [min]
    wear_force: F64  # dy, seed004 (24) [N]
    static_gain: F64  # D [N/(mm/rev)]
    vb: F64  # flank wear of the pass [mm]
    vb_trend: F64  # trend value at t [mm] (NaN before the trend exists)
    wear_rate: F64  # trend slope [mm/min]
    remaining_life: F64  # [min] (inf if the wear does not grow, NaN if unknown)
    remaining_life_sd: F64  # [min]
    life_fraction: F64  # t / (t + remaining_life)
    warning: NDArray[np.bool_]
    alarm: NDArray[np.bool_]


def _crossing(c: F64, level: float, after: float) -> float:
    """First time >= ``after`` at which the polynomial ``sum c_i t^i`` reaches ``level``."""
    roots = np.roots(np.concatenate([c[::-1][:-1], [c[0] - level]]))
    real = roots[np.abs(roots.imag) < 1e-9].real
    real = real[real >= after]
    if len(real) == 0:
        return math.nan if float(np.polyval(c[::-1], after)) < level else after
    return float(real.min())


class ToolLifeMonitor:
    """Flank wear, remaining life and warning/alarm flags, one step per block of passes."""

    def __init__(self, params: ToolLifeParams) -> None:
        self.params = params
        self._law = WearLawPredictor(params.law) if params.law is not None else None

    def _life(
        self,
        S: F64,
        m: int,
        tj: float,
        law_ok: bool,
        hist_rows: list[F64],
        law: F64,
        force_sharp: float,
    ) -> tuple[float, float, float, float] | None:
        """Trend, rate, remaining life and its sd at ``tj``: the wear law's (on the
        history, ``hist_rows`` joined in place) when it applies, else the polynomial's;
        None while the polynomial's normal equations are singular (they gate both)."""
        p = self.params
        if not (law_ok and self._law is not None):
            return _polynomial_life(S, m, tj - p.trend_start, p.vb_limit)
        # the polynomial's values would be replaced: only its gate is computed
        if not _regular(S, m):
            return None
        H = np.concatenate(hist_rows)[-MAX_HISTORY:]
        hist_rows[:] = [H]
        return self._law.predict(
            H[:, 0],
            H[:, 1],
            H[:, 2],
            H[:, 3],
            t_now=tj,
            z_now=law[0],
            crater_now=law[1],
            force_sharp=force_sharp,
            force_per_flank_wear=p.force_per_flank_wear,
            vb_limit=p.vb_limit,
            with_sd=p.life_sd,
        )

    def initial_state(self) -> ToolLifeState:
        return ToolLifeState(misc=np.zeros(7), sums=np.zeros(10))

    def step(
        self, state: ToolLifeState, t: ArrayLike, force: ArrayLike, feed: ArrayLike
    ) -> tuple[ToolLifeState, ToolLifeRecord]:
        """Process passes ending at cutting times ``t`` [min], increasing.

        Parameters
        ----------
        state : ToolLifeState
        t : array_like
            Cutting time on the wear clock at the end of each pass [min].
        force : array_like
            Mean cutting force of each pass [N] (any source).
        feed : array_like
            Feed of each pass [mm/rev], > 0.
        """
        ta, Fa, fa = _passes(state, t, force, feed)
        p = self.params
        misc = state.misc.copy()
        S = state.sums.copy()
        law = state.law.copy()
        hist_rows: list[F64] = [state.hist]
        n_hist = len(state.hist)
        n = len(ta)
        out = {k: np.empty(n) for k in ("dy", "D", "vb", "trend", "rate", "rul", "sd", "frac")}
        warn = np.zeros(n, dtype=bool)
        alarm = np.zeros(n, dtype=bool)
        lam = float(p.trend_forgetting)
        for j in range(n):
            tj, Fj, fj = float(ta[j]), float(Fa[j]), float(fa[j])
            feed_changed = (
                misc[MISC_PASSES] > 0.5
                and abs(fj - misc[MISC_FEED]) > p.feed_tolerance * misc[MISC_FEED]
            )
            if misc[MISC_PASSES] < 0.5:
                # seed004 (25): the first pass is cut with a sharp tool
                misc[MISC_D] = Fj / fj
                misc[MISC_OFFSET] = 0.0
                misc[MISC_T_FIRST] = tj
            elif misc[MISC_PASSES] < 1.5 and p.extrapolate_sharp_force and not feed_changed:
                # seed004 (25) with y(0) extrapolated to t = 0 from the first two pass means
                m1 = 0.5 * misc[MISC_T_FIRST]
                m2 = 0.5 * (misc[MISC_T_FIRST] + tj)
                f0 = misc[MISC_FORCE] - (Fj - misc[MISC_FORCE]) * m1 / (m2 - m1)
                misc[MISC_D] = f0 / fj
            elif feed_changed:
                # section 4.3.1: D from the change of force over the change of feed
                d_new = (Fj - misc[MISC_FORCE]) / (fj - misc[MISC_FEED])
                misc[MISC_OFFSET] += (misc[MISC_D] - d_new) * misc[MISC_FEED]
                misc[MISC_D] = d_new
            # seed004 (24)
            dy = Fj - misc[MISC_D] * fj - misc[MISC_OFFSET]
            lp = p.law
            # the law's constants hold for one feed: passes at another feed use the
            # polynomial trend and the constant crater rate (and do not enter the law)
            law_ok = lp is not None and abs(fj - lp.feed) <= p.feed_tolerance * lp.feed
            if law_ok and lp is not None and self._law is not None:
                # the wear law's inputs over this pass (force held over the pass):
                # seed004 (3)'s low-pass of F/(f d) and seed004 (5)'s crater force loss
                dt = tj - (misc[MISC_T] if misc[MISC_PASSES] > 0.5 else 0.0)
                e = math.exp(-dt / lp.tau_abrasive)
                u = Fj / (fj * lp.depth)
                zbar = u + (law[0] - u) * lp.tau_abrasive / dt * (1.0 - e)
                law[0] = u + (law[0] - u) * e
                c_rate = float(self._law.crater_rate(Fj))
                c_mid = law[1] + 0.5 * dt * c_rate
                law[1] += dt * c_rate
                vb = (dy + c_mid) / p.force_per_flank_wear
                if tj >= p.trend_start:
                    hist_rows.append(np.array([[tj - 0.5 * dt, vb, zbar, c_mid]]))
                    n_hist += 1
            else:
                vb = (dy + p.crater_force_rate * tj) / p.force_per_flank_wear
            if tj >= p.trend_start:
                # weighted normal equations of VB = sum_i c_i (t - t_trend)^i
                tau = tj - p.trend_start
                S *= lam
                powers = tau ** np.arange(5)
                S[0:5] += powers
                S[5:8] += powers[:3] * vb
                S[8] += vb * vb
                S[9] += 1.0
            trend = rate = rul = sd = frac = math.nan
            m = int(p.trend_order) + 1
            if S[9] >= p.min_trend_passes:
                fit = self._life(
                    S, m, tj, law_ok, hist_rows, law, misc[MISC_D] * fj + misc[MISC_OFFSET]
                )
                if fit is not None:
                    trend, rate, rul, sd = fit
                    if not p.life_sd:
                        sd = math.nan
                    frac = tj / (tj + rul) if math.isfinite(rul) else 0.0
                    warn[j] = frac >= p.warning_fraction
                    alarm[j] = frac >= p.alarm_fraction or trend >= p.vb_limit
            out["dy"][j], out["D"][j], out["vb"][j] = dy, misc[MISC_D], vb
            out["trend"][j], out["rate"][j], out["rul"][j] = trend, rate, rul
            out["sd"][j], out["frac"][j] = sd, frac
            misc[MISC_FEED], misc[MISC_FORCE], misc[MISC_T] = fj, Fj, tj
            misc[MISC_PASSES] += 1.0
        rec = ToolLifeRecord(
            ta.copy(), out["dy"], out["D"], out["vb"], out["trend"], out["rate"], out["rul"],
            out["sd"], out["frac"], warn, alarm,
        )  # fmt: skip
        hist = np.concatenate(hist_rows)[-MAX_HISTORY:] if n_hist else state.hist
        return ToolLifeState(misc=misc, sums=S, law=law, hist=hist), rec


__all__ = ["ToolLifeMonitor", "ToolLifeParams", "ToolLifeRecord", "ToolLifeState"]


def _passes(
    state: ToolLifeState, t: ArrayLike, force: ArrayLike, feed: ArrayLike
) -> tuple[F64, F64, F64]:
    """The passes' times, forces and feeds as arrays, checked (ParameterError naming the
    input)."""
    ta = np.atleast_1d(np.asarray(t, dtype=np.float64))
    Fa = np.atleast_1d(np.asarray(force, dtype=np.float64))
    fa = np.atleast_1d(np.asarray(feed, dtype=np.float64))
    if ta.ndim != 1 or Fa.shape != ta.shape or fa.shape != ta.shape:
        raise ParameterError(
            "force/feed", f"1-D arrays shaped like t {ta.shape}", (Fa.shape, fa.shape)
        )
    if not (np.all(np.isfinite(ta)) and np.all(np.isfinite(Fa))):
        raise ParameterError("t/force", "finite values", "NaN or inf")
    if not np.all(np.isfinite(fa)) or np.any(fa <= 0):
        bad = fa[~(np.isfinite(fa) & (fa > 0))][0]
        raise ParameterError("feed", "a feed > 0 mm/rev for every pass", float(bad))
    prev_t = state.misc[MISC_T] if state.misc[MISC_PASSES] > 0.5 else 0.0
    if np.any(np.diff(np.concatenate([[prev_t], ta])) <= 0):
        raise ParameterError("t", "strictly increasing cutting times", ta.tolist()[:5])
    return ta, Fa, fa


def _normal_matrix(S: F64, m: int) -> F64:
    """The trend polynomial's normal-equation matrix from the weighted sums ``S``."""
    return np.array([[S[i + k] for k in range(m)] for i in range(m)])


def _regular(S: F64, m: int) -> bool:
    """Whether :func:`_polynomial_life` would give a fit (its normal equations regular)."""
    return bool(np.linalg.cond(_normal_matrix(S, m)) < 1e12)


def _polynomial_life(
    S: F64, m: int, tau: float, vb_limit: float
) -> tuple[float, float, float, float] | None:
    """Trend, wear rate, remaining life and its sd from the weighted sums ``S`` of the
    polynomial of ``m`` coefficients at ``tau`` after the trend start (None: the normal
    equations are singular)."""
    M = _normal_matrix(S, m)
    r = S[5 : 5 + m]
    if not np.linalg.cond(M) < 1e12:
        return None
    Minv = np.linalg.inv(M)
    c = Minv @ r
    sse = S[8] - float(c @ r)
    # choice: the weighted count S0 as the sample size (conservative for forgetting < 1:
    # the effective count is larger)
    s2 = max(sse, 0.0) / max(S[0] - m, 1.0)
    C = s2 * Minv
    trend = float(np.polyval(c[::-1], tau))
    dc = c[1:] * np.arange(1, m)
    rate = float(np.polyval(dc[::-1], tau))
    t_star = _crossing(c, vb_limit, tau)
    if not math.isfinite(t_star):
        return trend, rate, math.inf, math.inf
    # delta method: g(c, t*) = sum c_i t*^i - VB_lim = 0
    slope = float(np.polyval(dc[::-1], t_star))
    grad = -(t_star ** np.arange(m)) / slope
    return trend, rate, max(t_star - tau, 0.0), math.sqrt(max(float(grad @ C @ grad), 0.0))
