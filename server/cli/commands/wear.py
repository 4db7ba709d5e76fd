"""Flank wear of turning tools from a drive or force signal, on held-out tools.

Examples::

    cutwatch wear ../shared/data/turning-wear/segments.csv --out out/wear
    cutwatch wear segments.csv --signal drive_current --out out/wear_cv3
    cutwatch wear segments.csv --train-tools 6,7,11,14,15 --test-tools 3,10 \\
        --model out/model.json --out out/wear_a
    cutwatch wear other.csv --model out/model.json --out out/wear_b   # model read
    cutwatch wear segments.csv --method hybrid --diagnose --out out/diag  # why missed

Seed 004's adaptive wear observer adapted to one row per cutting segment (see
docs/turning-wear.md): a wear state that only grows, a wear-rate law on the segment
index (the table has no cutting time: rates and lives are per segment), a force-wear
output relation fitted by RLS on the training tools, a fresh-tool reference from each
tool's first 10 segments, the programmed feed rate (CON.G.FREAL, CNC units: only its
ratio to the tool's first segments is used, glitch values replaced by the median of
their neighbours) as the condition input. Default: leave one tool out over every tool.
Writes DIR/estimates.csv (95 % intervals, life in segments), DIR/report.json (per tool
and overall MAE, RMSE, coverage, width, remaining-life error, the linear and
gradient-boosting baselines beside them) and DIR/report.html.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

HELP = "estimate flank wear of turning tools from a drive/force signal (held-out tools)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from server.records.wear_table import SIGNALS

    p.add_argument("table", type=Path, help="CSV table of cutting segments (Latin-1)")
    p.add_argument("--out", metavar="DIR", type=Path, required=True, help="output directory")
    p.add_argument(
        "--signal",
        choices=list(SIGNALS),
        default="feed_force",
        help="feed_force (F_f), drive_torque (TV2.Z) or drive_current (CV3.Z)",
    )
    p.add_argument("--train-tools", metavar="LIST", help="tools to fit on, e.g. 3,5,6")
    p.add_argument(
        "--test-tools",
        metavar="LIST",
        help="tools to estimate (default: leave one tool out over all tools)",
    )
    p.add_argument(
        "--model",
        metavar="FILE",
        type=Path,
        help="fitted model (JSON): written after fitting, or read if it exists and no "
        "--train-tools is given",
    )
    p.add_argument(
        "--criterion",
        metavar="UM",
        type=float,
        default=300.0,
        help="VB limit [um] for the remaining life (ISO 3685 average flank wear, carbide)",
    )
    p.add_argument(
        "--map",
        metavar="COL=EXPR",
        action="append",
        default=[],
        help="column map as in cutwatch residual, e.g. --map F_f_MEAN=Ff_mean*1.0 "
        "(columns: tool, Vb, CON.G.FREAL and the signal's _MEAN/_RMS/_MAX/_SK/_KURT)",
    )
    p.add_argument(
        "--method",
        choices=("observer", "hybrid"),
        default="observer",
        help="observer: issue 18's per-signal observer; hybrid: issue 35's monotone state "
        "with a map learnt across tools, every choice made inside the fold, CV+ intervals",
    )
    p.add_argument(
        "--set",
        dest="signal_set",
        metavar="SET",
        default="F_f",
        help="--method hybrid: the signals read together: F_f, TV2.Z, CV3.Z, TV2.S, "
        "drives (Z/X drive torques and currents, spindle) or all",
    )
    p.add_argument(
        "--first-list",
        action="store_true",
        help="--method hybrid: the protocol's first candidate list (40 configurations, "
        "faster); the same as --revision 1",
    )
    p.add_argument(
        "--revision",
        type=int,
        choices=(1, 2, 3, 4, 5),
        default=None,
        help="--method hybrid: the protocol's candidate list (1: 40, 2: 176, 3: 36 "
        "configurations per signal set; 4: revision 3's 36 with the prior wear rate's "
        "rule, the median at the same conditions or a Taylor-type law in the cutting "
        "speed, chosen in each fold; 5: revision 3's 36 with that law per segment inside the "
        "filter, its exponent from the knot intervals within the training tools; default 4, "
        "see docs/turning-wear.md)",
    )
    p.add_argument(
        "--protocol",
        choices=("loto", "leave-k", "both"),
        default="loto",
        help="--method hybrid without --test-tools: leave one tool out (default), "
        "repeated leave-k-tools-out (k = 2, 3, 4, 5 seeded draws each) or both; each "
        "split's pooled MAE is reported as the median and range over the splits",
    )
    p.add_argument(
        "--k",
        metavar="K,...",
        default=None,
        help="--protocol leave-k or both: only these k of 2, 3, 4 (the same seeded draws "
        "as the full run; e.g. to run k = 4 in a second process)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="--method hybrid: the first split of each protocol only and the first list "
        "without gradient boosting (30 configurations): a check that it runs, not a result",
    )
    p.add_argument(
        "--diagnose",
        action="store_true",
        help="--method hybrid: why the remaining targets are missed (a diagnosis after the "
        "results, nothing chosen by it): the splits of --protocol under the default "
        "protocol; for the tools left out one at a time (each, or each of --test-tools) "
        "per method (ours, its map alone, the line, gradient boosting on five features and "
        "on the _MEAN alone) the MAE on all rows, at the measured VB points, against a "
        "smooth monotone curve through them, its lower bound over every monotone VB "
        "through them, and the maps fitted in-sample; for every split the ratio ours / "
        "linear each of those ways, median (range) per protocol; writes DIR/diagnosis.json "
        "and (leave one out) DIR/diagnosis.png",
    )
    p.add_argument("--no-baselines", action="store_true", help="skip the two baselines")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    import math

    from server.errors import CutwatchError
    from server.records.wear_table import (
        FEED,
        SIGNALS,
        parse_tools,
        read_wear_table,
        signal_columns,
    )

    if not (math.isfinite(args.criterion) and args.criterion > 0):
        raise CutwatchError(f"--criterion {args.criterion}: expected a VB limit > 0 um")
    if args.method != "hybrid":
        for flag, given in (("--diagnose", args.diagnose), ("--quick", args.quick)):
            if given:
                raise CutwatchError(
                    f"{flag}: expected --method hybrid (it diagnoses or shortens the nested "
                    f"evaluation), found --method {args.method}"
                )
    if args.method == "hybrid":
        return _run_hybrid(args)
    table = read_wear_table(args.table, [FEED, *signal_columns(args.signal)], args.map)
    train = parse_tools(args.train_tools, table, "--train-tools")
    test = parse_tools(args.test_tools, table, "--test-tools")
    model = None
    if args.model is not None and args.model.is_file() and train is None:
        model = _read_model(args.model, args.signal)
    if (train is not None or model is not None) and test is None:
        test = [t for t in table.tools if t not in (train or model.train_tools)]  # type: ignore[union-attr]
        if not test:
            raise CutwatchError(
                f"{table.path}: no tool left to test (every tool is a training tool); "
                "pass --test-tools"
            )
    if (train is not None or model is None) and not table.has_vb:
        raise CutwatchError(
            f"{table.path}: column 'Vb': expected measured flank wear to fit on, found none "
            "(give a fitted --model FILE to estimate without it)"
        )
    if train is not None and test is not None and set(train) & set(test):
        raise CutwatchError(
            f"--train-tools and --test-tools share tool(s) {sorted(set(train) & set(test))}"
        )
    results, fitted = _estimate(args, table, train, test, model)
    rep, rows, figs = _report(args, table, results, fitted)
    from server.records.wear_report import verdict, write_report

    write_report(args.out, rep, rows, figs, table.has_vb)
    if args.model is not None and model is None and fitted is not None:
        args.model.parent.mkdir(parents=True, exist_ok=True)
        args.model.write_text(json.dumps(fitted.to_dict(), indent=2) + "\n")
    print(f"{table.path} [{SIGNALS[args.signal]}_MEAN]: {verdict(rep)}")
    print(f"wrote {args.out}/estimates.csv, report.json, report.html")
    return 0


def _run_hybrid(args: argparse.Namespace) -> int:
    """Issue 35's hybrid: each test tool (default: leave one tool out) estimated by the
    configuration its fold chose, with CV+ intervals and the four baselines."""
    import csv

    import numpy as np
    from tqdm import tqdm

    from server.errors import CutwatchError
    from server.pipeline.wear_nested import (
        _Cache,
        condition_groups,
        run_fold,
        summarise,
    )
    from server.records.wear_table import parse_tools

    table = _hybrid_table(args)
    test = parse_tools(args.test_tools, table, "--test-tools")
    if args.diagnose:
        return _run_diagnose(args, table, test)
    if test is not None and args.protocol != "loto":
        raise CutwatchError(
            f"--protocol {args.protocol}: expected no --test-tools (the protocol draws the "
            f"test tools), found --test-tools {args.test_tools}"
        )
    if test is None:
        splits = _hybrid_splits(args, table)
    else:
        splits = [("given", tuple(test))]
    worst = max(len(t) for _, t in splits)
    if len(table.tools) - worst < 3:
        raise CutwatchError(
            f"{table.path}: --method hybrid: expected 3 or more training tools (the choice "
            f"is a leave-one-tool-out over them), found {len(table.tools) - worst}"
        )
    rev, cfgs, laws = _protocol(args)
    cache = _Cache()
    folds = []
    for proto, g in tqdm(splits, desc="wear folds", file=sys.stderr, disable=args.quiet):
        folds.append(
            run_fold(table, args.signal_set, g, proto, cache, configs=cfgs, rate_laws=laws)
        )
    args.out.mkdir(parents=True, exist_ok=True)
    with (args.out / "estimates.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["protocol", "split", "tool", "segment", "vb_true", "vb_est", "vb_lo",
                    "vb_hi", "chosen"])  # fmt: skip
        for fo in folds:
            sp = "+".join(str(t) for t in fo.test)
            for r in fo.tools:
                for k in range(len(r.vb)):
                    w.writerow([fo.protocol, sp, r.tool, k, f"{r.vb[k]:.3f}", f"{r.est[k]:.3f}",
                                f"{r.lo[k]:.3f}", f"{r.hi[k]:.3f}", fo.chosen])  # fmt: skip
    summ = summarise(folds, condition_groups(table))
    rep = {
        "table": str(table.path),
        "method": "hybrid",
        "set": args.signal_set,
        "time_base": "segment index (the table has no cutting time)",
        "interval": "95 % CV+ over the training tools",
        **summ,
    }
    rep["revision"] = "quick (32)" if args.quick else rev
    (args.out / "report.json").write_text(json.dumps(rep, indent=2, default=float) + "\n")
    for proto, v in summ.items():
        po = v["pooled"]
        ratio = po["mae"] / po["mae_linear"] if po["mae_linear"] > 0 else np.nan
        print(
            f"{table.path} [{args.signal_set}, hybrid, {proto}, {v['splits']} splits, "
            f"{v['n_configs']} configurations]: MAE {po['mae']:.1f} um (linear "
            f"{po['mae_linear']:.1f}, ratio {ratio:.2f}; gradient boosting "
            f"{po['mae_gbr5']:.1f}; prior {po['mae_prior']:.1f}); 95 % interval covers "
            f"{100 * po['coverage']:.0f} %"
        )
        if v["splits"] > 1:
            print("  per split, median (range): " + "; ".join(
                f"{k} {v[k]['median']:.3g} ({v[k]['min']:.3g}-{v[k]['max']:.3g})"
                for k in ("mae", "mae_linear", "mae_gbr5", "mae_gbr_same", "mae_prior",
                          "ratio_linear", "ratio_gbr5", "ratio_prior", "coverage", "optimism")
            ))  # fmt: skip
    print(f"wrote {args.out}/estimates.csv, report.json")
    return 0


def _protocol(args: argparse.Namespace) -> tuple[int, list[Any], tuple[str, ...]]:
    """The protocol revision the arguments name (4 by default; 1 with ``--first-list``),
    its candidate configurations (``--quick``: revision 1's list without boosting) and the
    prior rate's rules each fold chooses among."""
    from estimators.wear.hybrid import RATE_LAWS, candidates

    rev = 1 if args.first_list else (args.revision or 4)
    cfgs = candidates(revision=rev)
    if args.quick:
        cfgs = [c for c in candidates(revision=1) if c.map != "gbr"]
    laws = ("segment",) if rev >= 5 else RATE_LAWS if rev == 4 else ("median",)
    return rev, list(cfgs), laws


def _hybrid_splits(args: argparse.Namespace, table: Any) -> list[tuple[str, tuple[int, ...]]]:
    """The outer splits of ``--protocol`` (``--k`` and ``--quick`` applied)."""
    from server.errors import CutwatchError
    from server.pipeline.wear_nested import K_OUT, outer_splits

    splits = outer_splits(table.tools, quick=args.protocol == "loto")
    if args.protocol == "leave-k":
        splits = [sp for sp in splits if sp[0] != "loto"]
    if args.k is not None:
        try:
            ks = {int(x) for x in args.k.split(",") if x.strip()}
        except ValueError:
            ks = set()
        if not ks or not ks <= set(K_OUT):
            raise CutwatchError(
                f"--k: expected a comma list of {', '.join(map(str, K_OUT))}, found {args.k!r}"
            )
        splits = [sp for sp in splits if sp[0] == "loto" or int(sp[0][1:-1]) in ks]
    if args.quick:  # the first split of each protocol
        splits = [sp for i, sp in enumerate(splits) if sp[0] not in {q for q, _ in splits[:i]}]
    return splits


def _hybrid_table(args: argparse.Namespace) -> Any:
    """The table for ``--method hybrid`` (with measured VB; no model, no training list)."""
    from server.errors import CutwatchError
    from server.pipeline.wear_nested import SETS, SPEED, columns_needed
    from server.records.wear_table import VB, read_wear_table

    if args.signal_set not in SETS:
        raise CutwatchError(f"--set {args.signal_set!r}: expected one of {', '.join(SETS)}")
    table = read_wear_table(
        args.table, columns_needed([args.signal_set]), args.map, optional=(VB, SPEED)
    )
    if not table.has_vb:
        raise CutwatchError(
            f"{table.path}: column 'Vb': expected measured flank wear for --method hybrid "
            "(the map is learnt across the other tools), found none"
        )
    if args.train_tools is not None or args.model is not None:
        raise CutwatchError(
            "--method hybrid: expected --test-tools only (the other tools are the training "
            "tools; no model file), found --train-tools or --model"
        )
    return table


def _run_diagnose(args: argparse.Namespace, table: Any, test: list[int] | None) -> int:
    """``--diagnose``: the outer splits of ``--protocol`` under the default protocol (or
    ``--revision``); for the tools left out one at a time,
    :mod:`server.pipeline.wear_diagnose`'s tables and figure; for every split, the ratio
    ours / linear measured every way, median (range) per protocol."""
    from tqdm import tqdm

    from server.errors import CutwatchError
    from server.pipeline import wear_diagnose as D
    from server.pipeline.wear_nested import _Cache, run_fold

    if test is not None and args.protocol != "loto":
        raise CutwatchError(
            f"--diagnose --protocol {args.protocol}: expected no --test-tools (the protocol "
            f"draws the test tools), found --test-tools {args.test_tools}"
        )
    if len(table.tools) < 4:
        raise CutwatchError(
            f"{table.path}: --diagnose: expected 4 or more tools (3 or more training tools "
            f"per fold), found {len(table.tools)}"
        )
    splits: list[tuple[str, tuple[int, ...]]]
    if args.protocol == "loto":
        splits = [("loto", (t,)) for t in (test if test is not None else table.tools)]
    else:
        splits = _hybrid_splits(args, table)
    rev, cfgs, laws = _protocol(args)
    cache = _Cache()
    folds = [
        run_fold(table, args.signal_set, g, proto, cache, configs=cfgs, rate_laws=laws)
        for proto, g in tqdm(splits, desc="wear folds", file=sys.stderr, disable=args.quiet)
    ]
    what = "quick (30 configurations, a check that it runs)" if args.quick else f"revision {rev}"
    loto = [f for f in folds if f.protocol == "loto"]
    args.out.mkdir(parents=True, exist_ok=True)
    dg: dict[str, Any] = {"set": args.signal_set}
    if loto:
        dg = D.diagnose(table, args.signal_set, loto, cfgs)
        D.figure([dg], args.out / "diagnosis.png")
        print(f"{table.path}: " + D.text(dg))
    dg["protocol"] = f"{args.protocol}, {what}" + (" (the default)" if what == "revision 4" else "")
    dg["spread"] = D.spread(table, args.signal_set, folds, cfgs)
    print(D.spread_text(dg["spread"], args.signal_set))
    (args.out / "diagnosis.json").write_text(json.dumps(dg, indent=1, default=float) + "\n")
    print(f"wrote {args.out}/diagnosis.json" + (", diagnosis.png" if loto else ""))
    return 0


def _read_model(path: Path, signal: str) -> Any:
    from estimators.wear.turning import TurningWearModel
    from server.errors import CutwatchError

    try:
        data = json.loads(path.read_text())
        m = TurningWearModel.from_dict(data)
    except (OSError, ValueError, TypeError) as exc:
        raise CutwatchError(f"{path}: not a cutwatch wear model: {exc}") from None
    if m.signal != signal:
        raise CutwatchError(
            f"{path}: field 'signal': expected {signal!r} (--signal), found {m.signal!r}"
        )
    return m


def _estimate(
    args: argparse.Namespace, table: Any, train: Any, test: Any, model: Any
) -> tuple[list[Any], Any]:
    from tqdm import tqdm

    from estimators.errors import ParameterError
    from server.errors import CutwatchError
    from server.pipeline.wear_folds import leave_one_out, run_fold

    base = not args.no_baselines
    try:
        if train is None and model is None and test is None:
            with tqdm(
                total=len(table.tools), desc="wear folds", file=sys.stderr, disable=args.quiet
            ) as bar:
                res = leave_one_out(
                    table, args.signal, table.tools, criterion=args.criterion,
                    with_baselines=base, progress=bar.update,
                )  # fmt: skip
            return res, None
        if train is None and model is None:
            train = [t for t in table.tools if t not in test]
        fitted, res = run_fold(
            table, args.signal, train or model.train_tools, test,
            criterion=args.criterion, model=model, with_baselines=base and model is None,
        )  # fmt: skip
    except ParameterError as exc:
        raise CutwatchError(f"{table.path}: {exc}") from None
    return res, fitted


def _report(
    args: argparse.Namespace, table: Any, results: list[Any], fitted: Any
) -> tuple[dict[str, Any], list[dict[str, float]], list[tuple[str, str]]]:
    from server.pipeline.wear_folds import summarise
    from server.records.wear_report import tool_figure
    from server.records.wear_table import SIGNALS

    rep: dict[str, Any] = {
        "table": str(table.path),
        "signal": args.signal,
        "column": f"{SIGNALS[args.signal]}_MEAN",
        "criterion_um": args.criterion,
        "time_base": "segment index (the table has no cutting time); life in segments",
        "interval": "95 %",
        "train_tools": fitted.train_tools if fitted is not None else "leave-one-tool-out",
        "test_tools": [r.tool for r in results],
        **summarise(results, args.criterion),
    }
    if fitted is not None:
        rep["model"] = fitted.to_dict()
    rows = []
    figs = []
    for r in results:
        e = r.estimate
        for k in range(len(e.vb)):
            row = {
                "tool": r.tool, "segment": k, "vb_est": e.vb[k], "vb_lo": e.vb_lo[k],
                "vb_hi": e.vb_hi[k], "life_left": e.life_left[k],
                "life_left_lo": e.life_left_lo[k], "life_left_hi": e.life_left_hi[k],
            }  # fmt: skip
            if r.vb is not None:
                row["vb_true"] = r.vb[k]
            rows.append(row)
        est = {"vb": e.vb, "vb_lo": e.vb_lo, "vb_hi": e.vb_hi}
        figs.append((f"tool {r.tool}", tool_figure(r.tool, r.vb, est, r.baselines, rep["column"])))
    return rep, rows, figs
