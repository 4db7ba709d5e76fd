"""The simulated machine tool: a source of measurements (pure numpy/numba, no I/O).

Imports nothing of ours outside this package. Public names of the two-inertia stage
(seed 000) are re-exported here; the other machines are re-exported as their modules:
``xy_axis`` (seed 002), ``milling`` and ``feed_drives`` (seed 003), ``tool_wear``
(seed 004); ``centre`` (the 3-axis machining centre with its spindle drive and its CNC
trace, issue 31); chatter (docs/chatter.md): ``regeneration`` (the regenerative cut's
kernels), ``chatter`` (a flexible tool on a rigid machine), ``milling_regen`` (seed 003's
machine with a flexible tool), ``spindle`` (the spindle drive) and ``signal_chain`` (what
the drives see). The matrix exponential they share with the estimators is
:mod:`common.linalg`.
"""

from machine import (
    centre,
    chatter,
    feed_drives,
    milling,
    milling_regen,
    regeneration,
    signal_chain,
    spindle,
    tool_wear,
    xy_axis,
)
from machine.effects import EFFECT_NAMES, PlantEffects
from machine.errors import MachineError, ParameterError
from machine.stage import (
    SEED000_FORCE,
    SEED001_FORCE,
    CuttingForce,
    Measurements,
    StageConfig,
    StageSim,
    Trajectory,
    Truth,
)
from machine.stage_params import ADDED_WEIGHT_INERTIA, PRESETS, SAMPLE_TIME, StageParams, preset

__all__ = [
    "ADDED_WEIGHT_INERTIA",
    "EFFECT_NAMES",
    "PRESETS",
    "SAMPLE_TIME",
    "SEED000_FORCE",
    "SEED001_FORCE",
    "CuttingForce",
    "MachineError",
    "Measurements",
    "ParameterError",
    "PlantEffects",
    "StageConfig",
    "StageParams",
    "StageSim",
    "Trajectory",
    "Truth",
    "centre",
    "chatter",
    "feed_drives",
    "milling",
    "milling_regen",
    "preset",
    "regeneration",
    "signal_chain",
    "spindle",
    "tool_wear",
    "xy_axis",
]
