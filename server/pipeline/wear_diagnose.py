"""Why the remaining wear targets are missed: a diagnosis after the results (issue 35,
docs/turning-wear.md, "Why the remaining targets are missed").

Nothing here selects a model or changes a choice. Leave one tool out under the
default protocol (revision 4: revision 3's 36 configurations, the prior rate's rule
chosen in each fold), each held-out tool's estimate by its fold's chosen configuration
beside the line on one ``_MEAN``, gradient boosting on the signal's five features
(``gbr5``) and the same boosting on the ``_MEAN`` alone (``gbr_mean``); then:

- **what the measurement knots allow**: VB is measured at 4-9 points per tool and
  interpolated linearly in the file. Each method's MAE is given on all rows, at the
  knots, against a smooth monotone curve through the same knots (PCHIP) instead of the
  straight lines, and as a lower bound over every monotone VB through the knots (the
  distance of the estimate to the band ``[VB(a), VB(b)]`` between its knots, 0 inside
  it): the part of the error that no reading of VB between the knots can remove.
- **what the signal carries**: each method's map fitted on the held-out tool itself
  (in-sample, the tool's own VB: an upper bound on what that map structure can get from
  that tool's signal, not an estimate), and each tool's share of the pooled MAE.
- per tool, the signal's range over the life (5-95 %) and how much of the tool's VB a
  line in its ``_MEAN`` explains (R^2), and in its five features (linear, in-sample).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from common.arrays import F64
from estimators.wear.hybrid import (
    RATE_LAWS,
    HybridConfig,
    ToolData,
    candidates,
    fit,
    knots,
)
from server.pipeline.wear_nested import SETS, FoldResult, _Cache, run_fold, tool_data
from server.records.wear_table import FEATURES, VB, WearTable

#: the methods compared: ours (the hybrid), its map alone (the chosen configuration's
#: measurement, before the filter), the line on one ``_MEAN``, gradient boosting on the
#: five features and on the ``_MEAN`` alone
METHODS = ("ours", "ours_map", "linear", "gbr5", "gbr_mean")
#: the signal's range over a life: between these quantiles
RANGE_Q = (0.05, 0.95)


def loto_folds(
    table: WearTable,
    set_name: str,
    tools: Sequence[int] | None = None,
    *,
    configs: Sequence[HybridConfig] | None = None,
    rate_laws: Sequence[str] = RATE_LAWS,
    progress: Callable[[int], Any] | None = None,
) -> list[FoldResult]:
    """Leave each of ``tools`` (default: every tool) out in turn, under the default
    protocol (revision 4: ``candidates(revision=4)``, both prior-rate rules)."""
    cfgs = list(configs) if configs is not None else candidates(revision=4)
    cache = _Cache()
    out = []
    for t in tools if tools is not None else table.tools:
        out.append(
            run_fold(table, set_name, (t,), "loto", cache, configs=cfgs, rate_laws=rate_laws)
        )
        if progress is not None:
            progress(1)
    return out


def chosen_config(fold: FoldResult, configs: Sequence[HybridConfig]) -> HybridConfig:
    """The configuration a fold chose, from its label (``.../life=METHOD``)."""
    label = fold.chosen.rsplit("/life=", 1)[0]
    for c in configs:
        c = replace(c, rate_law=fold.rate_law)
        if c.label == label:
            return c
    raise KeyError(f"fold {fold.test}: chosen {fold.chosen!r} is not among the configurations")


def _gbr(X: F64, y: F64, Xt: F64) -> F64:
    from sklearn.ensemble import GradientBoostingRegressor

    return np.asarray(
        GradientBoostingRegressor(random_state=0).fit(X, y).predict(Xt), dtype=np.float64
    )


def _line(x: F64, y: F64, xt: F64) -> F64:
    A = np.column_stack([np.ones(len(x)), x])
    c, *_ = np.linalg.lstsq(A, y, rcond=None)
    return np.asarray(c[0] + c[1] * xt, dtype=np.float64)


def gbr_mean(table: WearTable, signal: str, train: Sequence[int], test: int) -> F64:
    """Gradient boosting (scikit-learn defaults, ``random_state=0``) on the ``_MEAN``
    alone, fitted on the training tools' rows: how much of ``gbr5``'s lead is its other
    four features."""
    tr = np.concatenate([table.rows_of(t) for t in train])
    col = table.columns[f"{signal}_MEAN"]
    return _gbr(
        col[tr][:, None], table.columns[VB][tr], table.column(f"{signal}_MEAN", test)[:, None]
    )


def interpolation(vb: F64) -> dict[str, F64]:
    """What the knots allow: the knots, a smooth monotone curve through them (PCHIP)
    and the band ``[lo, hi]`` every monotone VB through the knots lies in."""
    from scipy.interpolate import PchipInterpolator

    kn = knots(vb)
    k = np.arange(len(vb), dtype=np.float64)
    pchip = np.asarray(PchipInterpolator(kn, vb[kn])(k), dtype=np.float64)
    j = np.clip(np.searchsorted(kn, k, side="right") - 1, 0, len(kn) - 1)
    nxt = np.minimum(j + 1, len(kn) - 1)
    a, b = vb[kn[j]], vb[kn[nxt]]
    on = np.isin(np.arange(len(vb)), kn)
    lo = np.where(on, vb, np.minimum(a, b))
    hi = np.where(on, vb, np.maximum(a, b))
    return {"knots": kn.astype(np.float64), "pchip": pchip, "lo": lo, "hi": hi}


def oracle(
    table: WearTable, set_name: str, d: ToolData, cfg: HybridConfig | None
) -> dict[str, F64]:
    """Each method's map fitted on the tool itself (its own VB, in-sample) and run on
    it: an upper bound on what that map structure gets from this tool's signal. Ours:
    the fold's chosen configuration, fitted on the tool alone (the tool twice: the fit
    wants two tools; least squares, isotonic and boosting see the same rows), its prior
    rate the tool's own, entering with its record."""
    assert d.vb is not None
    s0 = SETS[set_name][0]
    x = table.column(f"{s0}_MEAN", d.tool)
    X5 = np.column_stack([table.column(f"{s0}_{f}", d.tool) for f in FEATURES])
    out = {
        "linear": _line(x, d.vb, x),
        "gbr5": _gbr(X5, d.vb, X5),
        "gbr_mean": _gbr(x[:, None], d.vb, x[:, None]),
    }
    if cfg is not None:
        ref = None
        if cfg.reference == "conditions":  # one tool: a flat level (removed by scaling)
            xs = d.x_all if (cfg.features == "five" and d.x_all is not None) else d.x
            ref = np.vstack([np.median(xs, axis=0), np.zeros(xs.shape[1])])
        m = fit([d, d], cfg, ref_level=ref)
        out["ours"] = m.run(d)[0]
        out["ours_map"] = m.measure(m.inputs(d), d.feed)
    return out


def shared_oracle(
    table: WearTable,
    set_name: str,
    tools: Sequence[int],
    cfgs: dict[int, HybridConfig | None],
) -> dict[int, dict[str, F64]]:
    """Each method's map fitted on *every* tool of the table at once, the held-out
    ``tools`` included (in-sample across tools): what one map shared by the tools can do
    at best; its gap to the per-tool oracle is the tools' disagreement. Ours: each
    fold's chosen configuration fitted on all of them and run on that fold's tool."""
    s0 = SETS[set_name][0]
    every = list(table.tools)
    rows = np.concatenate([table.rows_of(t) for t in every])
    y = table.columns[VB][rows]
    x = table.columns[f"{s0}_MEAN"]
    X5 = np.column_stack([table.columns[f"{s0}_{f}"] for f in FEATURES])
    from sklearn.ensemble import GradientBoostingRegressor

    g5 = GradientBoostingRegressor(random_state=0).fit(X5[rows], y)
    g1 = GradientBoostingRegressor(random_state=0).fit(x[rows][:, None], y)
    data = {t: tool_data(table, SETS[set_name], t) for t in every}
    fits: dict[str, Any] = {}
    out: dict[int, dict[str, F64]] = {}
    for t in tools:
        r = table.rows_of(t)
        o = {
            "linear": _line(x[rows], y, x[r]),
            "gbr5": np.asarray(g5.predict(X5[r]), dtype=np.float64),
            "gbr_mean": np.asarray(g1.predict(x[r][:, None]), dtype=np.float64),
        }
        c = cfgs.get(t)
        if c is not None:
            if c.label not in fits:
                fits[c.label] = fit([data[u] for u in every], c)
            o["ours"] = fits[c.label].run(data[t])[0]
            o["ours_map"] = fits[c.label].measure(fits[c.label].inputs(data[t]), data[t].feed)
        out[t] = o
    return out


def _r2(y: F64, p: F64) -> float:
    ss = float(np.sum((y - y.mean()) ** 2))
    return 1.0 - float(np.sum((y - p) ** 2)) / ss if ss > 0 else math.nan


def held_out(
    table: WearTable, set_name: str, fold: FoldResult, tool: int, cfg: HybridConfig | None
) -> tuple[dict[str, F64], F64 | None]:
    """One of a fold's test tools, each method fitted on the fold's training tools:
    ours (the fold's estimate), its map alone (``cfg`` refitted: the fit is
    deterministic), the line, ``gbr5`` and ``gbr_mean``; and, when ``cfg`` has the
    tool-offset state, the same configuration without it (the mechanism's check, not a
    choice; else None)."""
    r = next(x for x in fold.tools if x.tool == tool)
    train = [t for t in table.tools if t not in fold.test]
    d = tool_data(table, SETS[set_name], tool)
    est = {"ours": r.est}
    no_offset: F64 | None = None
    if cfg is not None:
        dtrain = [tool_data(table, SETS[set_name], t) for t in train]
        fm = fit(dtrain, cfg)
        est["ours_map"] = fm.measure(fm.inputs(d), d.feed)
        if cfg.offset:
            no_offset = fit(dtrain, replace(cfg, offset=False)).run(d)[0]
    est |= {
        "linear": r.base["linear"],
        "gbr5": r.base["gbr5"],
        "gbr_mean": gbr_mean(table, SETS[set_name][0], train, tool),
    }
    return est, no_offset


#: what :func:`split_ratios` measures per split: ours / linear on all rows, at the knots
#: (all, inside the lives, the two ends), against PCHIP and the monotone lower bound
SPLIT_KEYS = ("mae", "mae_knots", "mae_inner_knots", "mae_ends", "mae_pchip", "mae_lb")


def split_ratios(
    table: WearTable,
    set_name: str,
    fold: FoldResult,
    configs: Sequence[HybridConfig],
) -> dict[str, float]:
    """One outer split (any number of test tools), pooled over its test tools: each
    method's MAE measured every way of :data:`SPLIT_KEYS`, and ours / linear for each."""
    cfg = chosen_config(fold, configs)
    sums: dict[str, dict[str, float]] = {}
    n = dict.fromkeys(SPLIT_KEYS, 0)
    for r in fold.tools:
        est, _ = held_out(table, set_name, fold, r.tool, cfg)
        ip = interpolation(r.vb)
        kn = ip["knots"].astype(int)
        rows = np.arange(len(r.vb))
        parts = {"mae": rows, "mae_knots": kn, "mae_inner_knots": kn[1:-1],
                 "mae_ends": kn[[0, -1]], "mae_pchip": rows, "mae_lb": rows}  # fmt: skip
        for k, idx in parts.items():
            n[k] += len(idx)
        for m, e in est.items():
            err = np.abs(e - r.vb)
            gap = np.maximum(ip["lo"] - e, 0.0) + np.maximum(e - ip["hi"], 0.0)
            per = {k: err[idx] for k, idx in parts.items()}
            per["mae_pchip"] = np.abs(e - ip["pchip"])
            per["mae_lb"] = gap
            acc = sums.setdefault(m, dict.fromkeys(SPLIT_KEYS, 0.0))
            for k, v in per.items():
                acc[k] += float(np.sum(v))
    out = {f"{m}_{k}": v / n[k] for m, acc in sums.items() for k, v in acc.items()}
    for k in SPLIT_KEYS:
        out[f"ratio_{k}"] = out[f"ours_{k}"] / out[f"linear_{k}"]
    for m in sums:  # (2): every method on all rows against boosting on five features
        out[f"{m}_to_gbr5"] = out[f"{m}_mae"] / out["gbr5_mae"]
    return out


def spread(
    table: WearTable,
    set_name: str,
    folds: Sequence[FoldResult],
    configs: Sequence[HybridConfig] | None = None,
) -> dict[str, dict[str, dict[str, float]]]:
    """Per protocol (``loto``, ``l2o``, ...): the median and range over its splits of
    every :func:`split_ratios` number."""
    cfgs = list(configs) if configs is not None else candidates(revision=4)
    per: dict[str, list[dict[str, float]]] = {}
    for f in folds:
        per.setdefault(f.protocol, []).append(split_ratios(table, set_name, f, cfgs))
    return {
        p: {
            k: {
                "median": float(np.median([m[k] for m in ms])),
                "min": float(np.min([m[k] for m in ms])),
                "max": float(np.max([m[k] for m in ms])),
                "splits": float(len(ms)),
            }
            for k in ms[0]
        }
        for p, ms in per.items()
    }


def spread_text(sp: dict[str, dict[str, dict[str, float]]], set_name: str) -> str:
    """The ratio ours / linear per split, median (range), every way it is measured."""
    lines = [
        f"[{set_name}] ours / linear per split, median (range) over the splits: "
        + ", ".join(k.replace("mae_", "").replace("mae", "all rows") for k in SPLIT_KEYS)
    ]
    for p, v in sp.items():
        cells = [
            f"{v[f'ratio_{k}']['median']:.3f} ({v[f'ratio_{k}']['min']:.2f}-"
            f"{v[f'ratio_{k}']['max']:.2f})"
            for k in SPLIT_KEYS
        ]
        lines.append(f"  {p} ({int(v['ratio_mae']['splits'])} splits): " + "; ".join(cells))
        to = [
            f"{m} {v[f'{m}_to_gbr5']['median']:.3f} ({v[f'{m}_to_gbr5']['min']:.2f}-"
            f"{v[f'{m}_to_gbr5']['max']:.2f})"
            for m in METHODS
            if f"{m}_to_gbr5" in v and m != "gbr5"
        ]
        lines.append("      all rows / gbr5: " + "; ".join(to))
    return "\n".join(lines)


def tool_diagnosis(
    table: WearTable,
    set_name: str,
    fold: FoldResult,
    configs: Sequence[HybridConfig] | None,
    shared: dict[str, F64] | None = None,
) -> dict[str, Any]:
    """One held-out tool: per method the MAE on all rows, at the knots, against the
    PCHIP curve, the lower bound over monotone VB, and the in-sample oracle; the
    signal's range and R^2 over the tool's life; the estimates (for the figure)."""
    r = fold.tools[0]
    s0 = SETS[set_name][0]
    d = tool_data(table, SETS[set_name], r.tool)
    cfg = chosen_config(fold, configs) if configs is not None else None
    est, no_offset = held_out(table, set_name, fold, r.tool, cfg)
    vb = r.vb
    ip = interpolation(vb)
    kn = ip["knots"].astype(int)
    orc = oracle(table, set_name, d, cfg)
    x = table.column(f"{s0}_MEAN", r.tool)
    X5 = np.column_stack([table.column(f"{s0}_{f}", r.tool) for f in FEATURES])
    A5 = np.column_stack([np.ones(len(vb)), X5])
    c5, *_ = np.linalg.lstsq(A5, vb, rcond=None)
    c1, *_ = np.linalg.lstsq(np.column_stack([np.ones(len(vb)), x]), vb, rcond=None)
    # no signal, the tool's own VB: its first VB and its own mean rate per segment
    own = vb[0] + (vb[-1] - vb[0]) / max(len(vb) - 1, 1) * np.arange(len(vb))
    q = np.quantile(x, RANGE_Q)
    row: dict[str, Any] = {
        "tool": r.tool,
        "rows": len(vb),
        "knots": len(kn),
        "chosen": fold.chosen,
        "vb_first": float(vb[0]),
        "vb_last": float(vb[-1]),
        "signal": s0,
        "signal_range": float(q[1] - q[0]),
        "signal_lo": float(q[0]),
        "signal_hi": float(q[1]),
        "r2_mean": _r2(vb, _line(x, vb, x)),
        "r2_five_linear": _r2(vb, A5 @ c5),
        "line_intercept": float(c1[0]),
        "line_slope": float(c1[1]),
        "own_rate_oracle": float(np.mean(np.abs(own - vb))),
        "interp_pchip_gap": float(np.mean(np.abs(vb - ip["pchip"]))),
        "interp_band": float(np.mean(ip["hi"] - ip["lo"])),
    }
    for m, e in est.items():
        err = np.abs(e - vb)
        row[f"{m}_sum"] = float(np.sum(err))
        row[f"{m}_mae"] = float(np.mean(err))
        row[f"{m}_bias"] = float(np.mean(e - vb))
        row[f"{m}_mae_knots"] = float(np.mean(err[kn]))
        # the knots inside the life, and its two ends (first and last row: the extremes
        # of VB, where a map that regresses to the mean misses most)
        row[f"{m}_inner_sum"] = float(np.sum(err[kn[1:-1]]))
        row[f"{m}_ends_sum"] = float(err[kn[0]] + err[kn[-1]])
        row[f"{m}_mae_pchip"] = float(np.mean(np.abs(e - ip["pchip"])))
        gap = np.maximum(ip["lo"] - e, 0.0) + np.maximum(e - ip["hi"], 0.0)
        row[f"{m}_mae_lb"] = float(np.mean(gap))
        row[f"{m}_lb_sum"] = float(np.sum(gap))
        if m in orc:
            row[f"{m}_oracle"] = float(np.mean(np.abs(orc[m] - vb)))
        if shared is not None and m in shared:
            row[f"{m}_shared"] = float(np.mean(np.abs(shared[m] - vb)))
    if no_offset is not None:
        row["ours_without_offset_mae"] = float(np.mean(np.abs(no_offset - vb)))
        row["ours_without_offset_bias"] = float(np.mean(no_offset - vb))
    row["series"] = {"vb": vb.tolist(), **{m: e.tolist() for m, e in est.items()}}
    return row


def diagnose(
    table: WearTable,
    set_name: str,
    folds: Sequence[FoldResult],
    configs: Sequence[HybridConfig] | None = None,
) -> dict[str, Any]:
    """Per tool and pooled (every row of every held-out tool counted once)."""
    cfgs = list(configs) if configs is not None else candidates(revision=4)
    held = [f.tools[0].tool for f in folds]
    sh = shared_oracle(
        table, set_name, held, {f.tools[0].tool: chosen_config(f, cfgs) for f in folds}
    )
    tools = [tool_diagnosis(table, set_name, f, cfgs, sh[f.tools[0].tool]) for f in folds]
    n = sum(t["rows"] for t in tools)
    nk = sum(t["knots"] for t in tools)
    pooled: dict[str, float] = {"rows": float(n), "knots": float(nk)}
    for m in METHODS:
        pooled[f"{m}_mae"] = sum(t[f"{m}_sum"] for t in tools) / n
        pooled[f"{m}_mae_knots"] = sum(t[f"{m}_mae_knots"] * t["knots"] for t in tools) / nk
        pooled[f"{m}_mae_inner_knots"] = sum(t[f"{m}_inner_sum"] for t in tools) / (
            nk - 2 * len(tools)
        )
        pooled[f"{m}_mae_ends"] = sum(t[f"{m}_ends_sum"] for t in tools) / (2 * len(tools))
        pooled[f"{m}_mae_pchip"] = sum(t[f"{m}_mae_pchip"] * t["rows"] for t in tools) / n
        pooled[f"{m}_mae_lb"] = sum(t[f"{m}_lb_sum"] for t in tools) / n
        for k in ("oracle", "shared"):
            if all(f"{m}_{k}" in t for t in tools):
                pooled[f"{m}_{k}"] = sum(t[f"{m}_{k}"] * t["rows"] for t in tools) / n
        for t in tools:  # the tool's share of the pooled MAE [um]
            t[f"{m}_share"] = t[f"{m}_sum"] / n
    pooled["interp_pchip_gap"] = sum(t["interp_pchip_gap"] * t["rows"] for t in tools) / n
    pooled["interp_band"] = sum(t["interp_band"] * t["rows"] for t in tools) / n
    pooled["own_rate_oracle"] = sum(t["own_rate_oracle"] * t["rows"] for t in tools) / n
    slopes = np.array([t["line_slope"] for t in tools])
    pooled["line_slope_median"] = float(np.median(slopes))
    pooled["line_slope_min"] = float(np.min(slopes))
    pooled["line_slope_max"] = float(np.max(slopes))
    lin = pooled["linear_mae"]
    ratios = {
        k: pooled[f"ours_{k}"] / pooled[f"linear_{k}"]
        for k in (
            "mae",
            "mae_knots",
            "mae_inner_knots",
            "mae_ends",
            "mae_pchip",
            "mae_lb",
            "shared",
            "oracle",
        )
        if f"ours_{k}" in pooled and pooled.get(f"linear_{k}", 0.0) > 0
    }
    return {
        "set": set_name,
        "protocol": "leave one tool out, revision 4 (the default)",
        "tools": tools,
        "pooled": pooled,
        "ratio_to_linear": ratios,
        "beats_linear": sum(t["ours_mae"] < t["linear_mae"] for t in tools),
        "linear_mae": lin,
    }


def text(diag: dict[str, Any]) -> str:
    """The diagnosis as printed tables."""
    p = diag["pooled"]
    nan = math.nan
    lines = [
        f"[{diag['set']}] {diag['protocol']}; MAE in um, {int(p['rows'])} rows, "
        f"{int(p['knots'])} measured VB points (knots)",
        "method     held out: all rows  at knots (inner / ends)  vs PCHIP  monotone lower "
        "bound | in-sample: one map for all tools  each tool its own map",
    ]
    for m in METHODS:
        lines.append(
            f"{m:<10} {p[f'{m}_mae']:18.1f}  {p[f'{m}_mae_knots']:8.1f} "
            f"({p[f'{m}_mae_inner_knots']:5.1f} / {p[f'{m}_mae_ends']:5.1f})  "
            f"{p[f'{m}_mae_pchip']:8.1f}  {p[f'{m}_mae_lb']:20.1f} | "
            f"{p.get(f'{m}_shared', nan):31.1f}  {p.get(f'{m}_oracle', nan):20.1f}"
        )
    lines.append(
        "ours / linear: "
        + ", ".join(f"{k} {v:.3f}" for k, v in diag["ratio_to_linear"].items())
        + " (target 0.75)"
    )
    lines.append(
        f"interpolation: |straight line - PCHIP| {p['interp_pchip_gap']:.1f} um on average; "
        f"band a monotone VB could take between knots {p['interp_band']:.1f} um wide on "
        f"average. No signal, each tool's own first VB and mean rate: "
        f"{p['own_rate_oracle']:.1f} um. Line of VB on {diag['tools'][0]['signal']}_MEAN "
        f"within each tool: slope {p['line_slope_median']:.3g} um per unit (median; "
        f"{p['line_slope_min']:.3g} to {p['line_slope_max']:.3g})"
    )
    lines.append(
        f"per tool ({diag['beats_linear']} of {len(diag['tools'])} below the line): MAE and "
        "share of the pooled MAE [um] ours / linear / gbr5 / gbr_mean; own-map oracle ours / "
        "linear; signal range 5-95 %; R^2 of VB on _MEAN / five features (in-sample); slope"
    )
    for t in diag["tools"]:
        lines.append(
            f"  tool {t['tool']:>2}: MAE {t['ours_mae']:5.1f} / {t['linear_mae']:5.1f} / "
            f"{t['gbr5_mae']:5.1f} / {t['gbr_mean_mae']:5.1f}  share "
            f"{t['ours_share']:4.1f} / {t['linear_share']:4.1f} / {t['gbr5_share']:4.1f} / "
            f"{t['gbr_mean_share']:4.1f}  oracle {t.get('ours_oracle', nan):5.1f} / "
            f"{t['linear_oracle']:5.1f}  range {t['signal_range']:6.1f}  "
            f"R^2 {t['r2_mean']:.2f} / {t['r2_five_linear']:.2f}  slope {t['line_slope']:.3g}  "
            f"VB {t['vb_first']:.0f}-{t['vb_last']:.0f}, {t['knots']} knots"
        )
    for t in diag["tools"]:
        if "ours_without_offset_mae" in t:
            lines.append(
                f"  tool {t['tool']:>2}: its fold chose the tool-offset state; the same "
                f"configuration without it (a check of the mechanism, not a choice): MAE "
                f"{t['ours_without_offset_mae']:.1f} um, bias "
                f"{t['ours_without_offset_bias']:+.1f} (with it {t['ours_mae']:.1f}, "
                f"{t['ours_bias']:+.1f})"
            )
    return "\n".join(lines)


def figure(diags: Sequence[dict[str, Any]], path: Any) -> None:
    """Per-tool MAE bars (ours, linear, gbr5, gbr_mean, and ours' in-sample oracle), one
    panel per signal set; each tool's lower bound over monotone VB as a tick."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(diags), 1, figsize=(11.5, 3.4 * len(diags)), squeeze=False)
    cols = {"ours": "C0", "ours_map": "C9", "linear": "C1", "gbr5": "C2", "gbr_mean": "C4"}
    for ax, dg in zip(axes[:, 0], diags, strict=True):
        tools = dg["tools"]
        x = np.arange(len(tools))
        w = 0.12
        for i, m in enumerate(METHODS):
            ax.bar(x + (i - 3) * w, [t[f"{m}_mae"] for t in tools], w, color=cols[m], label=m)
            ax.plot(x + (i - 3) * w, [t[f"{m}_mae_lb"] for t in tools], "_", color="k", ms=5)
        for j, (k, lab, h) in enumerate(
            (
                ("shared", "ours, one map fitted on all nine tools", ".."),
                ("oracle", "ours, fitted on the tool itself", "//"),
            )
        ):
            ax.bar(
                x + (2 + j) * w,
                [t.get(f"ours_{k}", math.nan) for t in tools],
                w,
                color="white",
                edgecolor="C0",
                hatch=h,
                label=lab,
            )
        ax.set_xticks(x, [f"tool {t['tool']}" for t in tools])
        ax.set_ylabel("MAE [um]")
        p = dg["pooled"]
        ax.set_title(
            f"{dg['set']}, each tool left out (solid) and in-sample (hatched); pooled ours "
            f"{p['ours_mae']:.1f}, linear {p['linear_mae']:.1f}, gbr5 {p['gbr5_mae']:.1f}, "
            f"gbr_mean {p['gbr_mean_mae']:.1f} um\nblack ticks: the error's lower bound over "
            "every monotone VB through the measured points",
            fontsize=8,
        )
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


__all__ = [
    "METHODS",
    "chosen_config",
    "diagnose",
    "figure",
    "gbr_mean",
    "interpolation",
    "loto_folds",
    "oracle",
    "text",
    "tool_diagnosis",
]
