"""Benchmark of the stage with its force observers and both identifiers (issue 2).

Simulated seconds per wall second on one core for the whole chain (simulation, front end,
ordinary and switching RLS, three force estimates), at the live block size (125 samples,
50 ms) and at an offline block size (2500 samples, 1 s); and the per-block cost at two
run lengths (it must be flat).
"""

from __future__ import annotations

import time

import numpy as np

from server.experiments.benchmarks import Figures
from server.pipeline.stage_run import StageRun


def _rate(block: int, seconds: float) -> tuple[float, float]:
    r = StageRun()
    r.step(block)  # compile / warm up
    n = max(1, int(round(seconds / (block * 4e-4))))
    t0 = time.perf_counter()
    for _ in range(n):
        r.step(block)
    wall = time.perf_counter() - t0
    return n * block * 4e-4 / wall, wall / n


def measure(*, repeats: int, quick: bool) -> Figures:
    short, long_ = (2.0, 6.0) if quick else (10.0, 40.0)
    out: Figures = {
        "configuration": "seed000 stage + front end + ordinary RLS + "
        "switching RLS + 3 force estimates, 1 core"
    }
    for block, label in ((2500, "offline_block_2500"), (125, "live_block_125")):
        rates, costs_s, costs_l = [], [], []
        for _ in range(repeats):
            rf, c_s = _rate(block, short)
            rates.append(rf)
            costs_s.append(c_s)
            _, c_l = _rate(block, long_)
            costs_l.append(c_l)
        out[f"{label}.realtime_factor"] = float(np.median(rates))
        out[f"{label}.per_block_ms.run_{short:g}s"] = 1e3 * float(np.median(costs_s))
        out[f"{label}.per_block_ms.run_{long_:g}s"] = 1e3 * float(np.median(costs_l))
    out["realtime_factor"] = out["offline_block_2500.realtime_factor"]
    return out
