"""Speed of seed 002's x-axis loop (P/PI, IMBDO, DFO, both) and of the DFO alone.

The x-axis loop runs in blocks of 12 samples (its 1.2 ms delay at 10 kHz); the DFO alone
runs on a force signal in blocks of 125 samples (50 ms at 2.5 kHz, the stage's block).
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from estimators import dfo as dfo_mod
from estimators.force_observer import ObserverParams
from server.experiments.benchmarks import Figures
from server.experiments.reproductions import seed002_disturbance_observers as do
from server.pipeline import stage_harmonics as sh


def _median_time(fn: object, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()  # type: ignore[operator]
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def measure(*, repeats: int, quick: bool) -> Figures:
    """Simulated seconds per wall second (medians of ``repeats`` runs)."""
    duration = 1.0 if quick else 5.0
    do.simulate("combined", 0.05)  # compile / load the kernels
    out: Figures = {
        "xy_sample_rate_hz": 10000.0,
        "xy_block_samples": 12,
        "xy_duration_s": duration,
    }
    for c in do.CONFIGS:
        wall = _median_time(lambda c=c: do.simulate(c, duration), repeats)
        out[f"xy_{c}_realtime_factor"] = duration / wall
    # the stage's DFO (Q channel 250 Hz, offset state) with three harmonics
    p = sh.make_dfo(ObserverParams(J_M=1.0, B_M=0.0, F_CM=0.0, K=1.0), (100.0, 200.0, 300.0))
    ts = p.sample_time
    n_blk = 125
    dur2 = 10.0 if quick else 60.0
    n = round(dur2 / ts)
    y = np.sin(2 * np.pi * 100.0 * np.arange(n) * ts)

    def run_dfo() -> None:
        s = dfo_mod.Dfo(p).initial_state()
        for k0 in range(0, n, n_blk):
            s, _ = dfo_mod.Dfo(p).step(s, y[k0 : k0 + n_blk])

    run_dfo()
    wall = _median_time(run_dfo, repeats)
    out["dfo_3harmonics_2500hz_realtime_factor"] = dur2 / wall
    out["dfo_block_us"] = wall / (n / n_blk) * 1e6
    dur3 = 2.0 if quick else 10.0
    sh.run_stage(0.1)
    wall = _median_time(lambda: sh.run_stage(dur3), repeats)
    out["stage_with_dfo_realtime_factor"] = dur3 / wall
    return out
