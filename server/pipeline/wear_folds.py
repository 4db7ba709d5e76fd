"""Flank wear on held-out tools: folds, metrics and the two baselines.

One fold fits :mod:`estimators.wear.turning` on the training tools and estimates each
test tool; the baselines are fitted on the same training rows: a straight line of VB on
the signal's ``_MEAN`` (the first thing a data scientist tries) and scikit-learn's
gradient boosting on the signal's five features (a learned model one would pick).
Remaining life is in **segments** (the table has no cutting time).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NotRequired, TypedDict

import numpy as np

from common.arrays import F64
from estimators.wear.turning import (
    ToolSeries,
    TurningWearModel,
    TurningWearParams,
    WearEstimate,
    clean_condition,
    estimate,
    fit,
)
from server.records.wear_table import FEED, SIGNALS, VB, WearTable, signal_columns

#: seed of the gradient-boosting baseline
GBR_SEED = 18


def series_of(table: WearTable, signal: str, tool: int) -> tuple[ToolSeries, int]:
    """One tool's series for a signal, and how many feed-rate glitches were replaced."""
    y = table.column(f"{SIGNALS[signal]}_MEAN", tool)
    feed, n_bad = clean_condition(table.column(FEED, tool))
    vb = table.column(VB, tool) if table.has_vb else None
    return ToolSeries(tool=tool, y=y, feed=feed, vb=vb), n_bad


def _features(table: WearTable, signal: str, tools: Sequence[int]) -> tuple[F64, F64]:
    cols = signal_columns(signal)
    rows = np.concatenate([table.rows_of(t) for t in tools])
    X = np.column_stack([table.columns[c][rows] for c in cols])
    y = table.columns[VB][rows] if table.has_vb else np.full(len(rows), np.nan)
    return X, y


def _linear(X: F64, y: F64, Xt: F64) -> F64:
    """Least-squares line of VB on the first feature (``_MEAN``), applied to ``Xt``."""
    A = np.column_stack([np.ones(len(X)), X[:, 0]])
    c, *_ = np.linalg.lstsq(A, y, rcond=None)
    return np.asarray(c[0] + c[1] * Xt[:, 0], dtype=np.float64)


def baselines(table: WearTable, signal: str, train: Sequence[int], test: int) -> dict[str, F64]:
    """Linear (VB on ``_MEAN``) and gradient-boosting predictions for one test tool."""
    from sklearn.ensemble import GradientBoostingRegressor

    X, y = _features(table, signal, train)
    Xt, _ = _features(table, signal, [test])
    lin = _linear(X, y, Xt)
    gbr = GradientBoostingRegressor(random_state=GBR_SEED).fit(X, y)
    return {"linear": lin, "gbr": np.asarray(gbr.predict(Xt), dtype=np.float64)}


def life_truth(vb: F64, criterion: float) -> F64:
    """True remaining life [segments] at each segment (NaN if the tool never reaches it)."""
    hit = np.flatnonzero(vb >= criterion)
    if not len(hit):
        return np.full(len(vb), np.nan)
    return np.maximum(hit[0] - np.arange(len(vb)), 0).astype(np.float64)


def life_at_half(vb: F64, life: F64, criterion: float) -> float:
    """Relative error of the predicted remaining life at half of the tool's life (NaN if
    the tool does not reach the criterion)."""
    hit = np.flatnonzero(vb >= criterion)
    if not len(hit) or hit[0] < 2:
        return float("nan")
    k = int(hit[0]) // 2
    true = float(hit[0] - k)
    return float((life[k] - true) / true)


class BaselineError(TypedDict):
    """A baseline's errors on one tool [um]."""

    mae: float
    rmse: float


class ToolMetrics(TypedDict):
    """One test tool's numbers; the errors only where the tool has measured wear."""

    tool: int
    segments: int
    feed_glitches_replaced: int
    interval_median_width: float
    mae: NotRequired[float]
    rmse: NotRequired[float]
    coverage: NotRequired[float]
    vb_max: NotRequired[float]
    life_error_at_half: NotRequired[float]
    life_error_at_half_150um: NotRequired[float]
    baselines: NotRequired[dict[str, BaselineError]]


class BaselineOverall(TypedDict):
    """A baseline's pooled errors, and on how many tools ours is lower."""

    mae: float
    rmse: float
    tools_ours_lower: int


class Overall(TypedDict):
    """The pooled numbers over the tools with measured wear (life: median)."""

    mae: float
    mae_mean_over_tools: float
    rmse: float
    coverage: float
    interval_median_width: float
    life_median_abs_rel_error: float
    life_tools: int
    life150_median_abs_rel_error: float
    life150_tools: int
    baselines: dict[str, BaselineOverall]


class FoldSummary(TypedDict):
    """:func:`summarise`'s result: per tool, and overall when any tool has measured wear."""

    per_tool: list[ToolMetrics]
    overall: NotRequired[Overall]


@dataclass
class ToolResult:
    """One test tool: the estimate and its numbers."""

    tool: int
    estimate: WearEstimate
    vb: F64 | None
    baselines: dict[str, F64] = field(default_factory=dict)
    feed_glitches: int = 0
    life_150: F64 | None = None

    def metrics(self, criterion: float) -> ToolMetrics:
        e = self.estimate
        out: ToolMetrics = {
            "tool": self.tool,
            "segments": len(e.vb),
            "feed_glitches_replaced": self.feed_glitches,
            "interval_median_width": float(np.median(e.vb_hi - e.vb_lo)),
        }
        if self.vb is None:
            return out
        err = e.vb - self.vb
        out["mae"] = float(np.mean(np.abs(err)))
        out["rmse"] = float(np.sqrt(np.mean(err**2)))
        out["coverage"] = float(np.mean((self.vb >= e.vb_lo) & (self.vb <= e.vb_hi)))
        out["vb_max"] = float(np.max(self.vb))
        out["life_error_at_half"] = life_at_half(self.vb, e.life_left, criterion)
        if self.life_150 is not None:
            out["life_error_at_half_150um"] = life_at_half(self.vb, self.life_150, 150.0)
        out["baselines"] = {
            k: {
                "mae": float(np.mean(np.abs(v - self.vb))),
                "rmse": float(np.sqrt(np.mean((v - self.vb) ** 2))),
            }
            for k, v in self.baselines.items()
        }
        return out


def run_fold(
    table: WearTable,
    signal: str,
    train: Sequence[int],
    test: Sequence[int],
    *,
    criterion: float = 300.0,
    model: TurningWearModel | None = None,
    with_baselines: bool = True,
    params: TurningWearParams | None = None,
    life: bool = True,
) -> tuple[TurningWearModel, list[ToolResult]]:
    """Fit on ``train`` (unless ``model`` is given) and estimate every tool of ``test``
    (``life=False``: no remaining life, faster)."""
    p = params or TurningWearParams()
    if model is None:
        model = fit([series_of(table, signal, t)[0] for t in train], signal, p)
    results = []
    for t in test:
        s, n_bad = series_of(table, signal, t)
        est = estimate(model, s, p, criterion=criterion, life=life)
        life150 = None
        if life and s.vb is not None and criterion != 150.0:
            from estimators.wear.turning import life_from

            life150 = life_from(est.vb, est.rate, 150.0, model.lam)
        base = baselines(table, signal, train, t) if with_baselines and table.has_vb else {}
        results.append(ToolResult(t, est, s.vb, base, n_bad, life150))
    return model, results


def _life_errors(per: list[ToolMetrics], at_150um: bool) -> list[float]:
    """The tools' absolute life errors at half life: a predicted life of "never" (inf) is
    a miss and counts; NaN (criterion not reached) and no measured wear do not."""
    errs = []
    for m in per:
        e = m.get("life_error_at_half_150um") if at_150um else m.get("life_error_at_half")
        if e is not None and not np.isnan(e):
            errs.append(abs(e))
    return errs


def summarise(results: Sequence[ToolResult], criterion: float) -> FoldSummary:
    """Per-tool metrics and the overall ones (pooled over segments; life: median)."""
    per = [r.metrics(criterion) for r in results]
    out: FoldSummary = {"per_tool": per}
    have = [r for r in results if r.vb is not None]
    if not have:
        return out
    vb = np.concatenate([r.vb for r in have if r.vb is not None])
    est = np.concatenate([r.estimate.vb for r in have])
    lo = np.concatenate([r.estimate.vb_lo for r in have])
    hi = np.concatenate([r.estimate.vb_hi for r in have])
    life = _life_errors(per, False)
    life150 = _life_errors(per, True)
    ov: Overall = {
        "mae": float(np.mean(np.abs(est - vb))),
        "mae_mean_over_tools": float(np.mean([m["mae"] for m in per])),
        "rmse": float(np.sqrt(np.mean((est - vb) ** 2))),
        "coverage": float(np.mean((vb >= lo) & (vb <= hi))),
        "interval_median_width": float(np.median(hi - lo)),
        "life_median_abs_rel_error": float(np.median(life)) if life else float("nan"),
        "life_tools": len(life),
        "life150_median_abs_rel_error": float(np.median(life150)) if life150 else float("nan"),
        "life150_tools": len(life150),
        "baselines": {},
    }
    names = sorted({k for r in have for k in r.baselines})
    for n in names:
        pred = np.concatenate([r.baselines[n] for r in have])
        ov["baselines"][n] = {
            "mae": float(np.mean(np.abs(pred - vb))),
            "rmse": float(np.sqrt(np.mean((pred - vb) ** 2))),
            "tools_ours_lower": int(
                sum(m["mae"] < m["baselines"][n]["mae"] for m in per if "baselines" in m)
            ),
        }
    out["overall"] = ov
    return out


def leave_one_out(
    table: WearTable,
    signal: str,
    tools: Sequence[int],
    *,
    criterion: float = 300.0,
    with_baselines: bool = True,
    progress: Callable[[int], None] | None = None,
) -> list[ToolResult]:
    """Each tool estimated by a model fitted on the others."""
    out = []
    for t in tools:
        train = [s for s in tools if s != t]
        _, res = run_fold(
            table, signal, train, [t], criterion=criterion, with_baselines=with_baselines
        )
        out.extend(res)
        if progress is not None:
            progress(1)
    return out


def learning_curve(
    table: WearTable,
    signal: str,
    tools: Sequence[int],
    sizes: Sequence[int] = (1, 2, 4, 8),
    draws: int = 5,
    seed: int = 18,
    progress: Callable[[int], None] | None = None,
) -> dict[int, dict[str, float]]:
    """MAE on the tools left out against the number of training tools (random draws).

    Returns per size the median over draws of our MAE and the linear baseline's (a model
    with one training tool has no interval calibration: its scale is 1).
    """
    rng = np.random.default_rng(seed)
    out: dict[int, dict[str, float]] = {}
    for n in sizes:
        if n >= len(tools):
            continue
        ours, lin = [], []
        for _ in range(draws):
            train = sorted(int(x) for x in rng.choice(list(tools), size=n, replace=False))
            test = [t for t in tools if t not in train]
            _, res = run_fold(table, signal, train, test, with_baselines=False, life=False)
            vb = np.concatenate([r.vb for r in res if r.vb is not None])
            est = np.concatenate([r.estimate.vb for r in res])
            ours.append(float(np.mean(np.abs(est - vb))))
            X, y = _features(table, signal, train)
            Xt, yt = _features(table, signal, test)
            lin.append(float(np.mean(np.abs(_linear(X, y, Xt) - yt))))
            if progress is not None:
                progress(1)
        out[n] = {"mae": float(np.median(ours)), "linear_mae": float(np.median(lin))}
    return out


__all__ = [
    "GBR_SEED",
    "ToolResult",
    "baselines",
    "learning_curve",
    "leave_one_out",
    "life_at_half",
    "life_truth",
    "run_fold",
    "series_of",
    "summarise",
]
