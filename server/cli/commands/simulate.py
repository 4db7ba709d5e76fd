"""Simulate the stage and write the run as a measured log (DESIGN's log format).

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
    from machine.params import PRESETS

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
    p.add_argument("--speed", type=float, default=30.0, help="plateau speed [rad/s]")
    p.add_argument(
        "--half-period", type=float, default=2.0, help="time between velocity reversals [s]"
    )
    p.add_argument(
        "--dwell", type=float, default=0.3, help="rest at each reversal [s] (0: no stop)"
    )
    p.add_argument(
        "--levels", default="1,0.5,0.25", help="plateau speeds as fractions of --speed, in turn"
    )
    p.add_argument("--seed", type=int, default=0, help="random seed (current noise)")
    p.add_argument("--current-noise", type=float, default=0.0, help="current noise rms [A]")


def run(args: argparse.Namespace) -> int:
    import numpy as np
    from tqdm import tqdm

    from machine.effects import PlantEffects
    from machine.params import preset
    from machine.stage import (
        SEED000_FORCE,
        SEED001_FORCE,
        CuttingForce,
        StageConfig,
        StageSim,
        Trajectory,
    )
    from server.errors import CutwatchError
    from server.records.measured_log import write_log

    if not (0 < args.seconds <= 3600):
        raise CutwatchError(f"--seconds: expected a value in (0, 3600], got {args.seconds}")
    force = SEED000_FORCE if args.preset == "seed000" else SEED001_FORCE
    if args.no_force:
        force = CuttingForce(offset=0.0, amplitudes=(0.0,), frequencies=(100.0,))
    try:
        levels = tuple(float(x) for x in str(args.levels).split(","))
    except ValueError:
        raise CutwatchError(
            f"--levels: expected comma-separated fractions in (0, 1], got {args.levels!r}"
        ) from None
    traj = Trajectory(
        speed=args.speed, half_period=args.half_period, dwell=args.dwell, levels=levels
    )
    cfg = StageConfig(
        params=preset(args.preset),
        force=force,
        trajectory=traj,
        effects=PlantEffects().with_enabled(*args.effect),
        current_noise=args.current_noise,
    )
    sim = StageSim(cfg, seed=args.seed)
    if args.weight:
        sim.set_weight(True)
    block = 2500
    n_total = int(round(args.seconds / cfg.sample_time))
    cols: dict[str, list[np.ndarray]] = {
        k: [] for k in ("t", "tau_m", "i_m", "q_m", "q_l", "f_ext")
    }
    with tqdm(total=n_total, desc="simulate", unit="sample", unit_scale=True) as bar:
        done = 0
        while done < n_total:
            n = min(block, n_total - done)
            m, _ = sim.step(n)
            for k in cols:
                cols[k].append(getattr(m, k))
            done += n
            bar.update(n)
    nom = cfg.params
    sidecar = {
        "sample_time": cfg.sample_time,
        "units": {"effort": "N m", "position": "rad", "current": "A"},
        "kind": "two_inertia",
        "nominal": nom.as_dict(),
        "encoder_resolution": cfg.encoder_resolution,
        "source": f"cutwatch simulate --preset {args.preset}",
        "trajectory": {
            "speed": args.speed,
            "half_period": args.half_period,
            "dwell": args.dwell,
            "levels": list(levels),
        },
    }
    write_log(args.out, {k: np.concatenate(v) for k, v in cols.items()}, sidecar)
    truth = {
        "params": sim.config.true_params.as_dict(),
        "effects": sorted(args.effect),
        "effect_parameters": {k: getattr(cfg.effects, k) for k in args.effect},
        "weight": bool(args.weight),
    }
    truth_path = args.out.with_suffix(".truth.json")
    truth_path.write_text(json.dumps(truth, indent=2))
    print(f"wrote {args.out} ({n_total} samples), {args.out.with_suffix('.json')}, {truth_path}")
    return 0
