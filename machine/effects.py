"""Optional plant effects, all off by default (the canonical names of docs/design.md).

They make the simulated stage differ from the model the estimators are told about, so
that the residual loop has something real to find. Each effect has a magnitude and its
shape parameters; it acts only when its name is in ``enabled``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from machine.errors import ParameterError, require_nonnegative, require_positive

#: The canonical names (docs/design.md) of the effects the simulator can produce.
EFFECT_NAMES: tuple[str, ...] = (
    "offset",
    "coulomb_asymmetry",
    "stribeck",
    "position_periodic",
    "torque_ripple",
    "backlash",
)


@dataclass(frozen=True)
class PlantEffects:
    """Magnitudes and shapes of the optional effects; ``enabled`` switches them on."""

    enabled: frozenset[str] = field(default_factory=frozenset)
    offset: float = 0.3  # constant load torque (e.g. gravity, cable drag) [N m]
    coulomb_asymmetry: float = 0.4  # F_CL x (1 + a) forward, x (1 - a) backward [-]
    stribeck: float = 0.25  # extra breakaway friction at rest [N m]
    stribeck_velocity: float = 3.0  # Stribeck velocity [rad/s]
    position_periodic: float = 0.2  # load torque periodic in load angle, amplitude [N m]
    position_period: float = 2 * math.pi / 5  # its period in load angle [rad]
    torque_ripple: float = 0.15  # motor torque ripple amplitude [N m]
    torque_ripple_order: int = 6  # ripple periods per motor revolution
    backlash: float = 2e-4  # total gap of the transmission [rad]
    position_phase: float = 0.0  # phase of the position-periodic torque [rad]
    torque_ripple_phase: float = 0.0  # phase of the torque ripple [rad]

    def __post_init__(self) -> None:
        bad = sorted(set(self.enabled) - set(EFFECT_NAMES))
        if bad:
            raise ParameterError("effects", f"names from {list(EFFECT_NAMES)}", bad[0])
        for name in (
            "offset",
            "stribeck",
            "position_periodic",
            "torque_ripple",
            "position_phase",
            "torque_ripple_phase",
        ):
            v = float(getattr(self, name))
            if not math.isfinite(v):
                raise ParameterError(name, "a finite value", v)
        if not (0.0 <= self.coulomb_asymmetry < 1.0):
            raise ParameterError("coulomb_asymmetry", "a value in [0, 1)", self.coulomb_asymmetry)
        require_positive("stribeck_velocity", self.stribeck_velocity)
        require_positive("position_period", self.position_period)
        require_nonnegative("backlash", self.backlash)
        if (
            int(self.torque_ripple_order) != self.torque_ripple_order
            or self.torque_ripple_order < 1
        ):
            raise ParameterError("torque_ripple_order", "an integer >= 1", self.torque_ripple_order)

    def varied(self, rng: np.random.Generator) -> PlantEffects:
        """A copy with magnitudes and shapes drawn around these values (one Monte Carlo case).

        Magnitudes (offset, Stribeck level and velocity, position-periodic and ripple
        amplitudes, backlash gap) are scaled by a factor uniform in [0.7, 1.3]; the
        direction asymmetry is scaled the same way (kept below 0.95); the phases of the
        periodic effects are uniform in [0, 2 pi). Periods and the ripple order are kept
        (they are properties of the mechanics, not of a record).
        """

        def scaled(name: str) -> float:
            return float(getattr(self, name)) * float(rng.uniform(0.7, 1.3))

        return replace(
            self,
            offset=scaled("offset"),
            coulomb_asymmetry=min(scaled("coulomb_asymmetry"), 0.95),
            stribeck=scaled("stribeck"),
            stribeck_velocity=scaled("stribeck_velocity"),
            position_periodic=scaled("position_periodic"),
            torque_ripple=scaled("torque_ripple"),
            backlash=scaled("backlash"),
            position_phase=float(rng.uniform(0.0, 2 * math.pi)),
            torque_ripple_phase=float(rng.uniform(0.0, 2 * math.pi)),
        )

    def with_enabled(self, *names: str) -> PlantEffects:
        return replace(self, enabled=frozenset(names))

    def toggled(self, name: str, on: bool) -> PlantEffects:
        if name not in EFFECT_NAMES:
            raise ParameterError("effect", f"one of {list(EFFECT_NAMES)}", name)
        s = set(self.enabled)
        if on:
            s.add(name)
        else:
            s.discard(name)
        return replace(self, enabled=frozenset(s))

    def vector(self) -> np.ndarray:
        """The effect magnitudes (zero where disabled) packed for the simulation kernel."""
        on = self.enabled

        def m(name: str) -> float:
            return float(getattr(self, name)) if name in on else 0.0

        return np.array(
            [
                m("offset"),
                m("coulomb_asymmetry"),
                m("stribeck"),
                float(self.stribeck_velocity),
                m("position_periodic"),
                float(self.position_period),
                m("torque_ripple"),
                float(self.torque_ripple_order),
                m("backlash"),
                float(self.position_phase),
                float(self.torque_ripple_phase),
            ]
        )
