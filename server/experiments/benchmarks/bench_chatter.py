"""Speed of the chatter pieces: the regenerative cut, seed 003's machine with a flexible
tool, and the stability lobes.

- the benchmark's cut on a rigid machine (Insperger & Stepan's 1-DOF tool, two flutes,
  a/D = 1, 10000 rpm, 0.3 mm; 64 steps per mode period, 59 kHz): simulated seconds per
  wall second;
- seed 003's machine (4 flutes, 10 layers, X/Y drives at 5 kHz, spindle loop) with
  :data:`machine.milling_regen.DEMO_STRUCTURE` (four modes; 16 sub-steps per drive
  sample), case 1's cut: simulated seconds per wall second, beside the rigid machine;
- the semi-discretization: one critical multiplier at m = 100 and m = 400 (ms), and one
  speed of a lobe chart (the boundary by scan and bisection, ms).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable

import numpy as np

from common.cut_geometry import CutGeometry
from common.modes import BENCHMARK_1DOF
from estimators.chatter.lobes import lobe_chart
from estimators.chatter.sd import SemiDiscretization
from machine.chatter import ChatterCut, ChatterCutParams
from machine.milling import MillingMachine, MillingParams
from machine.milling_regen import DEMO_STRUCTURE
from server.experiments.benchmarks import Figures

CUT = CutGeometry(2, 1.0, True, 6e8, 2e8)


def _median(fn: Callable[[], float], repeats: int) -> float:
    return float(statistics.median(fn() for _ in range(repeats)))


def _cut_rate(seconds: float) -> float:
    cut = ChatterCut(ChatterCutParams(BENCHMARK_1DOF, CUT, 0.3e-3, 10000.0))
    cut.step(100)  # compiled (or loaded from the cache) outside the timing
    n = round(seconds / cut.dt)
    t0 = time.perf_counter()
    cut.step(n)
    return n * cut.dt / (time.perf_counter() - t0)


def _mill_rate(seconds: float, flexible: bool) -> float:
    m = MillingMachine(MillingParams(), structure=DEMO_STRUCTURE if flexible else None)
    m.step(50)
    n = round(seconds / m.sample_time)
    t0 = time.perf_counter()
    m.step(n)
    return n * m.sample_time / (time.perf_counter() - t0)


def _multiplier_ms(m: int) -> float:
    sd = SemiDiscretization(BENCHMARK_1DOF, CUT, m)
    sd.multiplier(10000.0, 0.3e-3)
    t0 = time.perf_counter()
    for _ in range(5):
        sd.multiplier(10000.0, 0.3e-3)
    return (time.perf_counter() - t0) / 5 * 1e3


def _chart_speed_ms() -> float:
    lobe_chart(BENCHMARK_1DOF, CUT, np.array([10000.0]))
    t0 = time.perf_counter()
    lobe_chart(BENCHMARK_1DOF, CUT, np.array([9000.0, 11000.0]))
    return (time.perf_counter() - t0) / 2 * 1e3


def measure(*, repeats: int, quick: bool) -> Figures:
    """Medians over ``repeats`` runs."""
    seconds = 0.5 if quick else 5.0
    mill = 0.2 if quick else 2.0
    res: Figures = {
        "config": f"benchmark cut {seconds:g} s; seed 003 machine {mill:g} s per run",
        "cut_realtime_factor": _median(lambda: _cut_rate(seconds), repeats),
        "flexible_mill_realtime_factor": _median(lambda: _mill_rate(mill, True), repeats),
        "rigid_mill_realtime_factor": _median(lambda: _mill_rate(mill, False), repeats),
        "sd_multiplier_m100_ms": _median(lambda: _multiplier_ms(100), repeats),
        "sd_multiplier_m400_ms": _median(lambda: _multiplier_ms(400), repeats),
        "lobe_chart_ms_per_speed": _median(_chart_speed_ms, repeats),
    }
    res["realtime_factor"] = res["cut_realtime_factor"]
    return res
