"""Two-inertia residual analysis speed: 1,000,000 samples (budget, docs/design.md: < 10 s).

The record is the simulated stage (seed 000 preset, 400 s at 2.5 kHz) with an
undeclared motor torque ripple, generated in memory. Measured: the analysis alone
(nominal observer, both residual channels, every candidate family, greedy selection,
the corrected observer, unexplained structure). Simulating the record is not timed.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from server.experiments.benchmarks import Figures


def measure(*, repeats: int, quick: bool) -> Figures:
    """Median wall time of one analysis (seconds) and its real-time factor."""
    from estimators.force_observer import LoadParams
    from estimators.residual.engine import analyse
    from estimators.residual.two_inertia import TwoInertiaModel
    from machine.effects import PlantEffects
    from machine.stage import StageConfig, StageSim
    from server.pipeline.stage_run import observer_params_for

    n = 100_000 if quick else 1_000_000
    cfg = StageConfig(effects=PlantEffects().with_enabled("torque_ripple"))
    sim = StageSim(cfg, seed=0)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "tau_m", "q_m", "q_l", "f_ext")}
    done = 0
    while done < n:
        m, _ = sim.step(min(25_000, n - done))
        for k in parts:
            parts[k].append(getattr(m, k))
        done += len(m.t)
    cols = {k: np.concatenate(v) for k, v in parts.items()}
    nom = cfg.params
    op = observer_params_for(cfg)
    lp = LoadParams(J_L=nom.J_L, B_L=nom.B_L, F_CL=nom.F_CL)
    times: list[float] = []
    selected: list[str] = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        model = TwoInertiaModel(
            cols["t"], cols["tau_m"], cols["q_m"], cols["q_l"], op, lp, f_ext=cols["f_ext"]
        )
        res = analyse(model)
        times.append(time.perf_counter() - t0)
        selected = [e.name for e in res.effects]
    med = statistics.median(times)
    return {
        "samples": n,
        "analysis_seconds": med,
        "analysis_samples_per_second": n / med,
        "analysis_realtime_factor": n * cfg.sample_time / med,
        "selected": ",".join(selected) or "none",
    }
