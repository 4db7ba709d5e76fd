"""The reference workload of ``cutwatch bench``: a fixed yardstick measured in the same run.

A benchmark's raw speed says as much about the machine (clock, turbo, cache, what else
runs on it) as about the code: the same commit measured 325-344x on one 2-core box and
938-952x on another of the same kind (issue 22). ``cutwatch bench`` therefore times this
workload before and after its groups and states every figure also as a ratio to it:
the figure as it would read on a machine on which one reference run takes exactly 1 s
(speeds times the reference's seconds, costs divided by them; :func:`normalise`).

The workload is a small, deterministic mix of what the pipeline spends its time on, in
three parts of about equal weight on the machine it was written on:

- **numba**: a compiled per-sample loop (a two-mass drive with PI control, tanh
  friction and a sinusoidal force, a ring buffer read one period back), like the
  simulators' and observers' kernels;
- **numpy**: per-block array work on 500-sample blocks (trigonometry, sums, a small
  matrix product, a search, stacking), like the estimators' block steps;
- **python**: interpreter work (dicts of floats, small objects, ``math`` calls, list
  appends), like the per-block and per-revolution glue.

It is self-contained on purpose: it calls nothing of the project, so making the project
faster never moves the yardstick. Changing it breaks the comparison with every earlier
figure: do not; if it must change, raise :data:`REFERENCE_VERSION` (printed with every
result) so old and new ratios are not compared.
"""

from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass

import numpy as np
from numba import njit

#: raise when the workload changes (ratios of different versions do not compare)
REFERENCE_VERSION = 1

#: sizes of the three parts (fixed: they define the yardstick)
_KERNEL_SAMPLES = 12_000_000
_NUMPY_BLOCKS = 5_000
_PYTHON_ROUNDS = 120_000


@njit(cache=True)
def _kernel(n: int, hist: np.ndarray) -> float:  # pragma: no cover
    """The numba part: ``n`` samples of a two-mass drive under PI position control."""
    ts = 2e-4
    x1 = v1 = x2 = v2 = integ = 0.0
    acc = 0.0
    hlen = hist.shape[0]
    for k in range(n):
        t = k * ts
        ref = 0.01 * math.sin(2.0 * math.pi * 0.5 * t)
        e = ref - x1
        integ += ts * e
        u = 400.0 * e + 2000.0 * integ - 20.0 * v1
        f_load = 3.0 * math.sin(2.0 * math.pi * 37.0 * t) + 0.5 * math.tanh(v2 / 1e-3)
        spring = 5e3 * (x1 - x2) + 2.0 * (v1 - v2)
        a1 = (u - spring - 0.8 * math.tanh(v1 / 1e-3)) / 0.02
        a2 = (spring - f_load) / 0.05
        v1 += ts * a1
        x1 += ts * v1
        v2 += ts * a2
        x2 += ts * v2
        head = k % hlen
        hist[head] = x2
        back = hist[(head - 97) % hlen]
        acc += (x2 - back) * (x2 - back)
    return acc


def _numpy_part(blocks: int) -> float:
    """The numpy part: per-block work on 500-sample blocks."""
    n = 500
    t = np.arange(n) * 4e-4
    m = np.array([[1.0, 0.2, 0.0], [0.2, 2.0, 0.1], [0.0, 0.1, 3.0]])
    grid = np.linspace(0.0, 1.0, 64)
    total = 0.0
    for b in range(blocks):
        ph = t + b * 0.2
        f = 100.0 + 3.0 * np.cos(2.0 * np.pi * 50.0 * ph) + np.sin(2.0 * np.pi * 7.0 * ph)
        fm = f - float(np.sum(f)) / n
        re = float(fm @ np.cos(ph))
        x = np.vstack([fm, np.abs(fm), fm * fm])
        g = m @ (x @ x.T) @ m.T
        idx = np.searchsorted(grid, np.mod(ph, 1.0))
        e = np.clip(idx - 1, 0, 63)
        total += re + float(np.trace(g)) * 1e-9 + float(np.mean(grid[e]))
    return total


@dataclass(frozen=True)
class _Sample:
    t: float
    value: float
    unit: str


def _python_part(rounds: int) -> float:
    """The interpreter part: dicts, small objects, ``math`` calls, list appends."""
    names = ("f_fixed", "f_adaptive", "f_switching", "f_segment", "vb_est", "life_left")
    latest: dict[str, float] = {}
    log: list[_Sample] = []
    acc = 0.0
    for k in range(rounds):
        t = k * 0.05
        row = {name: math.sin(t + i) * (i + 1.0) for i, name in enumerate(names)}
        latest.update(row)
        if k % 4 == 0:
            log.append(_Sample(t, math.hypot(row["f_fixed"], row["f_adaptive"]), "N"))
            if len(log) > 64:
                del log[:-64]
        key = (round(t, 3), "esc" if k % 2 else "fast", latest["vb_est"] > 0.0)
        acc += len(str(key)) + max(latest.values()) - min(latest.values())
        acc += sum(s.value for s in log[-4:]) * 1e-3
    return acc


def run_once() -> dict[str, float]:
    """One reference run: the seconds of each part and their sum (``seconds``, wall
    clock like the groups), and the process's CPU time over it (``cpu_seconds``: wall
    well above CPU means the machine was busy with other work)."""
    hist = np.zeros(256)
    _kernel(1000, hist)  # compiled or loaded from the cache: not timed
    out: dict[str, float] = {}
    c0 = time.process_time()
    t0 = time.perf_counter()
    _kernel(_KERNEL_SAMPLES, hist)
    t1 = time.perf_counter()
    _numpy_part(_NUMPY_BLOCKS)
    t2 = time.perf_counter()
    _python_part(_PYTHON_ROUNDS)
    t3 = time.perf_counter()
    out["cpu_seconds"] = time.process_time() - c0
    out["numba_seconds"] = t1 - t0
    out["numpy_seconds"] = t2 - t1
    out["python_seconds"] = t3 - t2
    out["seconds"] = t3 - t0
    return out


@dataclass
class Reference:
    """The reference runs of one ``cutwatch bench``: before and after the groups."""

    runs: list[dict[str, float]]

    @property
    def seconds(self) -> float:
        """The reference's time on this machine now: the median over every run [s]."""
        return float(statistics.median(r["seconds"] for r in self.runs))

    @property
    def cpu_seconds(self) -> float:
        """The process's CPU time over a reference run: the median over every run [s]."""
        return float(statistics.median(r.get("cpu_seconds", math.nan) for r in self.runs))

    @property
    def wall_over_cpu(self) -> float:
        """Wall over CPU time of the reference: above 1 the run waited for a core."""
        cpu = self.cpu_seconds
        return self.seconds / cpu if cpu > 0 else math.nan

    def as_dict(self) -> dict[str, float | list[float]]:
        runs = [r["seconds"] for r in self.runs]
        cpu = self.cpu_seconds
        return {
            "version": REFERENCE_VERSION,
            "seconds": self.seconds,
            "runs_seconds": runs,
            "spread": max(runs) / min(runs),
            "cpu_seconds": cpu,
            # > 1: the process waited for a core (other work on the machine)
            "wall_over_cpu": self.wall_over_cpu,
            **{
                f"{part}_seconds": float(statistics.median(r[f"{part}_seconds"] for r in self.runs))
                for part in ("numba", "numpy", "python")
            },
        }


def measure(runs: int) -> list[dict[str, float]]:
    """``runs`` reference runs."""
    return [run_once() for _ in range(max(1, runs))]


#: wall over CPU time of the reference above which ``cutwatch bench`` says the machine
#: was busy (its ratios then mostly measure the share of a core the run got)
BUSY_WALL_OVER_CPU = 1.2

#: keys of a group's result that are latencies or sizes, not speeds or costs
_NOT_SPEED = ("latency", "lag", "rss", "slope", "window", "duration", "slow_client_s", "warmup")


def normalise(key: str, value: float, ref_seconds: float) -> float | None:
    """The figure on a machine on which one reference run takes 1 s, or None when
    ``key`` is not a speed or a cost.

    Speeds (``*realtime_factor``, ``*samples_per_second``) are multiplied by the
    reference's seconds; costs (``*_seconds``, ``*_ms``, ``*_us``, CPU shares
    ``cpu_percent*``/``cpu_pct*``) are divided by them. Latencies, lags, memory,
    durations and counts are not normalised (they are not CPU speed).
    """
    if not math.isfinite(value) or ref_seconds <= 0.0:
        return None
    k = key.lower()
    if any(word in k for word in _NOT_SPEED):
        return None
    if k.endswith("realtime_factor") or k.endswith("samples_per_second"):
        return value * ref_seconds
    last = k.rsplit(".", 1)[-1]
    if (
        k.endswith(("_seconds", "_ms", "_us"))
        or ".per_block_ms." in k
        or last.startswith(("cpu_percent", "cpu_pct"))
        or ".cpu_pct" in k
        or k.startswith("cpu_pct")
    ):
        return value / ref_seconds
    return None


__all__ = [
    "BUSY_WALL_OVER_CPU",
    "REFERENCE_VERSION",
    "Reference",
    "measure",
    "normalise",
    "run_once",
]
