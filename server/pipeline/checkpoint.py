"""A live pipeline's state as one object, and its checkpoint file.

:class:`PipelineState` is everything a :class:`~server.pipeline.live_pipeline.LivePipeline`
carries from block to block: the source's place (the simulated stage, a log's position;
nothing for a live feed), every estimator's state (the observers, the RLS covariances,
the segment identifier's tracks, the harmonic observer, the effects), the scenario's
own (spindle factor, mounted weight, workpiece, the tool and its wear monitor, the
eccentricity loop with its tuner, the part program and the process monitor's taught
limits), the knobs, the installed effects and the latest
values. It is a plain value: a pipeline built for the same scenario and source continues
from it (:meth:`LivePipeline.restore`), in this process or another.

The file is :mod:`common.state_io`'s (npz + JSON header), of kind :data:`KIND` and
version :data:`VERSION`: bump it when a field of the state changes meaning; a file of
another version is refused with :class:`~common.state_io.StateFormatError` naming both
(docs/checkpoints.md).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

from common.state_io import StateFormatError, load_state, save_state
from estimators.observer_effects import ObserverEffect
from machine.stage import CuttingForce
from server.pipeline.eccentricity_part import LiveEccentricity
from server.pipeline.observer_bank import BankState
from server.pipeline.process_part import ProcessState
from server.pipeline.wear_clock import AcceleratedToolWear
from server.pipeline.wear_passes import PassState
from server.pipeline.workpiece import WorkpieceState

#: the checkpoint's kind in the file header
KIND = "cutwatch.pipeline"
#: version of :class:`PipelineState`'s schema
VERSION = 2


@dataclass
class ScriptState:
    """The scenario script's memory: the spindle factor in effect, the weight mounted,
    the plant configuration last applied (its key and the force)."""

    spindle_factor: float
    weight: float
    applied: tuple[Any, ...]
    force: CuttingForce


@dataclass
class ToolState:
    """The tool: its pass under way and the wear model with its life monitor."""

    passes: PassState
    wear: AcceleratedToolWear


@dataclass
class PipelineState:
    """One live pipeline's state (module docstring).

    Attributes
    ----------
    scenario, source
        The scenario's name and the source's (``"simulator"``, ``"replay"``, ``"mqtt"``):
        a pipeline restores only the state of its own scenario and source.
    seed
        The simulation's seed.
    t
        Time of the source [s] when the state was taken.
    knobs, effects
        The knob values and the installed observer effects.
    source_state
        The source's own state (:meth:`MeasurementSource.state`).
    estimators
        The observer bank's state.
    script, workpiece, tool, eccentricity
        The scenario's parts (None when the scenario has no such part).
    latest
        The last value of every channel.
    process
        The part program under way (issue 21): the machine, the drives' observers, the
        block and the injections waiting (None without a part program).
    taught
        The process monitor's state (:meth:`estimators.process_monitor.ProcessMonitor.
        initial_state`: the limits taught per (tool, program, block), the running sums);
        empty without a process monitor. A restarted service resumes its teach-in.
    """

    scenario: str
    source: str
    seed: int
    t: float
    knobs: dict[str, float | bool | str]
    effects: tuple[ObserverEffect, ...]
    source_state: object
    estimators: BankState
    script: ScriptState
    workpiece: WorkpieceState | None
    tool: ToolState | None
    eccentricity: LiveEccentricity | None
    latest: dict[str, float]
    process: ProcessState | None = None
    taught: dict[str, Any] = field(default_factory=dict)


def save_checkpoint(path: str | os.PathLike[str], state: PipelineState) -> None:
    """Write ``state`` to ``path`` (atomically: a crash leaves the previous file)."""
    meta = {"scenario": state.scenario, "source": state.source, "t": float(state.t)}
    save_state(path, state, kind=KIND, version=VERSION, meta=meta)


def load_checkpoint(path: str | os.PathLike[str]) -> PipelineState:
    """The state of a checkpoint file.

    Raises
    ------
    FileNotFoundError
        No file.
    StateFormatError
        Not a checkpoint of this version (named: the file, expected and found).
    """
    state, _ = load_state(path, kind=KIND, version=VERSION)
    if not isinstance(state, PipelineState):
        raise StateFormatError(f"{path}: expected a PipelineState, found {type(state).__name__}")
    return state


__all__ = [
    "KIND",
    "VERSION",
    "PipelineState",
    "ScriptState",
    "ToolState",
    "load_checkpoint",
    "save_checkpoint",
]
