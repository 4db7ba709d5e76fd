"""Find what the nominal model of a measured log misses, add it, report before and after.

Examples::

    cutwatch residual run.csv --out out/run
    cutwatch residual ../shared/data/emps/DATA_EMPS.mat \\
        --map tau_m=vir*gtau --map q_m=qm \\
        --meta '{"units": {"effort": "N", "position": "m"}}' --out out/emps

The nominal rigid model is identified by IDIM-LS (estimators.idim) on the first part of
the record; candidate effects (estimators.residual) are scored on the held-out end of
the record. Writes DIR/report.json, DIR/estimates.csv and DIR/report.html.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

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
        help="column map: COL=name, COL=name*scale or COL=name*scale+offset",
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
        help="fraction at the end of the record held out for scoring (0.3)",
    )
    p.add_argument("--out", metavar="DIR", type=Path, required=True, help="output directory")
    p.add_argument("--quiet", action="store_true", help="no progress messages")


def run(args: argparse.Namespace) -> int:
    from estimators.errors import ParameterError
    from estimators.residual import ResidualParams, analyse_rigid, apply_model
    from server.errors import CutwatchError
    from server.logfile import load_log, load_meta
    from server.residual_report import write_report

    if args.kind is not None and args.kind not in KINDS:
        raise CutwatchError(f"--kind {args.kind!r}: expected one of {', '.join(KINDS)}")
    try:
        params = ResidualParams(holdout_fraction=args.holdout)
    except ParameterError as exc:
        raise CutwatchError(f"--holdout: {exc}") from None
    meta = load_meta(args.meta)
    progress = not args.quiet
    log = load_log(args.log, meta=meta, maps=args.map, kind=args.kind, progress=progress)
    kind = log.kind or "rigid"
    if kind != "rigid":
        raise CutwatchError(
            f"{log.path}: kind {kind!r} is not available yet in cutwatch "
            "residual (only 'rigid'); pass --kind rigid to use the rigid model"
        )

    def say(msg: str) -> None:
        if progress:
            print(f"residual: {msg}", file=sys.stderr)

    try:
        res = analyse_rigid(
            log["q_m"], log["tau_m"], log["t"], log.sample_time, params, progress=say
        )
    except ParameterError as exc:
        raise CutwatchError(
            f"{log.path}: too few samples for the held-out split ({log.n} rows): {exc}"
        ) from None
    validation = None
    if args.validate is not None:
        other = load_log(args.validate, meta=meta, maps=args.map, kind=args.kind, progress=progress)
        try:
            nums = apply_model(
                res, other["q_m"], other["tau_m"], other["t"], other.sample_time, params.idim
            )
        except ParameterError as exc:
            raise CutwatchError(f"{other.path}: cannot validate on it: {exc}") from None
        validation = {"log": str(other.path), **nums}
    rep = write_report(args.out, log, res, validation)
    print(
        f"{log.path}: held-out rms {rep['rms_before']:.4g} -> {rep['rms_after']:.4g} "
        f"{log.units['effort']}, relerr {rep['relerr_before']:.3f} % -> "
        f"{rep['relerr_after']:.3f} %; selected: {', '.join(rep['selected']) or 'none'}"
    )
    for u in rep["unexplained"]:
        print(f"  unexplained: {u}")
    if validation is not None:
        print(
            f"validation {validation['log']}: relerr {validation['relerr_before']:.3f} % -> "
            f"{validation['relerr_after']:.3f} %"
        )
    print(f"wrote {args.out}/report.json, estimates.csv, report.html")
    return 0
