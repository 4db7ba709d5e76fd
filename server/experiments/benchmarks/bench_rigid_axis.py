"""The live rigid identifier's cost: machine-seconds of one axis per wall second.

One simulated rigid axis (``machine/rigid_axis.py``) at 1 kHz and at 500 Hz (a CNC's
trace), identified in the feed's blocks of 50 ms (estimators/rigid_id.py: parallel
filter, rows, exponentially weighted least squares, a Newey-West refresh every second of
motion), with the base model and with six effect columns (a residual report's
coulomb_asymmetry, force_lag and position_harmonics of 2 harmonics with direction); and
the per-block cost at two record lengths (it must be flat: the kept rows are bounded).
The record is simulated before the clock starts: this is the estimation cost alone.
"""

from __future__ import annotations

import time

import numpy as np

from estimators.rigid_id import LiveEffect, RigidIdentifier, rigid_design
from machine.rigid_axis import RigidAxisParams, simulate_rigid_axis
from server.experiments.benchmarks import Figures

EFFECTS = (
    LiveEffect.of("coulomb_asymmetry", {}),
    LiveEffect.of("force_lag", {"M": 95.0, "Fv": 200.0}),
    LiveEffect.of("position_harmonics", {"period": 2.5e-3, "harmonics": 2.0, "direction": 1.0}),
)


def _rate(rate: float, seconds: float, effects: tuple[LiveEffect, ...]) -> tuple[float, float]:
    ts = 1.0 / rate
    rec = simulate_rigid_axis(RigidAxisParams(sample_time=ts), seconds, np.random.default_rng(0))
    ident = RigidIdentifier(rigid_design(ts, effects=effects)[0])
    st = ident.initial_state()
    block = int(round(0.05 / ts))
    st, _ = ident.step(st, rec["t"][:block], rec["q_m"][:block], rec["tau_m"][:block])  # warm up
    n = len(rec["t"])
    t0 = time.perf_counter()
    blocks = 0
    for a in range(block, n - block + 1, block):
        st, _ = ident.step(st, rec["t"][a : a + block], rec["q_m"][a : a + block],
                           rec["tau_m"][a : a + block])  # fmt: skip
        blocks += 1
    wall = time.perf_counter() - t0
    return blocks * block * ts / wall, wall / blocks


def measure(*, repeats: int, quick: bool) -> Figures:
    short, long_ = (10.0, 30.0) if quick else (30.0, 120.0)
    out: Figures = {
        "configuration": "one rigid axis, 50 ms blocks, estimation only (simulated before "
        "the clock), 1 core"
    }
    for rate in (1000.0, 500.0):
        for effects, tag in (((), "base"), (EFFECTS, "effects")):
            label = f"{rate:g}Hz.{tag}"
            rates, cs, cl = [], [], []
            for _ in range(repeats):
                r, c_s = _rate(rate, short, effects)
                rates.append(r)
                cs.append(c_s)
                cl.append(_rate(rate, long_, effects)[1])
            out[f"{label}.realtime_factor"] = float(np.median(rates))
            out[f"{label}.per_block_ms.run_{short:g}s"] = 1e3 * float(np.median(cs))
            out[f"{label}.per_block_ms.run_{long_:g}s"] = 1e3 * float(np.median(cl))
    out["realtime_factor"] = out["1000Hz.base.realtime_factor"]
    return out
