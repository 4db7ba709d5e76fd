"""The simulated machine tool: a source of measurements (pure numpy/numba, no I/O).

Imports nothing of ours outside this package. Public names of the two-inertia stage
(seed 000) are re-exported here; the other machines (seed 002's x-axis, seed 003's
milling and feed drives, seed 004's wear model) live in their own modules.
"""

from machine.effects import EFFECT_NAMES, PlantEffects
from machine.errors import MachineError, ParameterError
from machine.params import ADDED_WEIGHT_INERTIA, PRESETS, SAMPLE_TIME, StageParams, preset
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
    "preset",
]
