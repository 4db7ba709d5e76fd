"""Residual analysis speed: 1,000,000 samples (budget, docs/design.md: < 10 s).

A closed-form rigid-axis record (M = 20 kg, Fv = 100, Fc = 8, offset = -1, a 3 N
position-periodic effect of period 2.5 mm, 1 N noise) sampled at 1 kHz. Measured:
the analysis alone (IDIM-LS nominal fit, every candidate family, greedy selection,
unexplained structure) and end to end (read the CSV log, analyse, write the report).
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from server.experiments.benchmarks import Figures


def _record(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    w1, w2 = 2 * np.pi * 0.3, 2 * np.pi * 1.1
    q = 0.05 * np.sin(w1 * t) + 0.01 * np.sin(w2 * t + 0.3)
    qd = 0.05 * w1 * np.cos(w1 * t) + 0.01 * w2 * np.cos(w2 * t + 0.3)
    qdd = -0.05 * w1**2 * np.sin(w1 * t) - 0.01 * w2**2 * np.sin(w2 * t + 0.3)
    f = 20 * qdd + 100 * qd + 8 * np.sign(qd) - 1.0 + 3 * np.sin(2 * np.pi * q / 0.0025)
    return {"t": t, "tau_m": f + rng.normal(0.0, 1.0, n), "q_m": q}


def measure(*, repeats: int, quick: bool) -> Figures:
    """Median wall time of the residual analysis of one record (seconds)."""
    from estimators.residual.engine import analyse
    from estimators.residual.rigid import RigidModel
    from server.records.measured_log import load_log, write_log
    from server.records.residual_report import write_report

    n = 100_000 if quick else 1_000_000
    cols = _record(n)
    analysis: list[float] = []
    end_to_end: list[float] = []
    selected: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.csv"
        write_log(path, cols, {"units": {"effort": "N", "position": "m"}, "kind": "rigid"})
        for _ in range(repeats):
            t0 = time.perf_counter()
            res = analyse(RigidModel(cols["q_m"], cols["tau_m"], cols["t"], 1e-3))
            analysis.append(time.perf_counter() - t0)
            selected = [e.name for e in res.effects]
            t0 = time.perf_counter()
            log = load_log(path)
            res = analyse(RigidModel(log["q_m"], log["tau_m"], log["t"], log.sample_time))
            write_report(Path(tmp) / "out", log, res)
            end_to_end.append(time.perf_counter() - t0)
    return {
        "samples": n,
        "analysis_seconds": statistics.median(analysis),
        "end_to_end_seconds": statistics.median(end_to_end),
        "analysis_samples_per_second": n / statistics.median(analysis),
        "analysis_realtime_factor": n * 1e-3 / statistics.median(analysis),
        "selected": ",".join(selected) or "none",
    }
