r"""Flank wear of a turning tool from a drive or force signal, one value per segment.

Seed 004 (Danai & Ulsoy, *An adaptive observer for on-line tool wear estimation in
turning, Part I*) adapted to what a table of one-second cutting segments has. What is
**taken from the paper** and what is **changed, and why**:

* Wear state that only grows, driven by a wear-rate law (seed004 eq. (3)-(8): abrasive
  break-in plus an accelerating, temperature-driven diffusive part). *Changed*: the table
  has no cutting time, no depth of cut and no temperature, so the state is the flank wear
  VB [um] and its rate rho [um per segment] on the **segment index** (one step = one
  segment; the time between segments is not given, so every rate and life here is "per
  segment", never per minute). The filter's state model is VB(k+1) = VB(k) + rho(k),
  rho(k+1) = rho(k) + w(k), w a random walk whose S.D. is the training tools' change of
  rate per segment; rho is projected to >= 0 after every update, so the modelled wear
  never falls (the estimate of it may be revised down by a measurement: clipping the
  estimate at its previous value ratchets it up on a noisy drive signal, drive-torque
  MAE 203 um against 76 without the clip, feed force 21.0 / 20.7). The remaining life
  keeps the paper's accelerating shape in the one form the table can calibrate: the rate
  grows with the wear, d(ln rho)/d(VB) = 1/lambda (the diffusive part of eq. (4)/(6)
  grows with the wear-land temperature, which grows with VB), lambda fitted on the
  training tools' rates above VB = 100 um (past the abrasive break-in, whose rate falls).
  In the filter's state model this acceleration ran away where the signal carries little
  (drive torque: MAE 205 um), so it is used for the life only.
* Output relation: the force is a static part set by the cutting conditions plus a
  wear part (seed004 eq. (22)-(24): ``y = D u + wear force``, static output removed).
  *Changed*: the wear part is ``a1 (VB - VB_r) + a2 (VB^2 - VB_r^2)`` (the paper's
  ``K13 d w_f`` is linear; on the real tools the force rises faster than linearly with
  VB, a1 and a2 are both projected to >= 0, a force that falls with wear is not
  physical here). The static part is the **fresh-tool reference** ``y_r`` (median of the
  tool's first ``n_ref`` segments, at the tool's mean initial wear ``VB_r`` of the
  training tools) plus ``D (F/F_r - 1)`` with ``F`` the programmed feed rate
  ``CON.G.FREAL`` (undocumented CNC units: only its ratio to the tool's first segments is
  used; glitch values are replaced, see :func:`clean_condition`). The feed per
  revolution (FREAL / SREAL) is the same on every tool (2.78e-4 in CNC units, 1-99 %
  spread < 3 %), so the feed rate is proportional to the spindle speed: it carries the
  speed (cutting-force and Z-drive friction change) and is the one condition input.
* Adaptive parameter estimation: the parameters ``(D, a1, a2)`` are estimated with the
  paper's recursive least squares with forgetting (eq. (20)-(21),
  :func:`estimators.ud_rls.covariance_update`) run over the training tools' segments,
  with the constraints a1, a2 >= 0 (Table 2's role). *Changed*: the paper projects after
  every update; here, while P is still large the first segments (almost no wear) drove
  the clipped estimate to 1e10, so a violated bound is made active and the recursion
  rerun without that term. *Changed*: the paper identifies an input-output model of the force on one
  tool without wear measurements; the scale of wear is not identifiable from the force
  alone (the paper defers it to off-line measurements, Part II), so here the RLS runs on
  the training tools, where VB is measured, with beta = 1 (the relation is the same for
  every tool; forgetting would weight the last tool read).
* Observer: the paper's deadbeat observer (eq. (17)-(19)) is replaced by an extended
  Kalman filter on (VB, rho): the deadbeat observer has no covariance, and the report
  needs 95 % intervals. The measurement variance is ``sigma_y^2 + (g * wear force)^2``
  (white noise, plus the tool-to-tool spread g of the force-wear gain measured on the
  training tools); the filter's standard deviation is scaled by a factor calibrated on
  the training tools (each training tool estimated by a model fitted on the others),
  so that 95 % of their segments fall inside. A segment whose innovation exceeds 5 S.D.
  is a reading glitch and skipped (the table's drive torque has isolated segments at
  -60 ... -100 against a level of ~85).
* Remaining life [segments] to a VB criterion: the law integrated from the current
  state, ``L = lambda/rho (1 - exp(-(C - VB)/lambda))``, its 95 % interval from the
  state's (calibrated) covariance by sampling.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from common.arrays import F64
from estimators.errors import ParameterError, require_in, require_positive
from estimators.ud_rls import covariance_update

if TYPE_CHECKING:
    from common.state_io import JsonNode

#: version of the JSON form of :class:`TurningWearModel`
MODEL_VERSION = 1
#: regressor scale: VB enters the RLS in units of 100 um (conditioning)
_VB_UNIT = 100.0
#: a life longer than this many segments is reported as never (inf)
_NO_END = 1e9
#: innovation gate [S.D.]: a segment further off is a reading glitch (the drive
#: torque holds single segments at -60 ... -100 against ~85), not wear; it is skipped
_GATE = 5.0
#: flank wear [um] past the abrasive break-in: the law's lambda is fitted above it
_BREAK_IN = 100.0


@dataclass(frozen=True)
class TurningWearParams:
    """Settings of the fit (not learned).

    Parameters
    ----------
    n_ref : int
        Segments at the start of each tool that give its fresh-tool reference. 10: the
        drive torque's segment-to-segment scatter (S.D. 3-4 CNC units) is as large as
        its whole wear part at VB = 150 um (3.2 units), so the reference must average
        several segments; with more, the wear during them differs between tools
        (leave-one-tool-out MAE of the drive torque 66 / 56 / 62 um with 5 / 10 / 20;
        the feed force 22.5 / 22.5 / 22.3 um).
    coverage : float
        Two-sided coverage of the intervals, in (0, 1).
    p0 : float
        Initial RLS covariance (scaled parameters).
    life_draws : int
        Samples of the state used for the remaining life's interval.
    seed : int
        Seed of those samples (the result is reproducible).
    """

    n_ref: int = 10
    coverage: float = 0.95
    p0: float = 1e4
    life_draws: int = 400
    seed: int = 4

    def __post_init__(self) -> None:
        if int(self.n_ref) != self.n_ref or self.n_ref < 1:
            raise ParameterError("n_ref", "an integer >= 1", self.n_ref)
        require_in("coverage", self.coverage, 0.0, 1.0, lo_open=True, hi_open=True)
        require_positive("p0", self.p0)
        if int(self.life_draws) != self.life_draws or self.life_draws < 10:
            raise ParameterError("life_draws", "an integer >= 10", self.life_draws)


@dataclass(frozen=True)
class ToolSeries:
    """One tool's segments in the order of its life.

    Attributes
    ----------
    tool : int
        Tool number.
    y : ndarray
        The signal's per-segment mean (e.g. ``F_f_MEAN``).
    feed : ndarray
        Programmed feed rate per segment (any unit; cleaned, > 0).
    vb : ndarray or None
        Measured flank wear [um] when known.
    """

    tool: int
    y: F64
    feed: F64
    vb: F64 | None = None

    def __post_init__(self) -> None:
        n = len(self.y)
        if len(self.feed) != n or (self.vb is not None and len(self.vb) != n):
            raise ParameterError(
                f"tool {self.tool}", "y, feed and vb of one length", (n, len(self.feed))
            )


@dataclass(frozen=True)
class TurningWearModel:
    """A fitted model: everything :func:`estimate` needs (JSON via :meth:`to_dict`).

    Attributes
    ----------
    signal : str
        The signal's name (informative).
    d, a1, a2 : float
        Output relation ``y - y_r = d (F/F_r - 1) + a1 (VB - VB_r) + a2 (VB^2 - VB_r^2)``
        (a1 in signal units per um, a2 per um^2).
    vb_ref : float
        Mean VB over the first ``n_ref`` segments of the training tools [um].
    vb_ref_sd : float
        Spread of that initial VB over the training tools [um] (the state's prior).
    sigma_y : float
        Residual standard deviation of the output relation (signal units).
    gain_spread : float
        Relative tool-to-tool spread of the wear part's gain.
    rate0, rate0_sd : float
        Initial wear rate and its spread over the training tools [um/segment].
    rate_walk : float
        Standard deviation of the rate's change per segment [um/segment].
    lam : float
        Wear-rate law scale [um]: the rate grows by e per lambda of wear.
    interval_scale : float
        Factor on the filter's standard deviation, calibrated on the training tools.
    n_ref : int
        Segments of the fresh-tool reference.
    train_tools : list of int
        Tools it was fitted on.
    """

    signal: str
    d: float
    a1: float
    a2: float
    vb_ref: float
    vb_ref_sd: float
    sigma_y: float
    gain_spread: float
    rate0: float
    rate0_sd: float
    rate_walk: float
    lam: float
    interval_scale: float
    n_ref: int
    train_tools: list[int] = field(default_factory=list)

    def to_dict(self) -> dict[str, JsonNode]:
        """JSON-ready form, with ``version``."""
        return {"version": MODEL_VERSION, "kind": "turning_wear", **asdict(self)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TurningWearModel:
        """Inverse of :meth:`to_dict` (ParameterError on a wrong version or field)."""
        if data.get("kind") != "turning_wear" or data.get("version") != MODEL_VERSION:
            raise ParameterError(
                "model",
                f"kind 'turning_wear', version {MODEL_VERSION}",
                f"kind {data.get('kind')!r}, version {data.get('version')!r}",
            )
        names = set(cls.__dataclass_fields__)
        missing = sorted(names - set(data))
        if missing:
            raise ParameterError("model", f"fields {', '.join(sorted(names))}", f"no {missing}")
        kw = {k: data[k] for k in names}
        return cls(**kw)


@dataclass(frozen=True)
class WearEstimate:
    """Per-segment estimates of one tool (rates and lives in segments)."""

    vb: F64
    vb_lo: F64
    vb_hi: F64
    rate: F64
    life_left: F64
    life_left_lo: F64
    life_left_hi: F64


def clean_condition(x: F64, *, window: int = 5, tolerance: float = 0.2) -> tuple[F64, int]:
    """Replace glitch values of a condition column by the median of their neighbourhood.

    A value is a glitch when it is not finite, <= 0, or further than ``tolerance``
    (relative) from the median of the ``window`` segments around it (the table's
    feed/speed columns hold isolated values 10-40x the tool's level, and a few zeros).

    Returns
    -------
    cleaned : ndarray
    n_replaced : int
    """
    v = np.asarray(x, dtype=np.float64).copy()
    n = len(v)
    ok = np.isfinite(v) & (v > 0)
    h = window // 2
    base = v.copy()
    base[~ok] = np.nan
    out = v.copy()
    bad = 0
    for i in range(n):
        nb = base[max(0, i - h) : i + h + 1]
        nb = nb[np.isfinite(nb)]
        med = float(np.median(nb)) if len(nb) else np.nan
        if not ok[i] or (np.isfinite(med) and abs(v[i] - med) > tolerance * med):
            out[i] = med
            bad += 1
    # a run of glitches longer than the window: hold the last good value
    for i in range(n):
        if not np.isfinite(out[i]) or out[i] <= 0:
            prev = out[:i][np.isfinite(out[:i]) & (out[:i] > 0)]
            out[i] = prev[-1] if len(prev) else float(np.nanmedian(base))
    return out, bad


def _reference(s: ToolSeries, n_ref: int) -> tuple[float, float]:
    k = min(n_ref, len(s.y))
    return float(np.median(s.y[:k])), float(np.median(s.feed[:k]))


def _regressors(s: ToolSeries, vb: F64, vb_ref: float, n_ref: int) -> tuple[F64, F64]:
    y_r, f_r = _reference(s, n_ref)
    u = s.feed / f_r - 1.0
    v = vb / _VB_UNIT
    v0 = vb_ref / _VB_UNIT
    phi = np.column_stack([u, v - v0, v * v - v0 * v0])
    return phi, s.y - y_r


def _fit_output(
    tools: list[ToolSeries], vb_ref: float, params: TurningWearParams
) -> tuple[F64, float, float]:
    """(d, a1, a2) by RLS with projection, residual S.D., relative gain spread."""
    data = []
    for s in tools:
        assert s.vb is not None
        data.append(_regressors(s, s.vb, vb_ref, params.n_ref))
    active = [0, 1, 2]
    theta = np.zeros(3)
    for _ in range(3):
        theta = np.zeros(3)
        th = np.zeros(len(active))
        P = np.eye(len(active)) * params.p0
        for phi, z in data:
            ph = np.ascontiguousarray(phi[:, active])
            for k in range(len(z)):
                # seed004 (20)-(21): RLS update, beta = 1 (the same relation on every tool)
                covariance_update(th, P, np.ascontiguousarray(ph[k]), float(z[k]), 1.0)
        theta[active] = th
        # Table 2 analogue: the force does not fall with wear (a1, a2 >= 0); a bound
        # that is violated is made active and the recursion rerun without that term
        neg = [i for i in (2, 1) if i in active and theta[i] < 0]
        if not neg:
            break
        active.remove(neg[0])
        theta[neg[0]] = 0.0
    res = []
    gains = []
    weights = []
    for s in tools:
        assert s.vb is not None
        phi, z = _regressors(s, s.vb, vb_ref, params.n_ref)
        pred = phi @ theta
        res.append(z - pred)
        wear = phi[:, 1:] @ theta[1:]
        zw = z - phi[:, 0] * theta[0]
        den = float(wear @ wear)
        if den > 0:
            gains.append(float(wear @ zw) / den)
            weights.append(den)
    r = np.concatenate(res)
    spread = 0.5
    if len(gains) > 1:
        # weighted by each tool's wear-force energy: a tool that barely wears has a gain
        # that is mostly noise, and says little about the tool-to-tool spread
        g = np.asarray(gains)
        w = np.asarray(weights) / np.sum(weights)
        mean = float(w @ g)
        spread = float(np.sqrt(w @ (g - mean) ** 2) / max(mean, 1e-9))
    return theta, float(np.std(r)), min(spread, 2.0)


def local_rates(vb: F64, span: int = 10) -> F64:
    """Wear rate per segment, a centred difference over ``span`` segments."""
    n = len(vb)
    idx = np.arange(n)
    lo = np.clip(idx - span // 2, 0, n - 1)
    hi = np.clip(idx + span // 2, 0, n - 1)
    return np.asarray((vb[hi] - vb[lo]) / np.maximum(hi - lo, 1), dtype=np.float64)


def fit_law(tools: list[ToolSeries]) -> tuple[float, float, float, float]:
    """rate0, its spread, rate walk S.D. and lambda from the training tools' VB."""
    r0 = []
    xs: list[F64] = []
    ys: list[F64] = []
    walks = []
    for s in tools:
        assert s.vb is not None
        r = local_rates(s.vb)
        r0.append(float(np.mean(r[: max(len(r) // 3, 1)])))
        walks.append(np.diff(r))
        m = (r > 0.05) & (s.vb >= _BREAK_IN)
        if m.sum() > 5:
            x = s.vb[m] - np.mean(s.vb[m])
            xs.append(x)
            ys.append(np.log(r[m]) - np.mean(np.log(r[m])))
    x = np.concatenate(xs) if xs else np.zeros(1)
    yy = np.concatenate(ys) if ys else np.zeros(1)
    slope = float(x @ yy / max(float(x @ x), 1e-9))
    # d ln(rate)/d VB = 1/lambda; a slope <= 0 means no acceleration seen: a long lambda
    lam = 1.0 / slope if slope > 1.0 / 1e4 else 1e4
    walk = float(np.std(np.concatenate(walks))) if walks else 0.1
    return float(np.mean(r0)), float(np.std(r0)) + 1e-3, max(walk, 1e-3), lam


def _fit_core(
    tools: list[ToolSeries], signal: str, params: TurningWearParams, scale: float
) -> TurningWearModel:
    starts = [float(np.mean(s.vb[: params.n_ref])) for s in tools if s.vb is not None]
    vb_ref = float(np.mean(starts))
    # a new tool's initial wear: the training tools' spread (two start worn, ~40 um)
    vb_ref_sd = max(float(np.std(starts)), 5.0)
    theta, sig, spread = _fit_output(tools, vb_ref, params)
    rate0, rate0_sd, walk, lam = fit_law(tools)
    return TurningWearModel(
        signal=signal,
        d=float(theta[0]),
        a1=float(theta[1]) / _VB_UNIT,
        a2=float(theta[2]) / _VB_UNIT**2,
        vb_ref=vb_ref,
        vb_ref_sd=vb_ref_sd,
        sigma_y=sig,
        gain_spread=spread,
        rate0=rate0,
        rate0_sd=rate0_sd,
        rate_walk=walk,
        lam=lam,
        interval_scale=scale,
        n_ref=params.n_ref,
        train_tools=[int(s.tool) for s in tools],
    )


def fit(
    tools: list[ToolSeries], signal: str = "", params: TurningWearParams | None = None
) -> TurningWearModel:
    """Fit the output relation, the wear-rate law and the interval scale on training tools.

    Parameters
    ----------
    tools : list of ToolSeries
        Training tools, each with ``vb``; at least two (the interval scale is calibrated by
        estimating each training tool with a model fitted on the others).
    signal : str
        Name stored in the model.
    params : TurningWearParams, optional

    Returns
    -------
    TurningWearModel
    """
    p = params or TurningWearParams()
    if len(tools) < 1:
        raise ParameterError("training tools", "at least 1", len(tools))
    for s in tools:
        if s.vb is None:
            raise ParameterError(f"tool {s.tool}", "measured VB for training", "none")
        if len(s.y) < p.n_ref + 2:
            raise ParameterError(f"tool {s.tool}", f">= {p.n_ref + 2} segments", len(s.y))
    scale = 1.0
    if len(tools) >= 2:
        zs = []
        for i, s in enumerate(tools):
            inner = _fit_core(tools[:i] + tools[i + 1 :], signal, p, 1.0)
            est = estimate(inner, s, p, life=False)
            sd = (est.vb_hi - est.vb) / _z(p.coverage)
            assert s.vb is not None
            zs.append(np.abs(s.vb - est.vb) / np.maximum(sd, 1e-9))
        scale = float(np.quantile(np.concatenate(zs), p.coverage)) / _z(p.coverage)
    return _fit_core(tools, signal, p, max(scale, 1e-3))


def _z(coverage: float) -> float:
    from statistics import NormalDist

    return float(NormalDist().inv_cdf(0.5 + coverage / 2.0))


def life_from(vb: F64, rate: F64, criterion: float, lam: float) -> F64:
    """Segments until VB reaches ``criterion`` under the law d(ln rate)/dVB = 1/lambda.

    ``L = lambda/rate (1 - exp(-(C - VB)/lambda))``; 0 at or above the criterion, inf
    with a zero rate.
    """
    gap = np.maximum(criterion - vb, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        life = lam / rate * (-np.expm1(-gap / lam))
    life = np.where(rate > 0, life, np.inf)
    return np.where(gap > 0, life, 0.0)


def estimate(
    model: TurningWearModel,
    series: ToolSeries,
    params: TurningWearParams | None = None,
    *,
    criterion: float = 300.0,
    life: bool = True,
) -> WearEstimate:
    """Run the observer over one tool's segments (causal: segment k uses segments <= k).

    Parameters
    ----------
    model : TurningWearModel
    series : ToolSeries
        The tool (``vb`` not used).
    params : TurningWearParams, optional
        Coverage and the life interval's sampling.
    criterion : float
        VB limit for the remaining life [um].
    life : bool
        Compute the remaining life (False: NaN, faster).

    Returns
    -------
    WearEstimate
    """
    p = params or TurningWearParams()
    n = len(series.y)
    y_r, f_r = _reference(series, model.n_ref)
    u = series.feed / f_r - 1.0
    z = series.y - y_r
    vr = model.vb_ref
    x = np.array([vr, model.rate0])
    P = np.diag([model.vb_ref_sd**2, model.rate0_sd**2])
    q = model.rate_walk**2
    out = np.empty((n, 2))
    cov = np.empty((n, 2, 2))
    for k in range(n):
        if k > 0:
            v, r = x
            # wear-rate law on the segment clock: VB(k+1) = VB + rho, rho(k+1) = rho + w
            x = np.array([v + r, r])
            A = np.array([[1.0, 1.0], [0.0, 1.0]])
            P = A @ P @ A.T + np.diag([0.0, q])
        v = max(x[0], 0.0)
        wear = model.a1 * (v - vr) + model.a2 * (v * v - vr * vr)
        # seed004 (24): output = static part (conditions) + wear part
        h = model.d * u[k] + wear
        H = np.array([model.a1 + 2.0 * model.a2 * v, 0.0])
        R = model.sigma_y**2 + (model.gain_spread * wear) ** 2
        S = float(H @ P @ H) + R
        innov = z[k] - h
        if innov * innov <= _GATE**2 * S:
            K = P @ H / S
            x = x + K * innov
            P = P - np.outer(K, H @ P)
            P = 0.5 * (P + P.T)
        # projection: the wear only grows, its rate is not negative
        x[1] = max(x[1], 0.0)
        x[0] = max(x[0], 0.0)
        out[k] = x
        cov[k] = P
    zc = _z(p.coverage) * model.interval_scale
    sd = np.sqrt(np.maximum(cov[:, 0, 0], 0.0))
    vb = out[:, 0]
    lo = np.maximum(vb - zc * sd, 0.0)
    hi = vb + zc * sd
    nan = np.full(n, np.nan)
    if not life:
        return WearEstimate(vb, lo, hi, out[:, 1], nan, nan.copy(), nan.copy())
    rng = np.random.default_rng(p.seed)
    L = life_from(vb, out[:, 1], criterion, model.lam)
    L_lo = np.empty(n)
    L_hi = np.empty(n)
    tail = (1.0 - p.coverage) / 2.0
    for k in range(n):
        C = cov[k] * model.interval_scale**2
        C = 0.5 * (C + C.T) + np.eye(2) * 1e-12
        w, V = np.linalg.eigh(C)
        draws = out[k] + (rng.standard_normal((p.life_draws, 2)) * np.sqrt(np.maximum(w, 0))) @ V.T
        lk = life_from(
            np.maximum(draws[:, 0], 0.0), np.maximum(draws[:, 1], 0.0), criterion, model.lam
        )
        qs = np.quantile(np.minimum(lk, _NO_END), [tail, 1.0 - tail])
        L_lo[k], L_hi[k] = (np.inf if x >= _NO_END else float(x) for x in qs)
    return WearEstimate(vb, lo, hi, out[:, 1], L, L_lo, L_hi)


__all__ = [
    "MODEL_VERSION",
    "ToolSeries",
    "TurningWearModel",
    "TurningWearParams",
    "WearEstimate",
    "clean_condition",
    "estimate",
    "fit",
    "fit_law",
    "life_from",
    "local_rates",
]
