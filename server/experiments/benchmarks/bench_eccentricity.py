"""Benchmark: milling with eccentricity on the X/Y drives, with the ESC or the fast tuner.

Simulated seconds per wall second (medians), case 1 of seed 003 Table 1 at 5 kHz, for
the machine alone, the machine + ESC (dynamometer force), the machine + fast tuner, and
the machine + ESC on the force estimated by observers on both axes.
"""

from __future__ import annotations

import statistics
import time

from harness.eccentricity_loop import EccentricityLoop, ObserverForceSource
from server.experiments.benchmarks import Figures
from server.experiments.reproductions._seed003_cut import ESC_TABLE1, case_params


def _rate(make: object, seconds: float, repeats: int) -> float:
    rates = []
    for _ in range(repeats):
        loop = make()  # type: ignore[operator]
        loop.run_revolutions(2)  # compile / warm caches outside the timing
        t0 = time.perf_counter()
        revs = round(seconds * loop.machine.spindle_rpm / 60.0)
        sim0 = loop.machine.t
        loop.run_revolutions(revs)
        wall = time.perf_counter() - t0
        rates.append((loop.machine.t - sim0) / wall)
    return float(statistics.median(rates))


def measure(*, repeats: int, quick: bool) -> Figures:
    """Realtime factors of the eccentricity loop variants (medians over ``repeats``)."""
    mp = case_params(1)
    seconds = 2.0 if quick else 20.0

    def observer_loop() -> EccentricityLoop:
        loop = EccentricityLoop(mp, tuner="esc", esc=ESC_TABLE1, adapt_start_s=0.0)
        loop.force_source = ObserverForceSource(loop.machine.drives.params)
        return loop

    res: Figures = {
        "config": f"seed 003 case 1, 5 kHz, {seconds:g} s simulated per run",
        "machine_realtime_factor": _rate(
            lambda: EccentricityLoop(mp, tuner="off"), seconds, repeats
        ),
        "esc_loop_realtime_factor": _rate(
            lambda: EccentricityLoop(mp, tuner="esc", esc=ESC_TABLE1, adapt_start_s=0.0),
            seconds,
            repeats,
        ),
        "fast_tuner_loop_realtime_factor": _rate(
            lambda: EccentricityLoop(mp, tuner="fast", adapt_start_s=0.0), seconds, repeats
        ),
        "esc_on_observers_realtime_factor": _rate(observer_loop, seconds, repeats),
    }
    res["realtime_factor"] = res["esc_loop_realtime_factor"]
    return res
