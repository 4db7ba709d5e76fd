"""The canonical effect names (docs/design.md, "Residual report"), defined once.

The simulator (:data:`machine.effects.EFFECT_NAMES`: what it can produce) and the
residual analyses (``FAMILIES`` plus ``NOT_OFFERED`` in :mod:`estimators.residual.rigid` and
:mod:`estimators.residual.two_inertia`: what they can fit, and what they decline with a
reason) use subsets of this list by meaning; ``tests/common/test_effect_names.py`` keeps
every subset inside it and each analysis's fitted plus declined names equal to it.
"""

from __future__ import annotations

#: every canonical effect name; ``none`` means "no effect" (a log without any)
CANONICAL_EFFECT_NAMES: tuple[str, ...] = (
    "none",
    "offset",
    "coulomb_asymmetry",
    "stribeck",
    "position_periodic",
    "torque_ripple",
    "backlash",
    "inertia",
    "viscous",
    "delay",
    "harmonic",
    "drift",
)

#: effects of a real drive, beyond the first list (docs/residual-emps.md): friction that
#: varies along the travel, a force periodic in position of a searched period with a
#: direction part, the whole effort acting late, a first-order force-loop lag. The rigid
#: analysis fits them; the design's list grows by these names (said in the closing note:
#: the design card lives outside this repository).
REAL_DRIVE_EFFECT_NAMES: tuple[str, ...] = (
    "position_friction",
    "position_harmonics",
    "drive_delay",
    "force_lag",
)
