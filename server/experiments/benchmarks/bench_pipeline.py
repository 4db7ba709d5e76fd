"""Benchmark: the live service's whole pipeline, offline (no server, no clients).

``server.pipeline.live_pipeline.LivePipeline`` on the default scenario steps the two-inertia X stage
with its three force observers and both RLS, the harmonic observer (DFO), the tool wear
model and its life monitor, the milling machine with eccentricity on its X/Y drives
with the ESC, and the part program on seed 003's machine with the drives' force
observers and the process monitor (issue 21): every estimator the service runs.
Simulated seconds per wall second (medians) at the live block (125 samples = 50 ms) and
at offline blocks (2500 samples = 1 s), after 2 s of warm-up (compiled kernels loaded,
observers settled).
"""

from __future__ import annotations

import statistics
import time

from server.pipeline.live_pipeline import LivePipeline


def _rate(block: int, seconds: float, repeats: int) -> float:
    rates = []
    for _ in range(repeats):
        p = LivePipeline("default")
        warm = max(1, round(2.0 / (block * p.sample_time)))
        for _ in range(warm):
            p.step(block)
        n = max(1, round(seconds / (block * p.sample_time)))
        t0 = time.perf_counter()
        for _ in range(n):
            p.step(block)
        rates.append(n * block * p.sample_time / (time.perf_counter() - t0))
    return float(statistics.median(rates))


def measure(*, repeats: int, quick: bool) -> dict[str, object]:
    """Realtime factors of the whole live pipeline at two block sizes."""
    seconds = 5.0 if quick else 30.0
    res: dict[str, object] = {
        "config": f"LivePipeline('default'), every estimator, {seconds:g} s simulated per run",
        "live_block_125.realtime_factor": _rate(125, seconds, repeats),
        "offline_block_2500.realtime_factor": _rate(2500, seconds, repeats),
    }
    res["realtime_factor"] = res["offline_block_2500.realtime_factor"]
    return res
