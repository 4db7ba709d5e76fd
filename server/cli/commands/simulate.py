"""Simulate the stage and write the run as a measured log (docs/design.md's log format).

The log holds what a drive sees (t, tau_m, i_m, q_m, q_l) and the load-side reference
force f_ext; the sidecar holds the sample time, units, kind and the NOMINAL parameters
(what the estimators are told). Plant effects switched on with --effect are not declared
in the sidecar: they are for the residual loop to find. The true parameters go into a
separate ``<stem>.truth.json`` for scoring.

Examples::

    cutwatch simulate --out run.csv --seconds 20
    cutwatch simulate --out run.csv --effect coulomb_asymmetry --weight
    cutwatch simulate --out paper.csv --half-period 4 --dwell 0 --levels 1   # seed 000 Fig. 8

The default motion is richer than the papers' (reversals every 2 s, 0.3 s at rest at
each, plateaus at 100/50/25 % of the speed) so that friction effects can be told apart.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

HELP = "simulate the stage and write a measured log (CSV + JSON sidecar)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    from machine.effects import EFFECT_NAMES
    from machine.stage_params import PRESETS

    p.add_argument("--out", type=Path, required=True, help="CSV file to write")
    p.add_argument("--seconds", type=float, default=10.0, help="simulated time [s]")
    p.add_argument(
        "--preset",
        default="seed000",
        choices=sorted(PRESETS),
        help="stage parameters (seed 000 Table I or seed 001 Table 1)",
    )
    p.add_argument(
        "--effect",
        action="append",
        default=[],
        choices=EFFECT_NAMES,
        help="switch on an undeclared plant effect (repeatable)",
    )
    p.add_argument("--weight", action="store_true", help="add the weight of seed 000 Fig. 7(b)")
    p.add_argument("--no-force", action="store_true", help="air cut: no cutting force")
    p.add_argument(
        "--speed", type=float, default=None, help="plateau speed [rad/s] (30; --seed: 20..40)"
    )
    p.add_argument(
        "--half-period",
        type=float,
        default=None,
        help="time between velocity reversals [s] (2; --seed: 1.5..2.5)",
    )
    p.add_argument(
        "--dwell",
        type=float,
        default=None,
        help="rest at each reversal [s] (0: no stop) (0.3; --seed: 0.15..0.45)",
    )
    p.add_argument(
        "--levels",
        default=None,
        help="plateau speeds as fractions of --speed, in turn (1,0.5,0.25; --seed: 1, "
        "0.4..0.7, 0.15..0.35 in random order)",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=None,
        help="draw one Monte Carlo case: the motion program (speed, reversal timing, "
        "dwell, levels), the current noise and the effects' magnitudes (x 0.7..1.3) and "
        "phases; options given explicitly win. Without it: the fixed default log",
    )
    p.add_argument(
        "--vary",
        default="motion,noise,effect",
        help="what --seed draws (comma list of motion, noise, effect); e.g. motion,noise "
        "for a second record of the same machine",
    )
    p.add_argument(
        "--current-noise",
        type=float,
        default=None,
        help="current noise rms [A] (0; --seed: 0.01..0.05)",
    )


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from server.errors import CutwatchError
    from server.experiments.residual_logs import simulate_stage, stage_case
    from server.records.measured_log import write_log

    if not (0 < args.seconds <= 3600):
        raise CutwatchError(f"--seconds: expected a value in (0, 3600], got {args.seconds}")
    levels = None
    if args.levels is not None:
        try:
            levels = tuple(float(x) for x in str(args.levels).split(","))
        except ValueError:
            raise CutwatchError(
                f"--levels: expected comma-separated fractions in (0, 1], got {args.levels!r}"
            ) from None
    vary = frozenset(v.strip() for v in str(args.vary).split(",") if v.strip())
    bad = sorted(vary - {"motion", "noise", "effect"})
    if bad:
        raise CutwatchError(f"--vary: expected names among motion, noise, effect, got {bad[0]!r}")
    case = stage_case(
        args.effect,
        args.seed,
        speed=args.speed,
        half_period=args.half_period,
        dwell=args.dwell,
        levels=levels,
        current_noise=args.current_noise,
        vary=vary,
    )
    n_total = int(round(args.seconds / 4e-4))
    with tqdm(total=n_total, desc="simulate", unit="sample", unit_scale=True) as bar:
        cols, sidecar, truth = simulate_stage(
            case,
            args.seconds,
            seed=args.seed,
            preset_name=args.preset,
            weight=args.weight,
            no_force=args.no_force,
            on_block=bar.update,
        )
    write_log(args.out, cols, sidecar)
    truth_path = args.out.with_suffix(".truth.json")
    truth_path.write_text(json.dumps(truth, indent=2))
    n = len(cols["t"])
    print(f"wrote {args.out} ({n} samples), {args.out.with_suffix('.json')}, {truth_path}")
    return 0
