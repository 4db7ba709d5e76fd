"""Scenarios: what the simulated machine does, as objects the live pipeline runs.

A :class:`Scenario` is a name, a description, the plant it simulates (:class:`Plant`:
the stage, the identifiers' and the observer's design) and its script: a tuple of
:class:`ScriptPart` objects, each answering two questions for a time ``t`` and the knob
values (the spindle-speed factor it imposes, the added inertia it mounts), plus the
machining processes the scenario runs (a workpiece losing mass, a wearing tool, the
eccentric milling tool). The pipeline asks its scenario; it never compares a
scenario's name.

A new scripted event is one more :class:`ScriptPart` (or process flag) in a scenario's
tuple; the part program with its injected events (issue 21) is the ``process`` flag.

A source that is not the simulator (a log, a broker) runs :func:`source_scenario`: no
script, no process, the plant from the source's own nominal parameters.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Protocol

from estimators.rls import IdentifierParams
from machine.stage import SEED000_FORCE, SEED001_FORCE, StageConfig
from machine.stage_params import ADDED_WEIGHT_INERTIA, preset
from server.pipeline.sources import MeasurementSource

KnobMap = Mapping[str, float | bool | str]


@dataclass(frozen=True)
class Plant:
    """The simulated stage of a scenario and the observers' design for it."""

    config: StageConfig
    ident: IdentifierParams = field(default_factory=IdentifierParams)
    design: Mapping[str, float] = field(default_factory=dict)


class ScriptPart(Protocol):
    """One scripted element of a scenario (spindle steps, a mounted weight...)."""

    def spindle_factor(self, t: float, knobs: KnobMap) -> float:
        """Factor on the spindle speed (and the force) at ``t`` (1: none)."""
        ...

    def extra_inertia(self, t: float, knobs: KnobMap) -> float | None:
        """Inertia this part mounts on the load at ``t`` [kg m^2] (None: none)."""
        ...


@dataclass(frozen=True)
class PeriodicSpindleSteps:
    """The spindle steps to ``low`` of the knob's speed every other ``period`` seconds,
    while the flag knob ``enabled_by`` is on."""

    period: float = 15.0
    low: float = 0.8
    enabled_by: str = "spindle_changes"
    #: its name among the knobs' readers (``server.pipeline.knobs``: ``spindle_changes``)
    reader: str = "spindle_steps"

    def spindle_factor(self, t: float, knobs: KnobMap) -> float:
        if knobs[self.enabled_by] and math.floor(t / self.period) % 2 == 1:
            return self.low
        return 1.0

    def extra_inertia(self, t: float, knobs: KnobMap) -> float | None:
        return None


@dataclass(frozen=True)
class SpindleStepAt:
    """The spindle speed (and the force with it) drops to ``low`` at ``at`` seconds."""

    at: float
    low: float = 0.8

    def spindle_factor(self, t: float, knobs: KnobMap) -> float:
        return self.low if t >= self.at else 1.0

    def extra_inertia(self, t: float, knobs: KnobMap) -> float | None:
        return None


@dataclass(frozen=True)
class WeightAt:
    """A weight of ``inertia`` is mounted on the load at ``at`` seconds."""

    at: float
    inertia: float = ADDED_WEIGHT_INERTIA

    def spindle_factor(self, t: float, knobs: KnobMap) -> float:
        return 1.0

    def extra_inertia(self, t: float, knobs: KnobMap) -> float | None:
        return self.inertia if t >= self.at else None


@dataclass(frozen=True)
class Scenario:
    """A scenario: its plant, its script and the machining processes it runs.

    Attributes
    ----------
    name, description
        As listed by ``GET /api/scenarios``.
    plant
        Builds the simulated stage and the observers' design (None: a source's own).
    script
        The scripted parts, asked in order (spindle factors multiply; the first part
        that mounts an inertia gives it).
    workpiece, tool_wear, eccentricity
        The workpiece losing mass and clamped fresh, seed 004's wearing tool changed at
        its limit, seed 003's eccentric milling tool with its tuner.
    process
        A part program cut part after part on seed 003's machine, watched by the process
        monitor (issue 21, :mod:`server.pipeline.process_part`).
    knobs
        Knob values that differ from the defaults in this scenario.
    source
        Builds the scenario's own measurement source from the seed (None: the simulated
        stage of ``plant``): the machining centre's CNC trace (issue 31).
    """

    name: str
    description: str
    plant: Callable[[], Plant] | None = None
    script: tuple[ScriptPart, ...] = ()
    workpiece: bool = False
    tool_wear: bool = False
    eccentricity: bool = False
    process: bool = False
    knobs: Mapping[str, float | bool | str] = field(default_factory=dict)
    source: Callable[[int], MeasurementSource] | None = None

    def spindle_factor(self, t: float, knobs: KnobMap) -> float:
        """The script's factor on the spindle speed at ``t``."""
        f = 1.0
        for part in self.script:
            f *= part.spindle_factor(t, knobs)
        return f

    @property
    def knob_readers(self) -> tuple[str, ...]:
        """The script's parts that read a knob, by their ``reader`` name (the knobs'
        :attr:`~server.pipeline.knobs.Knob.parts`)."""
        return tuple(r for p in self.script if (r := str(getattr(p, "reader", ""))))

    def extra_inertia(self, t: float, knobs: KnobMap) -> float | None:
        """The inertia the script mounts at ``t`` (None: none)."""
        for part in self.script:
            j = part.extra_inertia(t, knobs)
            if j is not None:
                return j
        return None


def _centre(seed: int) -> MeasurementSource:
    from server.pipeline.centre_source import CentreSource

    return CentreSource(seed)


def _seed000() -> Plant:
    return Plant(StageConfig(params=preset("seed000"), force=SEED000_FORCE))


def _seed001() -> Plant:
    p = preset("seed001")
    ident = IdentifierParams(q_rls_hz=40.0, scale=(p.J_L, p.B_L, p.F_CL, 1.0))
    design = {"err3_J_M": 0.0, "err3_B_M": 0.0, "err3_K": 0.0, "err3_F_CM": 0.0}
    return Plant(StageConfig(params=p, force=SEED001_FORCE), ident, design)


#: the scenario ``cutwatch serve``, the live pipeline and the Docker image start on when
#: none is named: the machining centre as its CNC reports it (issue 31). The seeds'
#: machines side by side (the default before issue 31) stay selectable by their name,
#: ``default`` (kept: reproductions, benchmarks, checkpoints and the channel hashes name it)
DEFAULT_SCENARIO = "machining-centre"
#: the scenario of the seeds' machines side by side (the stage, seed 003's milling, seed
#: 004's wear): its name, kept from before issue 31
STAGE_SCENARIO = "default"

#: the scenarios of a simulated machine, by name
SCENARIO_OBJECTS: Mapping[str, Scenario] = {
    s.name: s
    for s in (
        Scenario(
            STAGE_SCENARIO,
            "the seeds' machines side by side (the default before issue 31): X stage "
            "reciprocating while milling; workpiece losing mass; spindle changes",
            _seed000,
            script=(PeriodicSpindleSteps(),),
            workpiece=True,
            tool_wear=True,
            eccentricity=True,
            process=True,
        ),
        Scenario(
            "seed000-weight",
            "seed 000 Table III: the weight (+2.92e-4 kg m^2) added at 10 s",
            _seed000,
            script=(WeightAt(10.0),),
        ),
        Scenario(
            "seed001-spindle",
            "seed 001 Fig. 9: spindle speed and force drop to 80 % at 11 s",
            _seed001,
            script=(SpindleStepAt(11.0),),
            knobs={"spindle_changes": False},
        ),
        Scenario(
            "machining-centre",
            "a 3-axis machining centre with its spindle drive, as its CNC's 500 Hz trace "
            "(issue 31): part program O2001, tools in a magazine",
            source=_centre,
        ),
    )
}

#: name -> one-line description
SCENARIOS: dict[str, str] = {k: s.description for k, s in SCENARIO_OBJECTS.items()}


def source_scenario(name: str) -> Scenario:
    """The scenario of a source the knobs do not apply to (a log, a live feed): its own
    name, no script, no process."""
    return Scenario(name, f"measurements from the {name} source")
