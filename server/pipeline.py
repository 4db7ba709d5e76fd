"""Pipeline wiring: the simulated machine feeding every estimator, block by block.

PROVISIONAL STUB (being replaced by the foundation's real stage + observers).
The public surface below is the contract the live service builds on:

- ``LivePipeline(scenario: str = "default", seed: int = 0)``
- ``.sample_time`` (s), ``.t`` (simulated time, s)
- ``.channels() -> list[Channel]``: every per-sample output, with unit and group
- ``.step(n) -> dict[str, np.ndarray]``: advance ``n`` samples; one float64 array of
  length ``n`` per channel name (plus ``"t"``)
- ``.knobs() -> dict[str, Knob]``: live-tweakable parameters with their ranges
- ``.set_knob(name, value)``: validated; raises ``ParameterError`` naming the field, the
  allowed range and the value; nothing changes on error
- ``.reset()``; ``.snapshot() -> dict`` (latest values, truths, knob values)
- ``SCENARIOS``: name -> one-line description
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from estimators.errors import ParameterError


@dataclass(frozen=True)
class Channel:
    name: str
    unit: str
    group: str
    label: str


@dataclass
class Knob:
    name: str
    value: float | bool | str
    min: float | None
    max: float | None
    unit: str
    doc: str
    choices: tuple[str, ...] | None = None


SCENARIOS: dict[str, str] = {
    "default": "X stage reciprocating while milling; workpiece losing mass; spindle changes",
}


class LivePipeline:
    def __init__(self, scenario: str = "default", seed: int = 0) -> None:
        if scenario not in SCENARIOS:
            raise ParameterError("scenario", f"one of {sorted(SCENARIOS)}", scenario)
        self.scenario = scenario
        self.seed = seed
        self.sample_time = 4e-4
        self._knobs = {
            "spindle_rpm": Knob("spindle_rpm", 1500.0, 100.0, 12000.0, "rpm", "spindle speed"),
            "weight_on": Knob("weight_on", False, None, None, "", "added load weight"),
        }
        self.reset()

    def reset(self) -> None:
        self.t = 0.0
        self._k = 0

    def channels(self) -> list[Channel]:
        return [
            Channel("force_true", "N m", "force", "true cutting torque"),
            Channel("force_fixed", "N m", "force", "fixed-parameter observer"),
        ]

    def knobs(self) -> dict[str, Knob]:
        return dict(self._knobs)

    def set_knob(self, name: str, value: float | bool | str) -> None:
        if name not in self._knobs:
            raise ParameterError("name", f"one of {sorted(self._knobs)}", name)
        k = self._knobs[name]
        if k.min is not None and k.max is not None:
            v = float(value)
            if not (math.isfinite(v) and k.min <= v <= k.max):
                raise ParameterError(name, f"a value in [{k.min:g}, {k.max:g}] {k.unit}", value)
        k.value = value

    def step(self, n: int) -> dict[str, np.ndarray]:
        t = self.t + self.sample_time * np.arange(1, n + 1)
        f = float(self._knobs["spindle_rpm"].value) / 60.0 * 4
        true = 0.2 + 0.1 * np.sin(2 * np.pi * f * t)
        self.t = float(t[-1])
        self._k += n
        return {"t": t, "force_true": true, "force_fixed": true * 0.9}

    def snapshot(self) -> dict[str, object]:
        return {"t": self.t, "scenario": self.scenario,
                "knobs": {k: v.value for k, v in self._knobs.items()}}
