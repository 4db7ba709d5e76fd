"""Tool wear: seed 004's adaptive wear observer and its linear models (``linear``,
``observer``), the tool-life monitor and its reduced wear law (``monitor``, ``law``), the
lathe's flank wear per segment (``turning``), the unseen-tool hybrid and its per-machine
calibration (``hybrid``, ``calibration``) and the machining centre's wear per tool from the
spindle's cutting power (``centre``)."""

from estimators.wear import (
    calibration,
    centre,
    hybrid,
    law,
    linear,
    monitor,
    observer,
    turning,
)

__all__ = [
    "calibration",
    "centre",
    "hybrid",
    "law",
    "linear",
    "monitor",
    "observer",
    "turning",
]
