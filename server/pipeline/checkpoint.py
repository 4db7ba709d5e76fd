"""A live pipeline's state as one object, and its checkpoint file.

:class:`PipelineState` is everything a :class:`~server.pipeline.live_pipeline.LivePipeline`
carries from block to block: the source's place (the simulated stage, a log's position;
a live feed's time), the scenario script's memory (spindle factor, mounted weight, the
plant configuration applied), every part's state by its name (:meth:`Part.state`: the
stage observers' filters, RLS covariances and segment tracks; the DFO; the installed
effects; the workpiece; the tool and its wear monitor; the eccentricity loop with its
tuner; the part program and the process monitor's taught limits), the knobs and the
latest values. It is a plain value: a pipeline built for the same scenario, source and
parts continues from it (:meth:`LivePipeline.restore`), in this process or another.

The file is :mod:`common.state_io`'s (npz + JSON header), of kind :data:`KIND` and
version :data:`VERSION`: bump it when a field of the state changes meaning; a file of
another version is refused with :class:`~common.state_io.StateFormatError` naming both
(docs/checkpoints.md). Version 3 (issue 26): the parts' states by name, each part's its
own (version 2 kept the eccentricity part as the object itself).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

from common.state_io import JsonNode, StateFormatError, load_state, save_state
from machine.stage import CuttingForce

#: the checkpoint's kind in the file header
KIND = "cutwatch.pipeline"
#: version of :class:`PipelineState`'s schema
VERSION = 3


@dataclass
class ScriptState:
    """The scenario script's memory: the spindle factor in effect, the weight mounted,
    the plant configuration last applied (its key and the force)."""

    spindle_factor: float
    weight: float
    applied: tuple[Any, ...]
    force: CuttingForce


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
    knobs
        The knob values.
    source_state
        The source's own state (:meth:`MeasurementSource.state`).
    script
        The scenario script's memory.
    parts
        Every part's state (:meth:`Part.state`), by the part's name; a pipeline restores
        only a state of the same parts.
    latest
        The last value of every channel.
    """

    scenario: str
    source: str
    seed: int
    t: float
    knobs: dict[str, float | bool | str]
    source_state: object
    script: ScriptState
    parts: dict[str, Any] = field(default_factory=dict)
    latest: dict[str, float] = field(default_factory=dict)


def save_checkpoint(path: str | os.PathLike[str], state: PipelineState) -> None:
    """Write ``state`` to ``path`` (atomically: a crash leaves the previous file)."""
    meta: dict[str, JsonNode] = {
        "scenario": state.scenario,
        "source": state.source,
        "t": float(state.t),
    }
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
    "load_checkpoint",
    "save_checkpoint",
]
