"""Benchmark of the broker's drive-block wire format: binary columns against JSON.

One live-size block (125 samples = 50 ms at 2.5 kHz; tau_m, q_m, q_l, f_ext), encoded and
decoded: bytes per block and microseconds per round trip (median of ``repeats`` runs of
many blocks). The choice of the binary format in docs/broker.md rests on these numbers.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from server.experiments.benchmarks import Figures
from server.records.drive_wire import (
    decode_drive,
    decode_drive_json,
    encode_drive,
    encode_drive_json,
)

NAME = "broker"
UNITS = {"effort": "N m", "position": "rad"}


def _block(n: int = 125) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    return {
        "tau_m": rng.normal(size=n),
        "q_m": 100.0 + np.cumsum(rng.normal(size=n)) * 1e-3,
        "q_l": 10.0 + np.cumsum(rng.normal(size=n)) * 1e-4,
        "f_ext": rng.normal(size=n),
    }


def _us(fn: Callable[[], object], count: int, repeats: int) -> float:
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(count):
            fn()
        runs.append((time.perf_counter() - t0) / count)
    return 1e6 * float(np.median(runs))


def measure(*, repeats: int, quick: bool) -> Figures:
    cols = _block()
    count = 300 if quick else 3000
    variants: dict[str, tuple[Callable[[], bytes], Callable[[bytes], object]]] = {
        "binary_f32": (
            lambda: encode_drive(1, 0.0, 4e-4, cols, UNITS),
            decode_drive,
        ),
        "binary_f64": (
            lambda: encode_drive(1, 0.0, 4e-4, cols, UNITS, {k: "<f8" for k in cols}),
            decode_drive,
        ),
        "json": (lambda: encode_drive_json(1, 0.0, 4e-4, cols, UNITS), decode_drive_json),
    }
    out: Figures = {
        "configuration": "one 125-sample block of tau_m, q_m, q_l, f_ext; encode + decode"
    }
    for name, (enc, dec) in variants.items():
        payload = enc()
        out[f"{name}.bytes"] = len(payload)

        def round_trip(e: Callable[[], bytes] = enc, d: Callable[[bytes], object] = dec) -> object:
            return d(e())

        out[f"{name}.round_trip_us"] = _us(round_trip, count, repeats)
    return out
