"""Benchmarks: simulated seconds per wall second and per-block cost (medians).

Groups (modules server/experiments/benchmarks/bench_<group>.py; see docs/benchmarks.md):
  broker                 the drive-block wire format: binary against JSON
  centre                 the machining centre's simulation and its CNC trace export
  centre-pipeline        one machining centre's pipeline at 500 Hz as a worker steps it
  chatter                the regenerative cut, the flexible-tool machine, the lobes
  disturbance-observers  seed 002's loops and the stage DFO
  eccentricity           milling with X/Y drives, ESC and the fast tuner
  fleet                  N machines on broker feeds and the fleet page (mosquitto)
  history                the kept history's cost per committed event (SQLite, fsync)
  live                   the real service with 10 WebSocket clients
  monitoring             breakage to feed-hold command on the broker at 1x (mosquitto)
  opcua                  one OPC UA source under load: values per second, node-to-dashboard latency
  pipeline               the live service's whole pipeline, offline
  residual               residual analysis of 1,000,000 samples (rigid)
  residual-two-inertia   the same for the two-inertia observer
  rigid-axis             the live rigid identifier of one axis (1 kHz, 500 Hz)
  stage                  the stage with its observers and both RLS
  tool-wear              the wear model, observer and life monitor
  upload                 the live loop's lag while an 80 MB log is uploaded, beside idle

Every run also times a fixed reference workload of its own (numba, numpy and
interpreter work, about 1 s; server/experiments/bench_reference.py) before and after
the groups, and prints every speed and cost also as a ratio to it: the figure on a
machine on which one reference run takes 1 s (speeds times the reference's seconds,
costs divided by them). Ratios compare across machines; raw figures do not
(docs/benchmarks.md, "Figures that compare across machines").

``pipeline`` reports what watching a machine costs (estimation) apart from simulating it,
per part, in ms of wall time per machine-second (``cost.*``, ``part.<name>.*``).

``--against REF`` (any group): the group on the code of git commit REF and on this tree's,
each in child processes of its own, run in turn (before, after, before, ...), --repeats
runs each after one warm-up each; every figure as the two medians side by side, their
spreads and the ratio after / before (server/experiments/bench_against.py). The group's
own figures are then this tree's medians; ``before_after`` holds the comparison.

--json prints exactly one JSON document on stdout (progress, and any child process's
output, on stderr): {"realtime_factor": x, "realtime_factor_of": "...", "realtime_factor_ratio":
r, "reference": {...}, "ratios": {"<group>": {"<key>": r}}, "<group>": {...}}: the
top-level realtime_factor is the stage group's (offline block of 2500 samples) and
realtime_factor_of names its configuration; without the stage group it is absent and
realtime_factor_of says so. This is a benchmark, not a test: run it on a quiet machine
and compare medians, or compare ratios.

--duration S runs a group's soak instead (one long run: memory and CPU over time, drops;
the live group has one): cutwatch bench live --duration 1800 --json.

Examples::

    cutwatch bench stage tool-wear --json        # two groups, five runs each
    cutwatch bench pipeline --quick --repeats 1  # a smoke check of one group
    cutwatch bench stage chatter --against main  # these groups before/after, side by side
    cutwatch bench live --duration 10 --json     # a short soak of the live service
    cutwatch bench fleet --quick --machines 4 --workers 2 --seconds 15  # a plant of 4

``fleet`` takes ``--machines N`` (default 20) and ``--workers W``: 0 (default) runs one
``cutwatch serve`` per machine, W > 0 spreads the machines over W ``cutwatch worker``
shards fed by one feeder process (docs/plant.md); ``--seconds`` is its window. With
``--centres`` the machines are machining centres at 500 Hz replaying one recorded trace,
their monitors' events scored against its truth (``cutwatch bench fleet --machines 300
--workers 2 --centres --seconds 300``: the plant of docs/plant.md).
"""

from __future__ import annotations

import argparse
import json
from types import ModuleType
from typing import TYPE_CHECKING, cast

if TYPE_CHECKING:
    from server.experiments.bench_against import BeforeAfter, Options

HELP = "measure speed (medians of several runs); a benchmark, not a test"

#: the group whose ``realtime_factor`` is reported at the top level
HEADLINE_GROUP = "stage"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("group", nargs="*", help="benchmark group(s); default: all")
    p.add_argument("--repeats", type=int, default=5, help="runs per measurement (median)")
    p.add_argument("--quick", action="store_true", help="short runs (smoke check)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="soak: one run of S seconds of a group that has one (live): memory, CPU, drops",
    )
    p.add_argument(
        "--against",
        metavar="REF",
        help="measure each group also on the code of git commit REF (e.g. main), in turn "
        "with this tree's in child processes: before/after medians and their ratio",
    )
    g = p.add_argument_group("fleet", "options of the fleet group")
    g.add_argument("--machines", type=int, help="machines (default 20; --quick 4)")
    g.add_argument("--workers", type=int, default=0, help="0: a service each; W: W workers")
    g.add_argument("--seconds", type=float, help="measuring window [s] (default 60)")
    g.add_argument(
        "--soak", action="store_true", help="with --workers: no kill; memory over the window"
    )
    g.add_argument(
        "--centres",
        action="store_true",
        help="with --workers: machining centres at 500 Hz replaying a recorded trace, their "
        "monitors' events scored against its truth (a soak: no kill)",
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


def _print_group(name: str, res: dict[str, object], ratios: dict[str, float]) -> None:
    print(f"[{name}]")
    for k, v in res.items():
        if isinstance(v, float):
            r = ratios.get(k)
            extra = f"   ratio {r:.4g}" if r is not None else ""
            print(f"  {k:40s} {v:.4g}{extra}")
        elif not isinstance(v, list | dict):
            print(f"  {k:40s} {v}")


def _print_before_after(name: str, ba: BeforeAfter) -> None:
    print(
        f"[{name}] before = {ba['ref']} ({ba['commit'][:10]}), after = this tree; medians of "
        f"{ba['runs']} runs each, in turn"
    )
    print(f"  {'figure':40s} {'before':>11s} {'after':>11s} {'after/before':>12s}  spreads")
    for k, row in ba["figures"].items():
        print(
            f"  {k:40s} {row['before']:11.4g} {row['after']:11.4g} "
            f"{row['after_over_before']:12.4f}  {row['before_spread']:.2f} / "
            f"{row['after_spread']:.2f}"
        )


def _ratios(res: dict[str, object], ref_s: float) -> dict[str, float]:
    from server.experiments.bench_reference import normalise

    out: dict[str, float] = {}
    for k, v in res.items():
        if isinstance(v, float | int) and not isinstance(v, bool):
            r = normalise(k, float(v), ref_s)
            if r is not None:
                out[k] = r
    return out


def _soak(args: argparse.Namespace, mods: dict[str, ModuleType], wanted: list[str]) -> int:
    from server.errors import CutwatchError

    if len(wanted) != 1 or not hasattr(mods[wanted[0]], "soak"):
        have = [g for g, m in mods.items() if hasattr(m, "soak")]
        raise CutwatchError(
            f"--duration: expected exactly one group with a soak ({', '.join(have)}), "
            f"got {', '.join(wanted) or 'every group'}"
        )
    if not args.duration > 0:
        raise CutwatchError(f"--duration: expected seconds > 0, got {args.duration}")
    d = float(args.duration)
    res = mods[wanted[0]].soak(duration_s=d, warmup_s=min(300.0, d / 3), sample_s=min(5.0, d / 20))
    if args.json:
        print(json.dumps({wanted[0]: res}, indent=2))
    else:
        _print_group(wanted[0], res, {})
    return 0


def run(args: argparse.Namespace) -> int:
    from server.errors import CutwatchError
    from server.experiments import bench_reference
    from server.experiments.bench_against import commit_of, measure_against

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
    fleet: Options = {
        "machines": args.machines,
        "workers": args.workers,
        "seconds": args.seconds,
        "soak": args.soak,
    }
    if args.centres:
        if args.workers < 1:
            raise CutwatchError(f"--centres: expected --workers 1 or more, got {args.workers}")
        # only when asked: a tree measured by --against that has no centres mode still runs
        fleet["centres"] = True
    if args.duration is not None:
        return _soak(args, mods, wanted)
    runs = bench_reference.measure(1 if args.quick else 3)
    result: dict[str, dict[str, object]] = {}
    # resolved once: a bad commit refused before anything is measured, and every group
    # measured against the same commit even if the branch moves during the run
    sha = commit_of(args.against) if args.against else None
    for g in wanted:
        kw: Options = fleet if g == "fleet" else {}
        if args.against:
            cmp = measure_against(
                g, args.against, repeats=args.repeats, quick=args.quick, options=kw, commit=sha
            )
            result[g] = {**cmp.labels, **cmp.figures, "before_after": cmp.before_after}
        else:
            result[g] = mods[g].measure(repeats=args.repeats, quick=args.quick, **kw)
    # again after the groups: a load that changed in between shows as a spread
    ref = bench_reference.Reference(runs + bench_reference.measure(1 if args.quick else 2))
    ratios = {g: _ratios(res, ref.seconds) for g, res in result.items()}
    if not args.json:
        for g, res in result.items():
            _print_group(g, res, ratios[g])
            ba = res.get("before_after")
            if isinstance(ba, dict):
                _print_before_after(g, cast("BeforeAfter", ba))
    head = result.get(HEADLINE_GROUP)
    top: dict[str, object]
    if isinstance(head, dict) and "realtime_factor" in head:
        top = {
            "realtime_factor": head["realtime_factor"],
            "realtime_factor_of": f"{HEADLINE_GROUP}: {head.get('configuration', '')}, "
            "offline block of 2500 samples",
            "realtime_factor_ratio": ratios[HEADLINE_GROUP]["realtime_factor"],
        }
    else:
        top = {
            "realtime_factor_of": f"not measured: the {HEADLINE_GROUP} group was not run "
            f"(cutwatch bench {HEADLINE_GROUP})"
        }
    refd = ref.as_dict()
    if args.json:
        print(json.dumps({**top, "reference": refd, "ratios": ratios, **result}, indent=2))
        return 0
    print(
        f"reference (v{refd['version']}) {ref.seconds:.3f} s, median of "
        f"{len(ref.runs)} runs (max/min {refd['spread']:.2f}); ratio = the figure on a "
        "machine where the reference takes 1 s"
    )
    if ref.wall_over_cpu > bench_reference.BUSY_WALL_OVER_CPU:
        print(
            f"note: the reference's wall time was {ref.wall_over_cpu:.2f}x its CPU time: "
            "the machine was busy with other work; the figures (and less so the ratios, "
            "if the load was steady) measure the share of a core the runs got"
        )
    if "realtime_factor" in top:
        print(
            f"realtime_factor {top['realtime_factor']:.4g}, ratio "
            f"{top['realtime_factor_ratio']:.4g} ({top['realtime_factor_of']})"
        )
    return 0
