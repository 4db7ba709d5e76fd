"""Benchmarks: simulated seconds per wall second and per-block cost (medians).

Groups (modules server/experiments/benchmarks/bench_<group>.py; see docs/benchmarks.md):
  broker                 the drive-block wire format: binary against JSON
  disturbance-observers  seed 002's loops and the stage DFO
  eccentricity           milling with X/Y drives, ESC and the fast tuner
  fleet                  N machines on broker feeds and the fleet page (mosquitto)
  live                   the real service with 10 WebSocket clients
  pipeline               the live service's whole pipeline, offline
  residual               residual analysis of 1,000,000 samples (rigid)
  residual-two-inertia   the same for the two-inertia observer
  stage                  the stage with its observers and both RLS
  tool-wear              the wear model, observer and life monitor

--json prints {"realtime_factor": x, "realtime_factor_of": "...", "<group>": {...}}:
the top-level realtime_factor is the stage group's (offline block of 2500 samples) and
realtime_factor_of names its configuration; without the stage group it is absent and
realtime_factor_of says so. This is a benchmark, not a test: run it on a quiet machine
and compare medians.

Examples::

    cutwatch bench stage tool-wear --json        # two groups, five runs each
    cutwatch bench pipeline --quick --repeats 1  # a smoke check of one group
    cutwatch bench fleet --quick --machines 4 --workers 2 --seconds 15  # a plant of 4

``fleet`` takes ``--machines N`` (default 20) and ``--workers W``: 0 (default) runs one
``cutwatch serve`` per machine, W > 0 spreads the machines over W ``cutwatch worker``
shards fed by one feeder process (docs/plant.md); ``--seconds`` is its window.
"""

from __future__ import annotations

import argparse
import json
from types import ModuleType

HELP = "measure speed (medians of several runs); a benchmark, not a test"

#: the group whose ``realtime_factor`` is reported at the top level
HEADLINE_GROUP = "stage"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("group", nargs="*", help="benchmark group(s); default: all")
    p.add_argument("--repeats", type=int, default=5, help="runs per measurement (median)")
    p.add_argument("--quick", action="store_true", help="short runs (smoke check)")
    p.add_argument("--json", action="store_true", help="print JSON")
    g = p.add_argument_group("fleet", "options of the fleet group")
    g.add_argument("--machines", type=int, help="machines (default 20; --quick 4)")
    g.add_argument("--workers", type=int, default=0, help="0: a service each; W: W workers")
    g.add_argument("--seconds", type=float, help="measuring window [s] (default 60)")
    g.add_argument(
        "--soak", action="store_true", help="with --workers: no kill; memory over the window"
    )


def group_name(module: ModuleType) -> str:
    """A benchmark module's group name, derived one way: ``bench_tool_wear`` ->
    ``tool-wear``."""
    from server.plugins import short_name

    return short_name(module).removeprefix("bench_").replace("_", "-")


def groups() -> dict[str, ModuleType]:
    """Group name -> module, for every module of the benchmarks package, by name."""
    from server.experiments import benchmarks
    from server.plugins import plugin_modules

    return {group_name(m): m for m in plugin_modules(benchmarks)}


def run(args: argparse.Namespace) -> int:
    from server.errors import CutwatchError

    mods = groups()
    wanted = [g.replace("_", "-") for g in args.group] or list(mods)
    for g in wanted:
        if g not in mods:
            raise CutwatchError(f"unknown benchmark group {g!r}; known: {', '.join(mods)}")
    if args.repeats < 1:
        raise CutwatchError(f"--repeats: expected an integer >= 1, got {args.repeats}")
    if args.machines is not None and args.machines < 1:
        raise CutwatchError(f"--machines: expected an integer >= 1, got {args.machines}")
    if args.workers < 0:
        raise CutwatchError(f"--workers: expected an integer >= 0, got {args.workers}")
    if args.seconds is not None and not args.seconds >= 5:
        raise CutwatchError(f"--seconds: expected a window of 5 s at least, got {args.seconds}")
    fleet = {
        "machines": args.machines,
        "workers": args.workers,
        "seconds": args.seconds,
        "soak": args.soak,
    }
    result: dict[str, object] = {}
    for g in wanted:
        kw = fleet if g == "fleet" else {}
        res = mods[g].measure(repeats=args.repeats, quick=args.quick, **kw)
        result[g] = res
        if not args.json:
            print(f"[{g}]")
            for k, v in res.items():
                print(f"  {k:40s} {v:.4g}" if isinstance(v, float) else f"  {k:40s} {v}")
    head = result.get(HEADLINE_GROUP)
    if isinstance(head, dict) and "realtime_factor" in head:
        top: dict[str, object] = {
            "realtime_factor": head["realtime_factor"],
            "realtime_factor_of": f"{HEADLINE_GROUP}: {head.get('configuration', '')}, "
            "offline block of 2500 samples",
        }
    else:
        top = {
            "realtime_factor_of": f"not measured: the {HEADLINE_GROUP} group was not run "
            f"(cutwatch bench {HEADLINE_GROUP})"
        }
    if args.json:
        print(json.dumps({**top, **result}, indent=2))
    elif "realtime_factor" in top:
        print(f"realtime_factor {top['realtime_factor']:.4g} ({top['realtime_factor_of']})")
    return 0
