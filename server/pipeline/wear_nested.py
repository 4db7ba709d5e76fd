"""Wear on tools never seen: the nested evaluation of issue 35 (docs/turning-wear.md,
"Tools never seen").

Outer splits: leave one tool out, and repeated leave-k-tools-out (k = 2, 3, 4). Inside
each outer fold every candidate configuration of :mod:`estimators.wear.hybrid` is scored
by leave-one-tool-out over the fold's training tools; the best is refit on all of them
and run on the test tools; its inner models give CV+ intervals over tools. The
baselines are fitted on the same training rows: a line of VB on one ``_MEAN``, gradient
boosting (scikit-learn defaults, ``random_state=0``) on one signal's five features and on
the hybrid's features, and a no-signal prior (VB from the segments cut so far and the
record). Everything is in segments: the table has no cutting time.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from common.arrays import F64
from estimators.errors import ParameterError
from estimators.wear.hybrid import (
    LIFE_METHODS,
    RATE_LAWS,
    SAME_CONDITIONS,
    HybridConfig,
    HybridModel,
    ToolData,
    candidates,
    choose_rate_law,
    fit,
    knots,
    life_end,
    taylor_fit,
    tool_rate,
)
from estimators.wear.turning import clean_condition
from server.records.wear_table import FEATURES, FEED, VB, WearTable, read_wear_table

#: the signal sets (the first names the linear and five-feature baselines' signal)
SETS: dict[str, tuple[str, ...]] = {
    "F_f": ("F_f",),
    "TV2.Z": ("TV2.Z",),
    "CV3.Z": ("CV3.Z",),
    "TV2.S": ("TV2.S",),
    "drives": ("TV2.Z", "CV3.Z", "TV2.X", "CV3.X", "TV2.S", "CV3.S"),
    "all": ("F_f", "TV2.Z", "CV3.Z", "TV2.X", "CV3.X", "TV2.S", "CV3.S", "F_c", "F_p"),
}
#: programmed spindle speed (CNC units): read when the table has it, for the groups
SPEED = "CON.A.SREAL.S"
#: repeated leave-k-tools-out: k and splits per k, and the seed of the draws
K_OUT = (2, 3, 4)
SPLITS_PER_K = 5
SPLIT_SEED = 35
ALPHA = 0.05
#: remaining-life criteria [um] (the second for tools that never reach the first)
CRITERIA = (300.0, 150.0)
BASELINES = ("linear", "gbr5", "gbr_same", "prior")


def columns_needed(sets: Sequence[str]) -> list[str]:
    """The ``_MEAN`` of every signal, the five features of each set's first signal
    (``CV3.X_SK``/``_KURT`` have empty cells and are never asked for)."""
    cols = {f"{s}_{f}" for name in sets for s in SETS[name] for f in features_of(s)}
    cols |= {f"{SETS[name][0]}_{f}" for name in sets for f in FEATURES}
    return [FEED, *sorted(cols)]


def features_of(signal: str) -> tuple[str, ...]:
    """The complete features of a signal (``CV3.X_SK``/``_KURT`` have empty cells)."""
    return ("MEAN", "RMS", "MAX") if signal == "CV3.X" else FEATURES


def load(path: Any, sets: Sequence[str]) -> WearTable:
    return read_wear_table(path, columns_needed(sets), optional=(VB, SPEED))


def condition_groups(table: WearTable) -> dict[int, str]:
    """Each tool's cutting-condition group, from the data: tools whose median
    (cleaned) programmed spindle speed and feed rate both agree within
    ``SAME_CONDITIONS`` (relative) share a group; a table without the speed column is
    grouped on the feed rate alone. Groups are named by their median condition
    (``S<speed>k_F<feed>``, CNC units, the speed in thousands), members in table order.

    On the published table the feed per revolution (feed / speed) is the same on every
    tool, so the groups are the three speeds: tools 6 and 7 (S7514k), tool 3 (S11977k),
    the other six (S8154k), not the tools 3, 5, 16 the data's notes name."""
    cols = [FEED, SPEED] if SPEED in table.columns else [FEED]
    cond = {
        t: np.array([float(np.median(clean_condition(table.column(c, t))[0])) for c in cols])
        for t in table.tools
    }
    members: list[list[int]] = []
    for t in table.tools:
        for g in members:
            ref = np.median([cond[m] for m in g], axis=0)
            if np.all(np.abs(cond[t] - ref) <= SAME_CONDITIONS * ref):
                g.append(t)
                break
        else:
            members.append([t])
    out: dict[int, str] = {}
    for g in members:
        med = np.median([cond[m] for m in g], axis=0)
        name = f"F{med[0]:.0f}" if len(med) == 1 else f"S{med[1] / 1e3:.0f}k_F{med[0]:.0f}"
        out.update({m: name for m in g})
    return out


def tool_data(
    table: WearTable, signals: Sequence[str], tool: int, *, record: bool = True
) -> ToolData:
    """One tool for the hybrid; ``record``: it enters with its record (its VB when it
    came in: 0 for a new tool, 39 / 41 um for tools 6 / 14 put back from the crib)."""
    x = np.column_stack([table.column(f"{s}_MEAN", tool) for s in signals])
    xa = np.column_stack([table.column(f"{s}_{f}", tool) for s in signals for f in features_of(s)])
    feed, _ = clean_condition(table.column(FEED, tool))
    vb = table.column(VB, tool)
    return ToolData(tool, x, feed, vb, float(vb[0]) if record else None, x_all=xa)


def outer_splits(
    tools: Sequence[int], *, quick: bool = False, splits_per_k: int = SPLITS_PER_K
) -> list[tuple[str, tuple[int, ...]]]:
    """(protocol, test tools): LOTO over every tool, then ``splits_per_k`` distinct
    random draws of k tools for each k in ``K_OUT`` (seeded)."""
    out: list[tuple[str, tuple[int, ...]]] = [("loto", (t,)) for t in tools]
    if quick:
        return out
    rng = np.random.default_rng(SPLIT_SEED)
    for k in K_OUT:
        seen: set[tuple[int, ...]] = set()
        while sum(1 for p, _ in out if p == f"l{k}o") < splits_per_k:
            pick = tuple(sorted(int(t) for t in rng.choice(list(tools), size=k, replace=False)))
            if pick not in seen:
                seen.add(pick)
                out.append((f"l{k}o", pick))
    return out


def _wquantile(values: F64, weights: F64, q: float) -> F64:
    """Weighted quantile along axis 1 (values (n, N), weights (N,))."""
    o = np.argsort(values, axis=1)
    v = np.take_along_axis(values, o, axis=1)
    cw = np.cumsum(weights[o], axis=1)
    cw /= cw[:, -1:]
    j = np.argmax(cw >= q - 1e-12, axis=1)
    return v[np.arange(len(v)), j]


@dataclass
class ToolResult:
    tool: int
    vb: F64
    est: F64
    lo: F64
    hi: F64
    base: dict[str, F64]
    life: dict[str, float] = field(default_factory=dict)
    entry: dict[str, float] = field(default_factory=dict)
    #: the life error at half-life taken apart (:func:`life_parts`)
    life_parts: dict[str, float] = field(default_factory=dict)


@dataclass
class FoldResult:
    protocol: str
    test: tuple[int, ...]
    chosen: str
    tools: list[ToolResult]
    #: the chosen configuration's inner score (mean over the inner left-out tools of
    #: their MAE) - what the selection believed of it
    inner_score: float = math.nan
    #: configurations whose inner score is within one paired standard error of the best
    #: (over the inner left-out tools): how many the inner folds cannot tell apart
    inner_close: int = 0
    n_configs: int = 0
    #: the prior rate's rule chosen on the training tools (revision 4; ``median`` only
    #: before; revision 5's ``segment`` alone), the law's exponent on them (clipped, and
    #: the unclipped slope; under ``segment`` b is one of the grid ``SEGMENT_B`` and
    #: there is no unclipped slope: nan) and each rule's inner score [um/segment]
    rate_law: str = "median"
    rate_b: float = math.nan
    rate_b_raw: float = math.nan
    #: revision 5: b is the fallback 0 (too few knot intervals for the fit)
    rate_b_fallback: bool = False
    rate_scores: dict[str, float] = field(default_factory=dict)


class _Cache:
    """Fits keyed by (signal set, training tools, reference, map): smoothing does not
    change the fit, and inner training sets repeat across outer folds."""

    def __init__(self) -> None:
        self.fits: dict[tuple[Any, ...], HybridModel] = {}

    def get(
        self, key: tuple[Any, ...], tools: Sequence[ToolData], cfg: HybridConfig
    ) -> HybridModel:
        k = (*key, cfg.features, cfg.reference, cfg.map, cfg.rate_law)
        m = self.fits.get(k)
        if m is None:  # the rule of the prior rate is fitted too (revision 5's law)
            m = fit(
                tools,
                HybridConfig(
                    cfg.reference, cfg.map, None, features=cfg.features, rate_law=cfg.rate_law
                ),
            )
            self.fits[k] = m
        return m


def _with(m: HybridModel, cfg: HybridConfig) -> HybridModel:
    out = HybridModel(**{**m.__dict__, "config": cfg})
    return out


def _prior_fit(train: Sequence[ToolData]) -> list[tuple[float, float]]:
    return [
        (float(np.median(t.feed)), float((t.vb[-1] - t.vb[0]) / max(len(t.vb) - 1, 1)))
        for t in train
        if t.vb is not None
    ]


def prior_predict(rates: list[tuple[float, float]], v0: float, tool: ToolData) -> F64:
    """No-signal prior: v0 + r k, r the training tools' median rate at these conditions
    (two or more sharing them) or over all."""
    feed = float(np.median(tool.feed[:10]))
    rs = np.array([r for _, r in rates])
    same = np.array([abs(f - feed) <= SAME_CONDITIONS * feed for f, _ in rates])
    r = float(np.median(rs[same] if same.sum() >= 2 else rs))
    start = tool.start_vb if tool.start_vb is not None else v0
    return start + r * np.arange(len(tool.feed), dtype=np.float64)


def _baselines(
    table: WearTable,
    signals: Sequence[str],
    train: Sequence[int],
    test: int,
    dtrain: Sequence[ToolData],
    dtest: ToolData,
) -> dict[str, F64]:
    from sklearn.ensemble import GradientBoostingRegressor

    def rows(tools: Sequence[int]) -> np.ndarray:
        return np.concatenate([table.rows_of(t) for t in tools])

    tr, te = rows(train), table.rows_of(test)
    y = table.columns[VB][tr]
    s0 = signals[0]
    A = np.column_stack([np.ones(len(tr)), table.columns[f"{s0}_MEAN"][tr]])
    c, *_ = np.linalg.lstsq(A, y, rcond=None)
    lin = c[0] + c[1] * table.columns[f"{s0}_MEAN"][te]
    X5 = np.column_stack([table.columns[f"{s0}_{f}"][tr] for f in FEATURES])
    X5t = np.column_stack([table.columns[f"{s0}_{f}"][te] for f in FEATURES])
    g5 = GradientBoostingRegressor(random_state=0).fit(X5, y).predict(X5t)
    Xs = np.vstack([np.column_stack([d.x, d.feed]) for d in dtrain])
    Xst = np.column_stack([dtest.x, dtest.feed])
    gs = (
        GradientBoostingRegressor(random_state=0).fit(Xs, y).predict(Xst)
        if len(signals) > 1
        else g5
    )
    fresh = [float(d.vb[0]) for d in dtrain if d.vb is not None and d.vb[0] <= 0.0]
    pr = prior_predict(_prior_fit(dtrain), float(np.mean(fresh)) if fresh else 0.0, dtest)
    return {
        "linear": np.asarray(lin, dtype=np.float64),
        "gbr5": np.asarray(g5, dtype=np.float64),
        "gbr_same": np.asarray(gs, dtype=np.float64),
        "prior": pr,
    }


def life_errors(
    vb: F64, est: F64, rate: F64, start: float, method: str, prior: float | F64 = math.nan
) -> dict[str, float]:
    """|predicted - true end| / true remaining life at half of the life, per criterion
    the tool reaches (none if it reaches neither); ``prior``: the training tools' rate
    at the tool's conditions (life method ``prior``)."""
    out: dict[str, float] = {}
    for crit in CRITERIA:
        hit = np.flatnonzero(vb >= crit)
        if len(hit) and hit[0] >= 2:
            h = int(hit[0])
            k = h // 2
            end = life_end(est, rate, k, crit, method=method, start=start, prior=_at(prior, k))
            out[f"{crit:g}"] = abs(end - h) / (h - k) if math.isfinite(end) else math.inf
    return out


def _at(prior: float | F64, k: int) -> float:
    """The prior rate at segment ``k`` (revision 5's is per segment)."""
    return float(prior) if np.ndim(prior) == 0 else float(np.asarray(prior)[k])


def life_parts(
    vb: F64, est: F64, rate: F64, start: float, method: str, prior: float | F64
) -> dict[str, float]:
    """The life error at half-life (300 um, 150 um if never 300) taken apart: the
    extrapolation is ``k + (criterion - level) / rate``; each of level and rate is taken
    from the estimate or from the measured VB (``true``: the mean rate since the tool
    came in, as the file's VB gives it; ``future``: the rate the tool really had to its
    end, which makes the error 0) or from the training tools' median rate at these
    conditions (``prior``). Keys ``LEVEL/RATE``; empty when neither criterion is
    reached."""
    for crit in CRITERIA:
        hit = np.flatnonzero(vb >= crit)
        if len(hit) and hit[0] >= 2:
            break
    else:
        return {}
    h = int(hit[0])
    k = h // 2
    prior = _at(prior, k)
    lv = {"est": float(est[k]), "true": float(vb[k])}
    if method == "prior":
        r_est = prior
    elif method == "mean":
        r_est = (lv["est"] - start) / max(k, 1)
    else:
        r_est = float(rate[k])
        if not math.isfinite(r_est):
            lo = max(0, k - 20)
            r_est = float((est[k] - est[lo]) / max(k - lo, 1))
    rt = {"est": r_est, "true": (lv["true"] - float(vb[0])) / max(k, 1), "prior": prior}
    out: dict[str, float] = {"criterion": crit, "rate_future": (crit - lv["true"]) / (h - k)}
    for ln, v in lv.items():
        for rn, r in rt.items():
            end = k + (crit - v) / r if r > 1e-9 else math.inf
            end = float(k) if v >= crit else end
            out[f"{ln}/{rn}"] = abs(end - h) / (h - k) if math.isfinite(end) else math.inf
    out["rate_est"], out["rate_true"], out["rate_prior"] = r_est, rt["true"], prior
    out["level_err"] = lv["est"] - lv["true"]
    return out


def _life_score(errs: Sequence[dict[str, float]]) -> float:
    """Median over tools of the life error at 300 um (150 um where 300 is not reached)."""
    v = [e.get("300", e.get("150")) for e in errs if e]
    return float(np.median([x for x in v if x is not None])) if v else math.inf


def _cv_plus(
    d: ToolData,
    tools: Sequence[int],
    models: dict[int, HybridModel],
    inner: dict[int, tuple[F64, F64, F64, F64]],
) -> tuple[F64, F64]:
    """CV+ 95 % interval over the training tools (each tool weighted once)."""
    lows, highs, ws = [], [], []
    for i in tools:
        mu, sg, _ = models[i].run(d)
        e_i, s_i, v_i, _ = inner[i]
        a = np.abs(v_i - e_i) / s_i
        lows.append(mu[:, None] - a[None, :] * sg[:, None])
        highs.append(mu[:, None] + a[None, :] * sg[:, None])
        ws.append(np.full(len(a), 1.0 / len(a)))
    w = np.concatenate(ws)
    return _wquantile(np.hstack(lows), w, ALPHA / 2), _wquantile(np.hstack(highs), w, 1 - ALPHA / 2)


def run_fold(
    table: WearTable,
    set_name: str,
    test: Sequence[int],
    protocol: str,
    cache: _Cache,
    *,
    configs: Sequence[HybridConfig] | None = None,
    rate_laws: Sequence[str] = ("median",),
) -> FoldResult:
    """One outer fold: nested choice, refit, CV+ intervals, baselines, life, entry.
    ``rate_laws``: the prior rate's rules to choose from on the training tools' rates
    (revision 4: ``("median", "taylor")``); the chosen one is set on every
    configuration."""
    laws = tuple(rate_laws)
    known = (*RATE_LAWS, "segment")
    if not laws or any(k not in known for k in laws) or ("segment" in laws and len(laws) > 1):
        raise ParameterError(
            "rate_laws",
            f"one or more of {RATE_LAWS}, or ('segment',) alone (revision 5's law is not "
            "chosen against the others)",
            laws,
        )
    signals = SETS[set_name]
    tools = [t for t in table.tools if t not in test]
    data = {t: tool_data(table, signals, t) for t in table.tools}
    cfgs = list(configs) if configs is not None else candidates()
    rates = [tool_rate(data[t]) for t in tools]
    _, rate_b, rate_b_raw, _ = taylor_fit(rates)
    rate_scores: dict[str, float] = {}
    law = rate_laws[0]
    if len(rate_laws) > 1:
        law, sc = choose_rate_law(rates)
        rate_scores = {k: v for k, v in sc.items() if k in rate_laws}
        law = min(rate_laws, key=lambda k: (rate_scores[k], list(rate_laws).index(k)))
    cfgs = [replace(c, rate_law=law) for c in cfgs]

    def model_of(train: Sequence[int], c: HybridConfig) -> HybridModel:
        key = (set_name, tuple(sorted(train)))
        return _with(cache.get(key, [data[t] for t in train], c), c)

    # inner leave-one-tool-out over the training tools
    score: dict[HybridConfig, list[float]] = {c: [] for c in cfgs}
    inner: dict[HybridConfig, dict[int, tuple[F64, F64, F64, F64]]] = {c: {} for c in cfgs}
    for i in tools:
        vb = data[i].vb
        assert vb is not None
        for c in cfgs:
            est, sd, rate = model_of([t for t in tools if t != i], c).run(data[i])
            score[c].append(float(np.mean(np.abs(est - vb))))
            inner[c][i] = (est, sd, vb, rate)
    best = min(cfgs, key=lambda c: (float(np.mean(score[c])), c.label))
    sb = np.asarray(score[best])
    close = 0
    for c in cfgs:
        diff = np.asarray(score[c]) - sb
        se = float(np.std(diff, ddof=1) / math.sqrt(len(diff))) if len(diff) > 1 else 0.0
        close += int(float(np.mean(diff)) <= se)
    model = model_of(tools, best)
    loo = {i: model_of([t for t in tools if t != i], best) for i in tools}

    def prior_of(m: HybridModel, d: ToolData) -> float | F64:
        if m.config.rate_law == "segment":  # per segment, at each segment's speed
            return m.rate_ref * m.scale(d.feed)
        return m.prior_rate(float(np.median(d.feed[: min(len(d.feed), 10)])))[0]

    # the life's extrapolation: chosen on the same inner folds
    life_method = min(
        LIFE_METHODS,
        key=lambda m: _life_score(
            [
                life_errors(v, e, r, float(v[0]), m, prior_of(loo[i], data[i]))
                for i, (e, _, v, r) in inner[best].items()
            ]
        ),
    )
    out: list[ToolResult] = []
    for t in test:
        d = data[t]
        assert d.vb is not None
        est, _, rate = model.run(d)
        lo, hi = _cv_plus(d, tools, loo, inner[best])
        base = _baselines(table, signals, tools, t, [data[x] for x in tools], d)
        r = ToolResult(t, d.vb, est, lo, hi, base)
        prior = prior_of(model, d)
        r.life = life_errors(d.vb, est, rate, float(d.start_vb or 0.0), life_method, prior)
        r.life_parts = life_parts(d.vb, est, rate, float(d.start_vb or 0.0), life_method, prior)
        # entered part-way (a third into its life): with its record, and with none
        k = len(d.vb) // 3
        for rec in (True, False):
            e, _, _ = model.run(d.tail(k, record=rec))
            r.entry["record" if rec else "no_record"] = float(np.mean(np.abs(e - d.vb[k:])))
        out.append(r)
    return FoldResult(
        protocol,
        tuple(test),
        f"{best.label}/life={life_method}",
        out,
        inner_score=float(np.mean(sb)),
        inner_close=close,
        n_configs=len(cfgs),
        rate_law=law,
        rate_b=model.speed_b if law == "segment" else rate_b,
        rate_b_raw=math.nan if law == "segment" else rate_b_raw,
        rate_b_fallback=law == "segment" and model.speed_b_fallback,
        rate_scores=rate_scores,
    )


def evaluate(
    table: WearTable,
    sets: Sequence[str],
    splits: Sequence[tuple[str, tuple[int, ...]]],
    *,
    configs: Sequence[HybridConfig] | None = None,
    progress: Callable[[int], Any] | None = None,
    rate_laws: Sequence[str] = ("median",),
) -> dict[str, list[FoldResult]]:
    """Every outer split for every signal set."""
    cache = _Cache()
    res: dict[str, list[FoldResult]] = {}
    for s in sets:
        res[s] = []
        for proto, test in splits:
            res[s].append(
                run_fold(table, s, test, proto, cache, configs=configs, rate_laws=rate_laws)
            )
            if progress is not None:
                progress(1)
        cache.fits.clear()
    return res


# ------------------------------------------------------------------ summaries
def _mae(a: F64, b: F64) -> float:
    return float(np.mean(np.abs(a - b)))


def fold_metrics(f: FoldResult) -> dict[str, float]:
    """Pooled over the fold's test tools: MAE (all rows, knots), baselines', coverage,
    median width."""
    vb = np.concatenate([t.vb for t in f.tools])
    est = np.concatenate([t.est for t in f.tools])
    kn = [knots(t.vb) for t in f.tools]
    vbk = np.concatenate([t.vb[k] for t, k in zip(f.tools, kn, strict=True)])
    m: dict[str, float] = {
        "mae": _mae(est, vb),
        "mae_knots": _mae(
            np.concatenate([t.est[k] for t, k in zip(f.tools, kn, strict=True)]), vbk
        ),
    }
    for b in BASELINES:
        pb = np.concatenate([t.base[b] for t in f.tools])
        m[f"mae_{b}"] = _mae(pb, vb)
        m[f"mae_knots_{b}"] = _mae(
            np.concatenate([t.base[b][k] for t, k in zip(f.tools, kn, strict=True)]), vbk
        )
    lo = np.concatenate([t.lo for t in f.tools])
    hi = np.concatenate([t.hi for t in f.tools])
    m["coverage"] = float(np.mean((vb >= lo) & (vb <= hi)))
    m["width"] = float(np.median(hi - lo))
    return m


def per_tool(f: FoldResult) -> list[dict[str, Any]]:
    out = []
    for t in f.tools:
        row: dict[str, Any] = {
            "tool": t.tool,
            "mae": _mae(t.est, t.vb),
            "coverage": float(np.mean((t.vb >= t.lo) & (t.vb <= t.hi))),
            "width": float(np.median(t.hi - t.lo)),
            "life": dict(t.life),
            "life_parts": dict(t.life_parts),
            "entry": dict(t.entry),
        }
        for b in BASELINES:
            row[f"mae_{b}"] = _mae(t.base[b], t.vb)
        out.append(row)
    return out


def summarise(folds: Sequence[FoldResult], groups: dict[int, str] | None = None) -> dict[str, Any]:
    """Per protocol: median and range over splits of each metric and of the ratios to
    the baselines; per tool (LOTO); by condition group (``groups``: tool -> group, from
    :func:`condition_groups`); life; entry; chosen configs."""
    out: dict[str, Any] = {}
    protos = list(dict.fromkeys(f.protocol for f in folds))
    for p in protos:
        fs = [f for f in folds if f.protocol == p]
        ms = [fold_metrics(f) for f in fs]
        keys = list(ms[0])
        for b in BASELINES:
            for m in ms:
                m[f"ratio_{b}"] = m["mae"] / m[f"mae_{b}"] if m[f"mae_{b}"] > 0 else math.nan
            keys.append(f"ratio_{b}")
        for f, m in zip(fs, ms, strict=True):
            # what the selection believed (inner score) against what the chosen
            # configuration made on the outer tools, each tool counted once as inside
            outer = float(np.mean([_mae(t.est, t.vb) for t in f.tools]))
            m["inner_score"] = f.inner_score
            m["outer_score"] = outer
            m["optimism"] = outer - f.inner_score
            m["optimism_ratio"] = outer / f.inner_score if f.inner_score > 0 else math.nan
            m["inner_close"] = float(f.inner_close)
        keys += ["inner_score", "outer_score", "optimism", "optimism_ratio", "inner_close"]
        tools = [r for f in fs for r in per_tool(f)]
        pooled = fold_metrics(FoldResult(p, (), "", [t for f in fs for t in f.tools]))
        beat = [r["mae"] < r["mae_linear"] for r in tools]
        cov75 = [r["coverage"] >= 0.75 for r in tools]
        out[p] = {
            "splits": len(fs),
            **{
                k: {
                    "median": float(np.median([m[k] for m in ms])),
                    "min": float(np.min([m[k] for m in ms])),
                    "max": float(np.max([m[k] for m in ms])),
                }
                for k in keys
            },
            "pooled": pooled,
            "tools_beat_linear": float(np.mean(beat)),
            "tools_cov75": float(np.mean(cov75)),
            "n_configs": fs[0].n_configs,
            "chosen": dict(
                sorted(
                    {c: sum(f.chosen == c for f in fs) for c in {f.chosen for f in fs}}.items(),
                    key=lambda kv: (-kv[1], kv[0]),  # ties by name: the same bytes every run
                )
            ),
            # the prior rate's rule per fold (revision 4) and the law's exponent: how
            # often the training tools' own slope left the physical range (the Taylor-
            # type law's folds only: revision 5's b is one of its grid, no raw slope),
            # and how often revision 5's b was the fallback 0 (too few knot intervals)
            "rate_laws": {
                law: sum(f.rate_law == law for f in fs) for law in sorted({f.rate_law for f in fs})
            },
            "rate_b": [f.rate_b for f in fs],
            "rate_b_raw": [f.rate_b_raw for f in fs],
            "rate_b_out_of_range": sum(
                1
                for f in fs
                if f.rate_law != "segment"
                and not (math.isfinite(f.rate_b_raw) and f.rate_b_raw == f.rate_b)
            ),
            "rate_b_fallback": sum(f.rate_b_fallback for f in fs),
        }
        if p == "loto":
            out[p]["per_tool"] = tools
            gs: dict[str, list[dict[str, Any]]] = {}
            for t in tools:
                if groups is not None and t["tool"] in groups:
                    gs.setdefault(groups[t["tool"]], []).append(t)
            out[p]["groups"] = {
                g: {
                    "tools": [t["tool"] for t in members],
                    **{
                        k: float(np.mean([t[k] for t in members]))
                        for k in ("mae", *(f"mae_{b}" for b in BASELINES))
                    },
                }
                for g, members in gs.items()
            }
            lives = [t["life"].get("300", t["life"].get("150")) for t in tools if t["life"]]
            out[p]["life_error"] = float(np.median(lives)) if lives else math.nan
            out[p]["life_tools"] = len(lives)
            parts = [t["life_parts"] for t in tools if t["life_parts"]]
            out[p]["life_parts"] = {
                k: float(np.median([x[k] for x in parts])) for k in (parts[0] if parts else {})
            }
            out[p]["entry_record"] = float(np.mean([t["entry"]["record"] for t in tools]))
            out[p]["entry_no_record"] = float(np.mean([t["entry"]["no_record"] for t in tools]))
    return out


__all__ = [
    "BASELINES",
    "SETS",
    "SPEED",
    "FoldResult",
    "ToolResult",
    "condition_groups",
    "evaluate",
    "fold_metrics",
    "knots",
    "life_parts",
    "load",
    "outer_splits",
    "per_tool",
    "run_fold",
    "summarise",
    "tool_data",
]
