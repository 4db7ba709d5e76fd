"""Speed of the tool-wear path (seed 004): wear model, adaptive observer, life monitor.

The wear observer samples every 0.01 min (0.6 s of cutting), so its real-time factors
are large; what matters for the live machine on an accelerated clock is the cost per
block and per pass. The linearisation (n' = 200) is the off-line design step.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np

from estimators.wear.monitor import ToolLifeMonitor, ToolLifeParams
from estimators.wear.observer import AdaptiveWearObserver
from harness.wear_clock import (
    SAMPLE_TIME_MIN,
    AcceleratedToolWear,
    design_linear_model,
    observer_params,
)
from machine.tool_wear import ToolWearModel
from server.experiments.benchmarks import Figures


def _median_time(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def measure(*, repeats: int, quick: bool) -> Figures:
    """Medians of ``repeats`` runs; simulated seconds per wall second as ``*_realtime_factor``."""
    minutes = 15.0 if quick else 60.0
    n = round(minutes / SAMPLE_TIME_MIN)
    sim_seconds = minutes * 60.0
    block = 125
    model = ToolWearModel()
    feed = np.full(n, 0.1)
    tr = model.simulate(feed, SAMPLE_TIME_MIN)  # compiles the kernel
    out: Figures = {
        "sample_time_min": SAMPLE_TIME_MIN,
        "run_min": minutes,
        "block_samples": block,
    }
    wall = _median_time(lambda: model.simulate(feed, SAMPLE_TIME_MIN), repeats)
    out["model_realtime_factor"] = sim_seconds / wall

    obs = AdaptiveWearObserver(observer_params())

    def run_observer() -> None:
        s = obs.initial_state()
        for k0 in range(0, n, block):
            s, _ = obs.step(s, tr.force[k0 : k0 + block], feed[k0 : k0 + block])

    run_observer()
    wall = _median_time(run_observer, repeats)
    out["observer_realtime_factor"] = sim_seconds / wall
    out["observer_block_us"] = wall / -(-n // block) * 1e6

    # the monitor, one pass per call (as the live machine calls it)
    passes = 150
    t = np.arange(1, passes + 1) * 0.2
    F = 520.0 + 90.0 * np.sqrt(t)
    mon = ToolLifeMonitor(ToolLifeParams(force_per_flank_wear=900.0))

    def run_monitor() -> None:
        s = mon.initial_state()
        for j in range(passes):
            s, _ = mon.step(s, t[j : j + 1], F[j : j + 1], feed[j : j + 1])

    run_monitor()
    out["monitor_pass_us"] = _median_time(run_monitor, repeats) / passes * 1e6

    # the monitor as the live machine builds it (remaining life from the wear law,
    # refitted every pass) over one tool life of 0.2-min passes of the model's force
    law_mon = AcceleratedToolWear(feed=0.1).monitor
    tp = model.simulate(np.full(150, 0.1), 0.2)
    Fp = tp.force

    def run_law_monitor() -> None:
        s = law_mon.initial_state()
        for j in range(passes):
            s, _ = law_mon.step(s, t[j : j + 1], Fp[j : j + 1], feed[j : j + 1])

    run_law_monitor()
    out["monitor_law_pass_us"] = _median_time(run_law_monitor, repeats) / passes * 1e6
    x_end = tr.states[-1]
    out["linearise_n200_ms"] = (
        _median_time(lambda: design_linear_model(model, 0.1, x_end), repeats) * 1e3
    )
    return out
