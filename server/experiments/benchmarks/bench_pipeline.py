"""Benchmark: the live service's whole pipeline, offline (no server, no clients).

``server.pipeline.live_pipeline.LivePipeline`` on the default scenario steps the two-inertia X stage
with its three force observers and both RLS, the harmonic observer (DFO), the tool wear
model and its life monitor, the milling machine with eccentricity on its X/Y drives
with the ESC, and the part program on seed 003's machine with the drives' force
observers and the process monitor (issue 21): every estimator the service runs.
Simulated seconds per wall second (medians) at the live block (125 samples = 50 ms) and
at offline blocks (2500 samples = 1 s), after 2 s of warm-up (compiled kernels loaded,
observers settled).

What watching a machine costs, apart from simulating one (issue 26): the pipeline counts
the wall time of every part's estimation apart from its simulation
(:meth:`LivePipeline.costs`: the simulated machine's script, a simulating part's own
machine, the simulator's stage), per machine-second at the live block: ``cost.*_ms``
(medians over the runs; ``part.<name>.estimation_ms`` and ``.simulation_ms`` per part,
``source.simulation_ms`` the stage's simulator, ``pipeline.estimation_ms`` the
coordination: the block, the accuracy).

``cutwatch bench pipeline --against REF`` measures this beside the code of a git commit
(:mod:`server.experiments.bench_against`, every group has it).
"""

from __future__ import annotations

import statistics
import time

from server.experiments.benchmarks import Figures
from server.pipeline.live_pipeline import LivePipeline, PipelineCosts


def _rate(block: int, seconds: float, repeats: int) -> tuple[float, list[PipelineCosts]]:
    rates: list[float] = []
    costs: list[PipelineCosts] = []
    for _ in range(repeats):
        p = LivePipeline("default")
        warm = max(1, round(2.0 / (block * p.sample_time)))
        for _ in range(warm):
            p.step(block)
        p.reset_costs()
        n = max(1, round(seconds / (block * p.sample_time)))
        t0 = time.perf_counter()
        for _ in range(n):
            p.step(block)
        rates.append(n * block * p.sample_time / (time.perf_counter() - t0))
        costs.append(p.costs())
    return float(statistics.median(rates)), costs


def _per_machine_second(costs: list[PipelineCosts]) -> dict[str, float]:
    """Median over the runs of each cost, in ms per machine-second."""
    rows: dict[str, list[float]] = {}

    def add(key: str, seconds: float, machine_s: float) -> None:
        rows.setdefault(key, []).append(1e3 * seconds / machine_s)

    for c in costs:
        ms = c["machine_s"]
        est = c["pipeline"]["estimation_s"]
        sim = c["source"]["simulation_s"]
        for name, v in c["parts"].items():
            add(f"part.{name}.estimation_ms", v["estimation_s"], ms)
            add(f"part.{name}.simulation_ms", v["simulation_s"], ms)
            est += v["estimation_s"]
            sim += v["simulation_s"]
        add("source.simulation_ms", c["source"]["simulation_s"], ms)
        add("pipeline.estimation_ms", c["pipeline"]["estimation_s"], ms)
        add("cost.estimation_ms", est, ms)
        add("cost.simulation_ms", sim, ms)
        add("cost.wall_ms", c["wall_s"], ms)
    return {k: float(statistics.median(v)) for k, v in rows.items()}


def measure(*, repeats: int, quick: bool) -> Figures:
    """Realtime factors of the whole live pipeline at two block sizes and its cost per
    machine-second by part (estimation apart from simulation)."""
    seconds = 5.0 if quick else 30.0
    live, costs = _rate(125, seconds, repeats)
    res: Figures = {
        "config": f"LivePipeline('default'), every estimator, {seconds:g} s simulated per run; "
        "costs in ms of wall time per machine-second at the live block (125 samples)",
        "live_block_125.realtime_factor": live,
        "offline_block_2500.realtime_factor": _rate(2500, seconds, repeats)[0],
        **_per_machine_second(costs),
    }
    res["realtime_factor"] = res["offline_block_2500.realtime_factor"]
    return res
