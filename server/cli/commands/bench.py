"""Benchmarks: simulated seconds per wall second and per-block cost (medians).

Groups (modules in server/experiments/benchmarks/; see docs/benchmarks.md):
  stage                  the stage with its observers and both RLS (issue 2)
  disturbance-observers  seed 002's loops and the stage DFO
  eccentricity           milling with X/Y drives, ESC and the fast tuner
  tool-wear              the wear model, observer and life monitor
  residual               residual analysis of 1,000,000 samples (rigid)
  residual_two_inertia   the same for the two-inertia observer
  live                   the real service with 10 WebSocket clients

--json prints {"realtime_factor": x, "<group>": {...}} with the configuration measured.
This is a benchmark, not a test: run it on a quiet machine and compare medians.
"""

from __future__ import annotations

import argparse
import importlib
import json
import pkgutil

HELP = "measure speed (medians of several runs); a benchmark, not a test"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("group", nargs="*", help="benchmark group(s); default: all")
    p.add_argument("--repeats", type=int, default=5, help="runs per measurement (median)")
    p.add_argument("--quick", action="store_true", help="short runs (smoke check)")
    p.add_argument("--json", action="store_true", help="print JSON")


def run(args: argparse.Namespace) -> int:
    from server.errors import CutwatchError
    from server.experiments import benchmarks

    mods = {}
    for info in sorted(pkgutil.iter_modules(benchmarks.__path__), key=lambda i: i.name):
        if not info.name.startswith("_"):
            m = importlib.import_module(f"server.experiments.benchmarks.{info.name}")
            mods[m.NAME] = m
    groups = args.group or list(mods)
    for g in groups:
        if g not in mods:
            raise CutwatchError(f"unknown benchmark group {g!r}; known: {', '.join(mods)}")
    if args.repeats < 1:
        raise CutwatchError(f"--repeats: expected an integer >= 1, got {args.repeats}")
    result: dict[str, object] = {}
    for g in groups:
        res = mods[g].measure(repeats=args.repeats, quick=args.quick)
        if "realtime_factor" in res and "realtime_factor" not in result:
            result["realtime_factor"] = res["realtime_factor"]
        result[g] = res
        if not args.json:
            print(f"[{g}]")
            for k, v in res.items():
                print(f"  {k:40s} {v:.4g}" if isinstance(v, float) else f"  {k:40s} {v}")
    if args.json:
        print(json.dumps(result, indent=2))
    return 0
