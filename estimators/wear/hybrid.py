"""Flank wear of a turning tool never seen: a monotone wear state filtered through a map
learnt across tools (issue 35; seed 004's state structure).

State (per tool, per segment k; the data have no cutting time, so the wear rate is
indexed by the segment number, um per segment)::

    VB(k+1) = VB(k) + r(k),   r(k+1) = r(k) + w(k),   r >= 0 (projected)

the wear grows and never shrinks (seed 004 eq. 3-8 keep the same monotone structure; the
rate's law is a random walk here because the file cannot calibrate the diffusive part per
tool). The measurement is a *map* from the segment's signals to VB, ``z = h(x)``, learnt
across the training tools (linear, quadratic, isotonic in a linear index or gradient
boosting: which one is chosen inside a nested evaluation, see
``server/pipeline/wear_nested.py``); its residual variance on the training rows is the
filter's measurement variance. ``smoothing = None`` is the map alone (no filter).

A tool enters with what its record says (its VB when it came in, e.g. a tool put back
from the crib); a tool with no record starts from what the training tools say of a fresh
tool at these cutting conditions (their start VB, mean and spread, and the prior's rate)
- never from its own first segments taken as new.

The signals enter either as absolute levels with the feed rate as one more input
(``reference = "none"``) or as the difference to the fresh-tool level that the training
tools predict at the tool's feed rate (``reference = "conditions"``: a line in the feed
rate through the training tools' first segments cut fresh).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common.arrays import F64
from estimators.errors import ParameterError

REFERENCES = ("none", "conditions")
MAPS = ("linear", "quadratic", "isotonic", "gbr")
#: the signals' features the map reads: ``_MEAN`` only, or every complete feature
FEATURE_SETS = ("mean", "five")
#: smoothing candidates: the rate's random-walk variance per segment, x the map's
#: residual variance; None = the map alone
SMOOTHINGS: tuple[float | None, ...] = (None, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
#: fresh-tool level of the signals: the first this many segments of a tool ...
N_FRESH = 5
#: ... while its VB is at most this [um]
FRESH_VB = 30.0
#: feed-rate unit (the CNC's, undocumented) scaled to order 1
_FEED_UNIT = 1000.0
#: S.D. [um] of a VB read from a tool's record (a microscope measurement)
RECORD_SD = 5.0
#: floor [um] of the S.D. of a fresh tool's start VB
FRESH_SD_FLOOR = 10.0
#: floor [um/segment] of the S.D. of the prior's rate
RATE_SD_FLOOR = 0.1
#: feed rates within this relative distance are the same cutting conditions
SAME_CONDITIONS = 0.02
#: the prior wear rate's rule (protocol revision 4): revision 3's median at the same
#: conditions, or a Taylor-type law in the cutting conditions (:func:`taylor_fit`)
RATE_LAWS = ("median", "taylor")
#: physical range of the law's exponent b (rate per segment ~ v_f^b): Taylor's n for
#: carbide 0.2-0.6 (handbook, uncoated to coated), b = 1/n (segments at a fixed cutting
#: time step) down to 1/n - 1 (one segment per pass of a fixed length): [0.67, 5]
TAYLOR_B = (0.67, 5.0)
#: revision 5: the law per segment inside the filter (``rate_law = "segment"``); its
#: exponent b from the knot intervals within the training tools, on this grid (0: no
#: speed effect; the rest: the physical range)
SEGMENT_B = (0.0, 0.67, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0)
#: a knot interval whose VB rises by at most this [um] is left out of b's fit (VB not
#: measured inside a flat stretch)
SEGMENT_MIN_DVB = 1.0
#: a knot: the slope of VB changes by more than this (relative)
KNOT_TOL = 0.01


@dataclass(frozen=True)
class HybridConfig:
    """One candidate configuration (the choices the nested evaluation makes)."""

    reference: str = "conditions"
    map: str = "linear"
    smoothing: float | None = 1e-2
    offset: bool = False
    features: str = "mean"
    rate_law: str = "median"

    def __post_init__(self) -> None:
        if self.rate_law not in (*RATE_LAWS, "segment"):
            raise ParameterError("rate_law", f"one of {(*RATE_LAWS, 'segment')}", self.rate_law)
        if self.features not in FEATURE_SETS:
            raise ParameterError("features", f"one of {FEATURE_SETS}", self.features)
        if self.reference not in REFERENCES:
            raise ParameterError("reference", f"one of {REFERENCES}", self.reference)
        if self.map not in MAPS:
            raise ParameterError("map", f"one of {MAPS}", self.map)
        if self.smoothing is not None and not (self.smoothing > 0):
            raise ParameterError("smoothing", "None or > 0", self.smoothing)
        if self.offset and self.smoothing is None:
            raise ParameterError("offset", "False for the map alone (it has no state)", True)

    @property
    def label(self) -> str:
        s = "map-alone" if self.smoothing is None else f"q={self.smoothing:g}"
        off = "/offset" if self.offset else ""
        law = "" if self.rate_law == "median" else f"/rate={self.rate_law}"
        return f"{self.features}/{self.reference}/{self.map}/{s}{off}{law}"


#: revision 3's smoothings: the rate's random walk that a wear rate can have (docs)
SMOOTHINGS_REV3 = (1e-6, 1e-5, 1e-4)
#: revision 3's (map, features): monotone maps on the ``_MEAN`` s, boosting on every
#: feature
MAPS_REV3 = (("linear", "mean"), ("isotonic", "mean"), ("gbr", "five"))


def candidates(*, revision: int = 3) -> list[HybridConfig]:
    """Every configuration of the protocol. Revision 4 has revision 3's 36; it adds the
    choice of the prior rate's law, made per fold on the rates (:func:`choose_rate_law`),
    not a configuration. Revision 3 (the list shrunk by physics,
    docs/turning-wear.md): (linear or isotonic on the ``_MEAN`` s, gradient boosting on
    every feature) x 2 references x 3 smoothings (1e-6, 1e-5, 1e-4) x with and without
    the tool-offset state = 36 per signal set; every one filtered (no map alone).
    Revision 2: 2 feature sets x 2 references x 4 maps x (the map alone + 5 smoothings
    x with and without the tool-offset state) = 176. Revision 1 (the first list, run
    first): ``_MEAN`` only, no offset state, smoothings 1e-4 ... 1e-1: 40."""
    if revision >= 3:
        return [
            HybridConfig(r, m, q, off, fs)
            for m, fs in MAPS_REV3
            for r in REFERENCES
            for q in SMOOTHINGS_REV3
            for off in (False, True)
        ]
    out = []
    feats = FEATURE_SETS if revision >= 2 else ("mean",)
    for fs in feats:
        for r in REFERENCES:
            for m in MAPS:
                for s in SMOOTHINGS:
                    if revision < 2 and s == 1e-5:
                        continue
                    out.append(HybridConfig(r, m, s, False, fs))
                    if revision >= 2 and s is not None:
                        out.append(HybridConfig(r, m, s, True, fs))
    return out


@dataclass(frozen=True)
class ToolData:
    """One tool's segments in the order of its life.

    Attributes
    ----------
    tool : int
    x : ndarray, shape (n, m)
        The signals' per-segment means (columns in the model's signal order).
    feed : ndarray, shape (n,)
        Programmed feed rate (cleaned, > 0; CNC units).
    vb : ndarray or None
        Measured (interpolated) flank wear [um], when known.
    start_vb : float or None
        VB [um] when the tool came in, from its record; None = no record (a fresh tool
        is assumed, with the training tools' spread).
    start_segment : int
        Segments the tool had cut before the first row (from its record; 0 if new).
    """

    tool: int
    x: F64
    feed: F64
    vb: F64 | None = None
    start_vb: float | None = None
    start_segment: int = 0
    x_all: F64 | None = None

    def __post_init__(self) -> None:
        if self.x_all is not None and len(self.x_all) != len(self.feed):
            raise ParameterError("x_all", f"{len(self.feed)} rows", len(self.x_all))
        if self.x.ndim != 2 or len(self.x) != len(self.feed):
            raise ParameterError("x", f"shape (n={len(self.feed)}, m)", self.x.shape)
        if self.vb is not None and len(self.vb) != len(self.feed):
            raise ParameterError("vb", f"{len(self.feed)} values", len(self.vb))

    def tail(self, k: int, *, record: bool) -> ToolData:
        """The tool entered part-way, at its segment ``k``: with its record (VB at ``k``
        as measured at the change) or with none."""
        vb = None if self.vb is None else self.vb[k:]
        start = float(self.vb[k]) if (record and self.vb is not None) else None
        xa = None if self.x_all is None else self.x_all[k:]
        return ToolData(self.tool, self.x[k:], self.feed[k:], vb, start, k if record else 0, xa)


@dataclass
class HybridModel:
    """A fitted map, the fresh-tool prior and the filter settings."""

    config: HybridConfig
    ref: F64 | None  # (2, m): fresh level = ref[0] + ref[1] * feed / unit
    mu: F64  # feature centring
    sd: F64  # feature scaling
    coef: F64 | None  # linear / quadratic / isotonic index coefficients
    iso_x: F64 | None
    iso_y: F64 | None
    gbr: Any
    sigma2: float  # the map's residual variance on the training rows [um^2]
    v0: float  # a fresh tool's start VB [um]
    v0_sd: float
    rates: list[tuple[float, float]] = field(default_factory=list)  # (feed, rate) per tool
    rate_sd: float = 1.0
    #: the Taylor-type law of the prior rate: ln r = level + b ln(v_f / vref)
    taylor: tuple[float, float, float, float] = (0.0, TAYLOR_B[0], math.nan, 1.0)
    #: revision 5: the law per segment, s_k = (v_k / vref)^speed_b; the training tools'
    #: median rate at vref and its spread
    speed_b: float = 0.0
    #: revision 5: True when too few knot intervals were left for the fit (fewer than
    #: the training tools + 2) and ``speed_b`` is the fallback 0, not a fitted value
    speed_b_fallback: bool = False
    rate_ref: float = 1.0
    rate_ref_sd: float = 1.0
    sigma2_within: float = 1.0  # residual variance about each tool's mean residual
    sigma2_between: float = 0.0  # variance of the tools' mean residuals (the offset)

    # ------------------------------------------------------------------ map
    def inputs(self, tool: ToolData) -> F64:
        """The columns the map reads: the ``_MEAN`` s, or every complete feature."""
        if self.config.features == "five" and tool.x_all is not None:
            return tool.x_all
        return tool.x

    def features(self, x: F64, feed: F64) -> F64:
        f = (np.asarray(feed, dtype=np.float64) / _FEED_UNIT)[:, None]
        if self.ref is None:
            z = np.column_stack([x, f])
        else:
            z = x - (self.ref[0] + self.ref[1] * f)
        return (z - self.mu) / self.sd

    def _design(self, z: F64) -> F64:
        one = np.ones((len(z), 1))
        if self.config.map == "quadratic":
            return np.column_stack([one, z, z * z])
        return np.column_stack([one, z])

    def measure(self, x: F64, feed: F64) -> F64:
        """The map's VB [um] for each segment."""
        z = self.features(x, feed)
        m = self.config.map
        if m == "gbr":
            return np.asarray(self.gbr.predict(z), dtype=np.float64)
        assert self.coef is not None
        idx = self._design(z) @ self.coef
        if m == "isotonic":
            assert self.iso_x is not None and self.iso_y is not None
            return np.interp(idx, self.iso_x, self.iso_y)
        return np.asarray(idx, dtype=np.float64)

    # --------------------------------------------------------------- prior
    def prior_rate(self, feed: float) -> tuple[float, float]:
        """The prior wear rate [um/segment] at these conditions and its spread: the
        training tools' median rate at the same conditions (two or more sharing them,
        else over all; ``rate_law = "median"``) or the Taylor-type law fitted on them
        (``"taylor"``)."""
        if self.config.rate_law == "taylor":
            return taylor_rate(self.taylor, feed), self.rate_sd
        if self.config.rate_law == "segment":
            s = self.scale(np.array([feed]))[0]
            return self.rate_ref * s, self.rate_ref_sd * s
        return median_rate(self.rates, feed), self.rate_sd

    def scale(self, feed: F64) -> F64:
        """Revision 5: each segment's wear relative to one cut at vref, (v / vref)^b
        (1 for the other rules)."""
        f = np.asarray(feed, dtype=np.float64)
        if self.config.rate_law != "segment" or self.speed_b == 0.0:
            return np.ones(len(f))
        return np.asarray((f / self.taylor[3]) ** self.speed_b, dtype=np.float64)

    def start(self, tool: ToolData) -> tuple[float, float]:
        """Start VB and its S.D.: the record's, or a fresh tool's."""
        if tool.start_vb is not None:
            return tool.start_vb, RECORD_SD
        return self.v0, self.v0_sd

    # --------------------------------------------------------------- filter
    def run(self, tool: ToolData) -> tuple[F64, F64, F64]:
        """Filter one tool: VB estimate, its S.D. and the rate, per segment.

        State (VB, rate, offset): the map reads ``z = VB + offset + e``, the offset a
        constant of the tool (the training tools' spread of their mean residual; 0 when
        the configuration has none), ``e`` the within-tool residual."""
        z = self.measure(self.inputs(tool), tool.feed)
        n = len(z)
        q = self.config.smoothing
        if q is None:
            s = math.sqrt(self.sigma2)
            return z, np.full(n, s), np.full(n, np.nan)
        seg = self.config.rate_law == "segment"
        if seg:  # the state's rate is the rate at vref; a segment adds r s_k
            r0, rsd = self.rate_ref, self.rate_ref_sd
        else:
            r0, rsd = self.prior_rate(float(np.median(tool.feed[: min(n, 10)])))
        sc = self.scale(tool.feed)
        v, vsd = self.start(tool)
        r, c = r0, 0.0
        if self.config.offset:
            R, g = self.sigma2_within, self.sigma2_between
        else:
            R, g = self.sigma2, 0.0
        a, b, d, e, f = vsd * vsd, 0.0, 0.0, rsd * rsd, 0.0
        Q = q * self.sigma2
        est = np.empty(n)
        esd = np.empty(n)
        rate = np.empty(n)
        for k in range(n):
            if k > 0:  # predict: VB += r s; the rate a random walk; the offset constant
                s = float(sc[k - 1])
                v = v + r * s
                a, b, d, e = a + 2 * s * b + s * s * e, b + s * e, d + s * f, e + Q
            h1, h2, h3 = a + d, b + f, d + g
            S = a + 2 * d + g + R
            innov = (z[k] - v - c) / S
            v += h1 * innov
            r += h2 * innov
            c += h3 * innov
            a, b, d = a - h1 * h1 / S, b - h1 * h2 / S, d - h1 * h3 / S
            e, f, g = e - h2 * h2 / S, f - h2 * h3 / S, g - h3 * h3 / S
            if r < 0.0:  # the wear never shrinks: project the rate
                r = 0.0
            est[k], esd[k], rate[k] = v, math.sqrt(max(a, 1e-12)), r * float(sc[k])
        return est, esd, rate


def _standardise(z: F64) -> tuple[F64, F64]:
    mu = z.mean(axis=0)
    sd = z.std(axis=0)
    sd[sd < 1e-12] = 1.0
    return mu, sd


def _pava(y: F64, w: F64) -> F64:
    """Isotonic (non-decreasing) least squares of ``y`` in the given order."""
    vals: list[float] = []
    wts: list[float] = []
    cnt: list[int] = []
    for yi, wi in zip(y.tolist(), w.tolist(), strict=True):
        vals.append(yi)
        wts.append(wi)
        cnt.append(1)
        while len(vals) > 1 and vals[-2] > vals[-1]:
            wsum = wts[-2] + wts[-1]
            v = (vals[-2] * wts[-2] + vals[-1] * wts[-1]) / wsum
            c = cnt[-2] + cnt[-1]
            vals[-2:] = [v]
            wts[-2:] = [wsum]
            cnt[-2:] = [c]
    return np.repeat(np.array(vals), np.array(cnt))


def fresh_reference(tools: Sequence[ToolData], features: str = "mean") -> F64:
    """The signals' fresh-tool level as a line in the feed rate, over the tools that came
    in fresh (their first ``N_FRESH`` segments at VB <= ``FRESH_VB``); one point per
    tool. A flat level when all share one feed rate."""
    pts_f: list[float] = []
    pts_x: list[F64] = []
    for t in tools:
        if t.vb is None:
            continue
        k = np.flatnonzero(t.vb[:N_FRESH] <= FRESH_VB)
        if len(k) == 0:
            continue
        pts_f.append(float(np.median(t.feed[k])) / _FEED_UNIT)
        x = t.x_all if (features == "five" and t.x_all is not None) else t.x
        pts_x.append(np.median(x[k], axis=0))
    if not pts_x:
        raise ParameterError("tools", "one training tool that came in fresh", 0)
    X = np.array(pts_x)
    f = np.array(pts_f)
    if np.ptp(f) <= SAME_CONDITIONS * f.mean():
        return np.vstack([X.mean(axis=0), np.zeros(X.shape[1])])
    A = np.column_stack([np.ones(len(f)), f])
    c, *_ = np.linalg.lstsq(A, X, rcond=None)
    return np.asarray(c, dtype=np.float64)


def fit(
    tools: Sequence[ToolData], config: HybridConfig, *, ref_level: F64 | None = None
) -> HybridModel:
    """Fit the map and the fresh-tool prior on training tools (each with ``vb``).
    ``ref_level``: with ``reference = "conditions"``, the signals' fresh-tool level given
    (shape (2, m), as :func:`fresh_reference` returns) instead of fitted; only the
    diagnosis's in-sample oracle on one tool uses it (a tool that came in worn has no
    fresh segments to fit it from, and on one tool any level is a constant the
    standardisation removes)."""
    train = [t for t in tools if t.vb is not None]
    if len(train) < 2:
        raise ParameterError("tools", "two or more training tools with measured VB", len(train))
    ref = None
    if config.reference == "conditions":
        ref = fresh_reference(train, config.features) if ref_level is None else ref_level
    five = config.features == "five"
    if five and any(t.x_all is None for t in train):
        raise ParameterError("x_all", "every feature of every training tool", None)
    X = np.vstack([t.x_all if (five and t.x_all is not None) else t.x for t in train])
    feed = np.concatenate([t.feed for t in train])
    y = np.concatenate([t.vb for t in train if t.vb is not None])
    # per-row weights: each tool counts once, whatever its length
    w = np.concatenate([np.full(len(t.feed), 1.0 / len(t.feed)) for t in train])
    w = w / w.mean()
    f = (feed / _FEED_UNIT)[:, None]
    raw = np.column_stack([X, f]) if ref is None else X - (ref[0] + ref[1] * f)
    mu, sd = _standardise(raw)
    m = HybridModel(config, ref, mu, sd, None, None, None, None, 0.0, 0.0, 0.0)
    z = (raw - mu) / sd
    if config.map == "gbr":
        # histogram gradient boosting: the same depth and number of trees as the
        # protocol's, ~6x faster than GradientBoostingRegressor on these rows
        from sklearn.ensemble import HistGradientBoostingRegressor
        from threadpoolctl import threadpool_limits

        m.gbr = HistGradientBoostingRegressor(
            max_depth=2, max_iter=100, early_stopping=False, random_state=0
        )
        with threadpool_limits(1):  # ~1,400 rows: threads cost more than they give
            m.gbr.fit(z, y, sample_weight=w)
    else:
        A = m._design(z)
        sw = np.sqrt(w)[:, None]
        reg = 1e-6 * np.eye(A.shape[1])
        reg[0, 0] = 0.0
        Aw = A * sw
        m.coef = np.linalg.solve(Aw.T @ Aw + reg * len(A), Aw.T @ (y * sw[:, 0]))
        if config.map == "isotonic":
            idx = A @ m.coef
            o = np.argsort(idx, kind="stable")
            m.iso_x = idx[o]
            m.iso_y = _pava(y[o], w[o])
    res = y - m.measure(X, feed)
    m.sigma2 = float(max(np.average(res * res, weights=w), 1.0))
    parts = np.cumsum([len(t.feed) for t in train])[:-1]
    means = np.array([float(np.mean(p)) for p in np.split(res, parts)])
    m.sigma2_between = float(max(np.var(means), 1.0))
    within = float(np.mean([float(np.var(p)) for p in np.split(res, parts)]))
    m.sigma2_within = max(within, 1.0)
    # a fresh tool: what the training tools that came in new started at
    fresh = [float(t.vb[0]) for t in train if t.vb is not None and t.vb[0] <= FRESH_VB]
    starts = [float(t.vb[0]) for t in train if t.vb is not None]
    m.v0 = float(np.mean(fresh)) if fresh else 0.0
    m.v0_sd = max(float(np.std(starts)), FRESH_SD_FLOOR)
    m.rates = [tool_rate(t) for t in train]
    m.taylor = taylor_fit(m.rates)
    if config.rate_law == "segment":
        vref = m.taylor[3]
        m.speed_b, m.speed_b_fallback = segment_fit(train, vref)
        refs = [
            float((t.vb[-1] - t.vb[0]) / max(np.sum((t.feed[:-1] / vref) ** m.speed_b), 1e-9))
            for t in train
            if t.vb is not None
        ]
        m.rate_ref = float(np.median(refs))
        m.rate_ref_sd = max(float(np.std(refs)), RATE_SD_FLOOR)
    m.rate_sd = max(float(np.std([r for _, r in m.rates])), RATE_SD_FLOOR)
    return m


def knots(vb: F64) -> np.ndarray:
    """Rows where VB was measured: the ends and every change of slope."""
    d = np.diff(vb)
    inner = np.flatnonzero(np.abs(np.diff(d)) > KNOT_TOL * np.maximum(np.abs(d[:-1]), 1e-9) + 1e-6)
    return np.unique(np.concatenate([[0], inner + 1, [len(vb) - 1]]))


def segment_b(tools: Sequence[ToolData], vref: float) -> float:
    """Revision 5: the exponent of the law per segment (:func:`segment_fit`'s b)."""
    return segment_fit(tools, vref)[0]


def segment_fit(tools: Sequence[ToolData], vref: float) -> tuple[float, bool]:
    """Revision 5: the exponent of the law per segment from the knot intervals within
    the tools: ``ln(dVB / sum s_k) = level(tool) + c VB_mid``, least squares for each b
    of :data:`SEGMENT_B`, the lowest residual sum of squares wins (the first on a tie).
    Intervals with dVB <= :data:`SEGMENT_MIN_DVB` are left out. With fewer intervals
    than the tools + 2 (no degree of freedom for the slope) b falls back to 0 (no
    speed factor). Returns (b, whether the fallback was used)."""
    rows: list[tuple[int, float, F64, float]] = []  # (tool index, dVB, feeds, mid VB)
    for i, t in enumerate(tools):
        if t.vb is None:
            continue
        kn = knots(t.vb)
        for a, b in itertools.pairwise(kn):
            dvb = float(t.vb[b] - t.vb[a])
            if dvb > SEGMENT_MIN_DVB:
                rows.append((i, dvb, t.feed[a:b] / vref, 0.5 * float(t.vb[a] + t.vb[b])))
    if len(rows) < len(tools) + 2:
        return 0.0, True
    ids = sorted({r[0] for r in rows})
    X = np.zeros((len(rows), len(ids) + 1))
    for j, r in enumerate(rows):
        X[j, ids.index(r[0])] = 1.0
        X[j, -1] = r[3] / 100.0
    best, best_rss = 0.0, math.inf
    for b in SEGMENT_B:
        y = np.array([math.log(r[1] / float(np.sum(r[2] ** b))) for r in rows])
        c, *_ = np.linalg.lstsq(X, y, rcond=None)
        rss = float(np.sum((y - X @ c) ** 2))
        if rss < best_rss - 1e-12:
            best, best_rss = b, rss
    return best, False


def tool_rate(t: ToolData) -> tuple[float, float]:
    """(median feed rate, mean wear rate [um/segment] from its first to its last row)."""
    assert t.vb is not None
    return float(np.median(t.feed)), float((t.vb[-1] - t.vb[0]) / max(len(t.vb) - 1, 1))


def median_rate(rates: Sequence[tuple[float, float]], feed: float) -> float:
    """Revision 3's rule: the median rate of the tools at the same conditions (feed
    rates within ``SAME_CONDITIONS``) when two or more share them, else of all."""
    rs = np.array([r for _, r in rates])
    same = np.array([abs(f - feed) <= SAME_CONDITIONS * feed for f, _ in rates])
    return float(np.median(rs[same] if same.sum() >= 2 else rs))


def taylor_fit(rates: Sequence[tuple[float, float]]) -> tuple[float, float, float, float]:
    """The prior rate's Taylor-type law ``ln r = level + b ln(v_f / vref)`` over the
    tools' (feed rate, rate), each tool once (protocol revision 4): b the least-squares
    slope clipped to :data:`TAYLOR_B` (the constrained fit of one parameter); the
    lower bound when the feed rates span less than ``SAME_CONDITIONS`` (no slope);
    level the median of ``ln r_i - b ln(v_i / vref)``; vref the median feed rate.
    Rates are floored at 1e-3 um/segment for the logarithm. Returns (level, b, the
    unclipped slope (nan without one), vref)."""
    if len(rates) < 2:
        raise ParameterError("rates", "two or more training tools", len(rates))
    f = np.array([v for v, _ in rates])
    vref = float(np.median(f))
    x = np.log(f / vref)
    y = np.log(np.maximum([r for _, r in rates], 1e-3))
    if np.ptp(f) <= SAME_CONDITIONS * vref:
        raw = math.nan
        b = TAYLOR_B[0]
    else:
        xc = x - x.mean()
        raw = float(xc @ (y - y.mean()) / (xc @ xc))
        b = float(min(max(raw, TAYLOR_B[0]), TAYLOR_B[1]))
    return float(np.median(y - b * x)), b, raw, vref


def taylor_rate(law: tuple[float, float, float, float], feed: float) -> float:
    """The law's rate [um/segment] at a feed rate."""
    level, b, _, vref = law
    return float(math.exp(level + b * math.log(feed / vref)))


def choose_rate_law(rates: Sequence[tuple[float, float]]) -> tuple[str, dict[str, float]]:
    """Revision 4's choice of the prior rate's rule on the training tools only: leave
    one tool out, predict its rate from the others by each rule, score = mean absolute
    error [um/segment], each tool once; the lower wins, a tie goes to ``median``."""
    score: dict[str, float] = {}
    for law in RATE_LAWS:
        errs = []
        for i, (f, r) in enumerate(rates):
            rest = [x for j, x in enumerate(rates) if j != i]
            p = taylor_rate(taylor_fit(rest), f) if law == "taylor" else median_rate(rest, f)
            errs.append(abs(p - r))
        score[law] = float(np.mean(errs))
    best = min(RATE_LAWS, key=lambda k: (score[k], RATE_LAWS.index(k)))
    return best, score


LIFE_METHODS = ("rate", "mean", "prior")


def life_end(
    est: F64,
    rate: F64,
    k: int,
    criterion: float,
    *,
    method: str = "rate",
    start: float = 0.0,
    prior: float = math.nan,
) -> float:
    """Predicted segment at which VB reaches ``criterion``, from the estimate at segment
    ``k``: linear in the filtered rate (``rate``; for the map alone, the slope of the
    estimate over the last 20 segments), in the mean rate since the tool came in
    (``mean``: (VB(k) - start) / k) or in the training tools' rate at these cutting
    conditions (``prior``: :meth:`HybridModel.prior_rate`, passed as ``prior``). inf
    when the rate is 0."""
    v = float(est[k])
    if v >= criterion:
        return float(k)
    if method == "prior":
        r = prior
    elif method == "mean":
        r = (v - start) / max(k, 1)
    else:
        r = float(rate[k])
        if not math.isfinite(r):
            lo = max(0, k - 20)
            r = float((est[k] - est[lo]) / max(k - lo, 1))
    return k + (criterion - v) / r if r > 1e-9 else math.inf


__all__ = [
    "FEATURE_SETS",
    "KNOT_TOL",
    "LIFE_METHODS",
    "MAPS",
    "RATE_LAWS",
    "REFERENCES",
    "SEGMENT_B",
    "SMOOTHINGS",
    "SMOOTHINGS_REV3",
    "TAYLOR_B",
    "HybridConfig",
    "HybridModel",
    "ToolData",
    "candidates",
    "choose_rate_law",
    "fit",
    "fresh_reference",
    "knots",
    "life_end",
    "median_rate",
    "segment_b",
    "segment_fit",
    "taylor_fit",
    "taylor_rate",
    "tool_rate",
]
