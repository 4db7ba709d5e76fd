"""Speed of the machining centre's simulation (issue 31) and of its CNC trace export.

Simulated seconds per wall second on one core for the default part program (the whole
part: tool changes, rapids, air moves and cuts in their real proportions), stepped at
the live block size (500 samples: 50 ms at 10 kHz) and at an offline one (10,000
samples: 1 s); the same with the 500 Hz trace exported block by block; and the cost per
simulated second (what the live default pays at 1x). Each also per CPU second of the
process (``sim_s_per_cpu_s``, not normalised: the reference is timed on the wall), the
figure a shared machine disturbs least. The first part is not timed (numba compiles or
loads its cache there).
"""

from __future__ import annotations

import statistics
import time

from machine.centre.sim import MachiningCentre
from machine.centre.trace import CncTrace, TraceParams
from server.experiments.benchmarks import Figures

#: samples of one default part (~31.8 s at 10 kHz)
_PART = 318_000


def _rate(block: int, seconds: float, trace: bool) -> tuple[float, float]:
    m = MachiningCentre()
    st = m.initial_state(seed=0)
    st, _ = m.step(st, 2_000)  # compile / load the cache, outside the timing
    tr = CncTrace(TraceParams(500.0, "sample"), m.sample_time)
    ts = tr.initial_state()
    n = round(seconds / m.sample_time)
    t0, c0 = time.perf_counter(), time.process_time()
    done = 0
    while done < n:
        st, rec = m.step(st, block)
        if trace:
            ts, _ = tr.export(ts, rec)
        done += block
    sim = done * m.sample_time
    return sim / (time.perf_counter() - t0), sim / max(time.process_time() - c0, 1e-9)


def measure(*, repeats: int, quick: bool) -> Figures:
    """Medians of ``repeats`` runs over one part (a third of one with ``quick``)."""
    seconds = (_PART / 3 if quick else _PART) * 1e-4
    out: Figures = {
        "configuration": f"the default part program, {seconds:.1f} s simulated per run, "
        "10 kHz, 1 core",
    }
    for block, label in ((10_000, "offline_block_10000"), (500, "live_block_500")):
        for trace in (False, True):
            key = f"{label}{'.with_trace_500hz' if trace else ''}"
            runs = [_rate(block, seconds, trace) for _ in range(repeats)]
            out[f"{key}.realtime_factor"] = statistics.median(r[0] for r in runs)
            # simulated seconds per CPU second of this process: what the runs cost, less
            # the time other work on a shared machine took from them
            out[f"{key}.sim_s_per_cpu_s"] = statistics.median(r[1] for r in runs)
    live = float(out["live_block_500.with_trace_500hz.sim_s_per_cpu_s"])  # type: ignore[arg-type]
    out["live_block_500.with_trace_500hz.cpu_share_at_1x"] = 1.0 / live
    out["realtime_factor"] = out["live_block_500.with_trace_500hz.realtime_factor"]
    return out
