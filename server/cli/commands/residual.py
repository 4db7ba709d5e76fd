"""Find what the nominal model of a measured log misses, add it, report before and after.

Examples::

    cutwatch residual run.csv --out out/run
    cutwatch residual ../shared/data/emps/DATA_EMPS.mat \\
        --map tau_m=vir*gtau --map q_m=qm \\
        --meta '{"units": {"effort": "N", "position": "m"}}' --out out/emps

The nominal model (rigid: IDIM-LS, estimators.idim; two_inertia: the cutting force
observer with the log's nominal parameters) is fitted on the first part of the record
(1 - --holdout). Candidate effects (estimators.residual.engine) are selected greedily by
blocked cross-validation inside that fitting part: per round, each family's shape is
searched again inside every training fold, its out-of-fold error reduction where it
acts is tested (Holm over the round's candidates) and must remove a quarter of the
floor. The held-out end takes no part in the selection: it is the report's before/after
figure. Writes DIR/report.json, DIR/estimates.csv and DIR/report.html.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

HELP = "find the residual of a measured log, add the missing effect, report before/after"

KINDS = ("rigid", "two_inertia")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", type=Path, help="measured log (.csv with .json sidecar, or .mat)")
    p.add_argument(
        "--meta",
        metavar="JSON",
        help="sidecar keys overriding the log's (a JSON file or inline object)",
    )
    p.add_argument(
        "--map",
        metavar="COL=EXPR",
        action="append",
        default=[],
        help="column map: COL=name, COL=name*scale or COL=name*scale+offset; the log's "
        "columns are t (or sample_time in --meta), tau_m (effort: N, N m, or A; in A "
        "without nominal.K_t the parameters are in A), q_m (m or rad), and optionally "
        "qd_m, qdd_m (the velocity and acceleration the controller reports, used instead "
        "of differentiating a coarse position), q_l, f_ext. One axis per run.",
    )
    p.add_argument(
        "--kind", metavar="KIND", help="rigid or two_inertia (default: sidecar, else rigid)"
    )
    p.add_argument(
        "--validate",
        metavar="OTHER_LOG",
        type=Path,
        help="apply the fitted model to a second record (same --meta/--map)",
    )
    p.add_argument(
        "--holdout",
        type=float,
        default=0.3,
        metavar="FRACTION",
        help="fraction at the end of the record held out for the before/after figure; the "
        "selection cross-validates inside the rest (0.3)",
    )
    p.add_argument(
        "--air-cut",
        metavar="START:STOP",
        action="append",
        default=[],
        help="two_inertia without f_ext: a segment [s] with no cutting force (repeatable)",
    )
    rows = p.add_argument_group(
        "rows",
        "Choose rows by a condition on any column of the file, text labels included: "
        "COND is TERM [& TERM ...], TERM is COLUMN OP VALUE with OP one of == != < <= > >= "
        "(numbers; == and != also text) or ~ (regular expression searched in the cell). "
        "Columns neither mapped nor required are otherwise ignored, whatever they hold. "
        "The rows each rule leaves out are counted in the report; the record is split "
        "where rows are left out (nothing is differentiated or filtered across a cut).",
    )
    rows.add_argument(
        "--keep",
        metavar="COND",
        action="append",
        default=[],
        help="use only rows where COND holds (repeatable: all must hold), "
        "e.g. --keep 'Machining_Process~^Layer'",
    )
    rows.add_argument(
        "--drop",
        metavar="COND",
        action="append",
        default=[],
        help="leave out rows where COND holds (repeatable: any), e.g. rows that do not "
        "reflect the machine: --drop 'S1_ActualVelocity<1 & X1_ActualPosition==198'",
    )
    rows.add_argument(
        "--drop-repeats",
        metavar="COLS",
        help="leave out rows that repeat the previous row in every column named "
        "(comma-separated names or patterns, e.g. 'X1_*,Y1_*'): stale copies of a sample",
    )
    rows.add_argument(
        "--nominal-rows",
        metavar="COND",
        help="fit the nominal model on these rows only (e.g. the tool in the air: "
        "--nominal-rows 'Machining_Process~^(Prep|Repositioning)'); effects on all rows",
    )
    rows.add_argument(
        "--load-rows",
        metavar="COND",
        help="rows where a process load acts (e.g. cutting: --load-rows "
        "'Machining_Process~^Layer'); offers the 'load' effect: an effort on these rows, "
        "by direction of motion",
    )
    p.add_argument("--out", metavar="DIR", type=Path, required=True, help="output directory")
    p.add_argument("--quiet", action="store_true", help="no progress messages")


def run(args: argparse.Namespace) -> int:
    from estimators.errors import ParameterError
    from estimators.residual.engine import ResidualParams, analyse, apply
    from server.errors import CutwatchError
    from server.pipeline.residual_run import model_notes
    from server.records.measured_log import load_log, load_meta
    from server.records.residual_report import write_report

    if args.kind is not None and args.kind not in KINDS:
        raise CutwatchError(f"--kind {args.kind!r}: expected one of {', '.join(KINDS)}")
    try:
        params = ResidualParams(holdout_fraction=args.holdout)
    except ParameterError as exc:
        raise CutwatchError(f"--holdout: {exc}") from None
    meta = load_meta(args.meta)
    progress = not args.quiet
    selection = row_selection(args)
    log = load_log(
        args.log, meta=meta, maps=args.map, kind=args.kind, progress=progress,
        selection=selection, current_ok=True,
    )  # fmt: skip
    kind = log.kind or "rigid"
    with _Progress(progress) as say:
        model = _model(kind, log, args)
        try:
            res = analyse(model, params, progress=say)
        except ParameterError as exc:
            if kind == "two_inertia":
                raise CutwatchError(f"{log.path}: {exc}") from None
            raise CutwatchError(
                f"{log.path}: too few samples for the held-out split ({log.n} rows): {exc}"
            ) from None
    validation = None
    if args.validate is not None:
        vkind = kind if kind == "two_inertia" else args.kind
        other = load_log(
            args.validate, meta=meta, maps=args.map, kind=vkind, progress=progress,
            selection=selection, current_ok=True,
        )  # fmt: skip
        try:
            nums = apply(res, _model(kind, other, args))
        except ParameterError as exc:
            raise CutwatchError(f"{other.path}: cannot validate on it: {exc}") from None
        validation = {"log": str(other.path), **nums}
    rep = write_report(args.out, log, res, validation, notes=model_notes(log, kind))
    _summary(args, log, rep, validation)
    return 0


def _model(kind: str, log: Any, args: argparse.Namespace) -> Any:
    """The residual model of ``log``: the rigid axis, or the observer with its nominal
    parameters, its reference force or the ``--air-cut`` segments."""
    from estimators.errors import ParameterError
    from estimators.residual.two_inertia import TwoInertiaModel
    from server.errors import CutwatchError
    from server.pipeline.residual_run import rigid_model

    if kind != "two_inertia":
        return rigid_model(log)
    op, lp = _observer_inputs(log)
    f_ext = log["f_ext"] if "f_ext" in log.columns else None
    if f_ext is None and not args.air_cut:
        raise CutwatchError(
            f"{log.path}: kind 'two_inertia' needs a reference force column 'f_ext' or "
            "--air-cut START:STOP segments with no cutting force"
        )
    air = parse_air_cuts(args.air_cut, log["t"], str(log.path)) if f_ext is None else None
    angular = log.units.get("position") == "rad"
    try:
        return TwoInertiaModel(
            log["t"], log["tau_m"], log["q_m"], log["q_l"], op, lp,
            f_ext=f_ext, air_cut=air, angular=angular,
        )  # fmt: skip
    except ParameterError as exc:
        raise CutwatchError(f"{log.path}: {exc}") from None


def row_selection(args: argparse.Namespace) -> Any:
    """The ``--keep/--drop/--drop-repeats/--nominal-rows/--load-rows`` options, parsed."""
    from server.records.row_select import RowSelection

    return RowSelection.from_options(
        keep=args.keep,
        drop=args.drop,
        drop_repeats=args.drop_repeats,
        phases={"nominal_rows": args.nominal_rows, "load_rows": args.load_rows},
    )


class _Progress:
    """Stage messages and a tqdm bar over the scored candidates, on stderr (--quiet: off)."""

    def __init__(self, on: bool) -> None:
        self.on = on
        self.bar: Any = None

    def __enter__(self) -> Callable[[str], None]:
        if self.on:
            from tqdm import tqdm

            self.bar = tqdm(desc="residual", unit="step", file=sys.stderr, leave=False)
        return self

    def __call__(self, msg: str) -> None:
        if self.bar is not None:
            self.bar.set_postfix_str(msg, refresh=False)
            self.bar.update(1)

    def __exit__(self, *exc: object) -> None:
        if self.bar is not None:
            self.bar.close()


_NOMINAL = ("J_M", "B_M", "F_CM", "K", "J_L", "B_L", "F_CL")


def parse_air_cuts(specs: list[str], t: Any, where: str) -> Any:
    """Mask of the samples inside the ``START:STOP`` segments [s] (CutwatchError if bad)."""
    import numpy as np

    from server.errors import CutwatchError

    mask = np.zeros(len(t), dtype=bool)
    for spec in specs:
        parts = spec.split(":")
        try:
            if len(parts) != 2:
                raise ValueError
            a, b = float(parts[0]), float(parts[1])
        except ValueError:
            raise CutwatchError(
                f"--air-cut {spec!r}: expected START:STOP in seconds, e.g. 0.5:2.0"
            ) from None
        if not (math.isfinite(a) and math.isfinite(b) and b > a):
            raise CutwatchError(f"--air-cut {spec!r}: expected finite START < STOP")
        seg = (t >= a) & (t <= b)
        if not seg.any():
            raise CutwatchError(
                f"{where}: --air-cut {spec!r} holds no sample (the log spans "
                f"{float(t[0]):g} ... {float(t[-1]):g} s)"
            )
        mask |= seg
    return mask


def _observer_inputs(log: Any) -> tuple[Any, Any]:
    from estimators.errors import ParameterError
    from estimators.residual.two_inertia import nominal_observer
    from server.errors import CutwatchError

    if "q_l" not in log.columns:
        raise CutwatchError(
            f"{log.path}: kind 'two_inertia' needs the load-side position column 'q_l'; "
            f"found {', '.join(sorted(log.columns))}"
        )
    missing = [k for k in _NOMINAL if k not in log.nominal]
    if missing:
        raise CutwatchError(
            f"{log.path}: kind 'two_inertia' needs the nominal parameters "
            f"{', '.join(_NOMINAL)} in the sidecar (or --meta '{{\"nominal\": ...}}'); "
            f"missing {', '.join(missing)}"
        )
    res = log.sidecar.get("encoder_resolution")
    try:
        op, lp = nominal_observer(log.nominal, log.sample_time, res)
    except (ParameterError, TypeError, ValueError) as exc:
        raise CutwatchError(f"{log.path}: nominal parameters: {exc}") from None
    return op, lp


def _summary(args: argparse.Namespace, log: Any, rep: Any, validation: Any) -> None:
    from server.records.residual_report import describe_structure

    if log.left_out:
        counts = "; ".join(f"{d['left_out']} by {d['rule']}" for d in log.left_out)
        print(f"{log.path}: rows read {log.n_read}, used {log.n}; left out: {counts}")
    for note in rep.get("notes", []):
        print(f"  {note}")
    print(
        f"{log.path}: held-out rms {rep['rms_before']:.4g} -> {rep['rms_after']:.4g} "
        f"{log.units['effort']}, relerr {rep['relerr_before']:.3f} % -> "
        f"{rep['relerr_after']:.3f} %; selected: {', '.join(rep['selected']) or 'none'}"
    )
    for a in rep.get("indistinguishable", []):
        print(
            f"  indistinguishable on this record: {' and '.join(a['families'])} "
            f"({a['installed']} installed); to tell them apart: {a['excitation']}"
        )
    for u in rep["unexplained"]:
        print(f"  unexplained: {describe_structure(u)}")
    if validation is not None:
        print(
            f"validation {validation['log']}: relerr {validation['relerr_before']:.3f} % -> "
            f"{validation['relerr_after']:.3f} %"
        )
    print(f"wrote {args.out}/report.json, estimates.csv, report.html")
