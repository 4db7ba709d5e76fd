"""Parameters of the two-inertia ball-screw stage (seed 000 Fig. 1-2) and its presets.

Units: rotary — inertia [kg m^2], torque [N m], angle [rad], angular velocity [rad/s].

The torsion stiffness
---------------------
Seed 000 Table I prints K = 1.7e4 "N/mm^2" and seed 001 Table 1 prints 24 000 "N/mm^2":
the unit is garbled (a stiffness of a shaft in a rotary model is N m/rad) and the two
papers disagree. We choose K so that the first (two-inertia) resonance

.. math:: f_r = \\frac{1}{2\\pi}\\sqrt{K\\,(1/J_M + 1/J_L)}

lies at about 400 Hz for each preset — "a few hundred Hz", above the 250 Hz band of
Q(s) and above the 100/200 Hz force harmonics, as on the papers' bench where the encoders on
both sides are what removes the resonance from the estimate. Seed 000: K = 900 N m/rad
(f_r = 402 Hz, anti-resonance sqrt(K/J_L)/2pi = 285 Hz). Seed 001: K = 9400 N m/rad
(f_r = 399 Hz, anti-resonance 273 Hz).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

from machine.errors import ParameterError, require_nonnegative, require_positive

#: Seed 000 Table II: sampling period 0.4 ms
SAMPLE_TIME = 4e-4
#: Seed 000 Table II: 20-bit encoders on both sides
ENCODER_BITS = 20
#: Seed 000 Fig. 7(b): the weight added on the load side [kg m^2]
ADDED_WEIGHT_INERTIA = 2.92e-4


@dataclass(frozen=True)
class StageParams:
    """Physical parameters of the two-inertia stage (true plant, or a nominal model)."""

    J_M: float  # motor-side inertia [kg m^2]
    J_L: float  # load-side inertia [kg m^2]
    K: float  # torsion stiffness [N m/rad] (see module docstring)
    K_t: float  # motor torque constant [N m/A]
    B_M: float  # motor-side viscous friction [N m s/rad]
    B_L: float  # load-side viscous friction [N m s/rad]
    F_CM: float  # motor-side Coulomb friction [N m]
    F_CL: float  # load-side Coulomb friction [N m]
    C_s: float = 0.0  # shaft damping [N m s/rad]; the papers' model has none

    def __post_init__(self) -> None:
        for name in ("J_M", "J_L", "K", "K_t"):
            require_positive(name, getattr(self, name))
        for name in ("B_M", "B_L", "F_CM", "F_CL", "C_s"):
            require_nonnegative(name, getattr(self, name))

    @property
    def resonance_hz(self) -> float:
        """First (two-inertia) resonance frequency [Hz]."""
        return math.sqrt(self.K * (1 / self.J_M + 1 / self.J_L)) / (2 * math.pi)

    @property
    def antiresonance_hz(self) -> float:
        """Anti-resonance of the motor-side response [Hz]."""
        return math.sqrt(self.K / self.J_L) / (2 * math.pi)

    def with_(self, **changes: float) -> StageParams:
        return replace(self, **changes)

    def as_dict(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}


#: Seed 000 Table I (K chosen, see module docstring)
OHNO2021 = StageParams(
    J_M=2.80e-4, J_L=2.80e-4, K=900.0, K_t=0.5710, B_M=0.002, B_L=0.002, F_CM=0.15, F_CL=0.15
)
#: Seed 001 Table 1 (K chosen, see module docstring)
OHNO_SWITCHING = StageParams(
    J_M=2.8e-3, J_L=3.2e-3, K=9400.0, K_t=0.5710, B_M=0.002, B_L=0.002, F_CM=0.15, F_CL=0.15
)

PRESETS: dict[str, StageParams] = {
    "seed000": OHNO2021,
    "seed001": OHNO_SWITCHING,
}


def preset(name: str) -> StageParams:
    """The named parameter preset (``seed000`` default, ``seed001``)."""
    try:
        return PRESETS[name]
    except KeyError:
        raise ParameterError("preset", f"one of {sorted(PRESETS)}", name) from None
