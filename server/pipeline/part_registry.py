"""Which parts a live pipeline is made of: the built-in ones, and those a user adds.

A part factory takes a :class:`BuildContext` (the scenario, the source, the knobs, the
simulated plant, the parts built before it) and returns a part, or None when the part is
not one of this pipeline's (the eccentricity loop belongs to the default scenario, not to
a replayed log). :data:`BUILTIN` lists cutwatch's own, in the order they run:

=============  ==============================================  ====================================
name           what                                            where
=============  ==============================================  ====================================
workpiece      a blank losing mass on the simulated stage      server/pipeline/workpiece.py
stage          seed 000/001's observers and the identifiers    server/pipeline/stage_part.py
effects        the residual loop's identified effects          server/pipeline/effects_part.py
dfo            seed 002's harmonic observer                    server/pipeline/dfo_part.py
wear           seed 004's wearing tool and its life monitor    server/pipeline/wear_part.py
eccentricity   seed 003's milling tool and its tuner           server/pipeline/eccentricity_part.py
process        the part program and the process monitor        server/pipeline/process_part.py
axes           every axis of a described machine, rigid, live  server/pipeline/axis_part.py
spindle        a spindle's cutting power over its taught idle  server/pipeline/spindle_part.py
cnc            the spindle drive's raw signals the spindle     server/pipeline/cnc_part.py
               part does not stream (the opcua source)
axis_monitor   the process monitor on the axes' process force  server/pipeline/axis_monitor_part.py
two_inertia    seed 000's observer on a scale axis, from the   server/pipeline/two_inertia_part.py
               parameters identified on the trace
centre_wear    wear per tool from the spindle's cutting power  server/pipeline/centre_wear_part.py
=============  ==============================================  ====================================

More parts come after these, in the order they were added: :func:`register` (in
process, e.g. a test: :func:`registered` is its context manager) or by name,
``module:attribute`` (:func:`load`; ``cutwatch serve --part`` and ``cutwatch worker
--part``, the setting ``CUTWATCH_PARTS``): the attribute is a part class or any callable
that takes the :class:`BuildContext` and returns a part (or None). docs/adding-a-part.md
walks through one.
"""

from __future__ import annotations

import contextlib
import importlib
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

from estimators.observer_effects import ObserverEffect
from server.errors import CutwatchError
from server.pipeline.part import Part
from server.pipeline.scenarios import Plant, Scenario
from server.pipeline.sources import MeasurementSource

__all__ = [
    "BUILTIN",
    "BuildContext",
    "PartFactory",
    "extra_factories",
    "load",
    "register",
    "registered",
    "unregister",
    "use",
]


@dataclass
class BuildContext:
    """What a part factory may build its part from.

    Attributes
    ----------
    scenario
        The scenario (its flags say which simulated processes it runs).
    source
        The measurement source (sample time, nominal parameters).
    seed
        The pipeline's seed (a simulating part draws its own generator from it).
    knobs
        The knob values at build.
    plant
        The simulated stage's configuration and the observers' design.
    spindle_factor
        The scenario's factor on the spindle speed at a time.
    effects
        The observer effects to install at build.
    axis_effects
        Per axis of a described machine, the residual report's effects its live rigid
        model holds (``cutwatch serve --model``).
    parts
        The parts built so far, by name.
    """

    scenario: Scenario
    source: MeasurementSource
    seed: int
    knobs: Mapping[str, float | bool | str]
    plant: Plant
    spindle_factor: Callable[[float], float]
    effects: tuple[ObserverEffect, ...] = ()
    axis_effects: Mapping[str, tuple[Any, ...]] = field(default_factory=dict)
    parts: dict[str, Part] = field(default_factory=dict)
    #: the parts that could not be built, with the reason
    failed: dict[str, str] = field(default_factory=dict)

    def part(self, name: str) -> Any:
        """The part ``name`` built before this one.

        Raises
        ------
        CutwatchError
            No such part (not in this pipeline, or it could not be built: the reason).
        """
        if name in self.failed:
            raise CutwatchError(f"needs the {name} part, which was not built ({self.failed[name]})")
        if name not in self.parts:
            raise CutwatchError(f"needs the {name} part, which this pipeline does not run")
        return self.parts[name]


#: a part factory: the context -> a part, or None when the part is not this pipeline's
PartFactory = Callable[[BuildContext], Part | None]


def _workpiece(c: BuildContext) -> Part | None:
    from server.pipeline.workpiece import WorkpiecePart

    if not c.scenario.workpiece:
        return None
    return WorkpiecePart(c.plant.config.trajectory.half_period, c.spindle_factor)


def _stage(c: BuildContext) -> Part:
    from server.pipeline.stage_part import StagePart

    why = getattr(c.source, "stage_refusal", "")  # a described machine without its model
    if why:
        raise CutwatchError(why)

    return StagePart(c.source, c.plant.ident, dict(c.plant.design))


def _effects(c: BuildContext) -> Part:
    from server.pipeline.effects_part import EffectsPart

    return EffectsPart(c.part("stage"), c.effects)


def _dfo(c: BuildContext) -> Part:
    from server.pipeline.dfo_part import DfoPart

    part = DfoPart(c.part("stage"), tuple(c.plant.config.force.frequencies))
    centre = _centre(c)
    if centre is not None:  # the centre's tools at its trace rate: where the DFO could see
        from server.pipeline.centre_rates import dfo_reason

        part.rate_note = dfo_reason(centre.machine.program, centre.rate_hz)
    return part


def _centre(c: BuildContext) -> Any:
    """The machining centre's source (None: another source)."""
    from server.pipeline.centre_source import CentreSource

    return c.source if isinstance(c.source, CentreSource) else None


def _wear(c: BuildContext) -> Part | None:
    from server.pipeline.wear_part import WearPart

    return WearPart(float(c.knobs["wear_rate"])) if c.scenario.tool_wear else None


def _eccentricity(c: BuildContext) -> Part | None:
    from server.pipeline.eccentricity_part import EccentricityPart

    if c.scenario.eccentricity:
        return EccentricityPart.from_knobs(c.knobs)
    centre = _centre(c)
    if centre is not None:  # listed with the reason, in numbers (issue 31 item 2)
        from server.pipeline.centre_rates import eccentricity_reason

        raise CutwatchError(eccentricity_reason(centre.machine.program, centre.rate_hz))
    return None


def _process(c: BuildContext) -> Part | None:
    from server.pipeline.process_part import ProcessPart

    return ProcessPart.from_knobs(c.seed, c.knobs) if c.scenario.process else None


def _spindle(c: BuildContext) -> Part | None:
    from server.pipeline.block_motion import program_lines
    from server.pipeline.machine_view import description_of
    from server.pipeline.spindle_part import SpindlePart

    desc = description_of(c.source)
    if desc is None or desc.spindle is None or "power" not in desc.spindle.signals:
        return None  # the stage, a log, a feed without a spindle's power: not built
    return SpindlePart(desc, str(getattr(c.source, "program", "")), program_lines(c.source))


def _axes(c: BuildContext) -> Part | None:
    from server.pipeline.axis_part import AxisPart
    from server.pipeline.machine_view import description_of, has_prior

    desc = description_of(c.source)
    if desc is None or c.source.knobs_apply:
        return None  # the simulator's stage: its observers are the stage part's
    if all(a.kind == "two_inertia" and has_prior(a) for a in desc.axes):
        return None  # the stage part's machine, fed or replayed alike (the same streams)
    return AxisPart(desc, c.axis_effects)


def _cnc(c: BuildContext) -> Part | None:
    from server.pipeline.cnc_part import CncPart
    from server.pipeline.machine_view import description_of

    desc = description_of(c.source)
    if desc is None or desc.spindle is None or c.source.name != "opcua":
        return None
    part = CncPart(desc)
    return part if part.sources else None  # nothing beside the spindle part's signals


def _axis_monitor(c: BuildContext) -> Part | None:
    from server.pipeline.axis_monitor_part import AxisMonitorPart, monitored_axes
    from server.pipeline.block_motion import program_lines
    from server.pipeline.machine_view import description_of

    desc = description_of(c.source)
    if desc is None or "axes" not in c.parts or "spindle" not in c.parts:
        return None  # no axes' force, or no spindle's cutting power to say where it cuts
    if desc.spindle is None or "line" not in desc.identities or not monitored_axes(desc):
        return None  # no revolution, no block to teach per, or no force in N (an export's A)
    prog = str(getattr(c.source, "program", ""))
    return AxisMonitorPart(desc, prog, program_lines(c.source))


def _two_inertia(c: BuildContext) -> Part | None:
    from server.pipeline.machine_view import description_of, has_prior
    from server.pipeline.two_inertia_part import TwoInertiaAxisPart, two_inertia_axes

    desc = description_of(c.source)
    if desc is None or c.source.knobs_apply or "spindle" not in c.parts:
        return None  # the simulator's stage; no spindle to say where the tool is in the air
    axes = [a for a in desc.axes if a.name in two_inertia_axes(desc)]
    if not axes or all(has_prior(a) for a in axes):
        return None  # no scale axis, or the stage part's observers watch it (its nominal)
    return TwoInertiaAxisPart(desc)


def _centre_wear(c: BuildContext) -> Part | None:
    from server.pipeline.centre_wear_part import CentreWearPart

    if "spindle" not in c.parts:
        return None  # no spindle's cutting power: not built
    return CentreWearPart(str(getattr(c.source, "program", "")))


#: cutwatch's own parts, by name, in the order they run (module docstring)
BUILTIN: tuple[tuple[str, PartFactory], ...] = (
    ("workpiece", _workpiece),
    ("stage", _stage),
    ("effects", _effects),
    ("dfo", _dfo),
    ("wear", _wear),
    ("eccentricity", _eccentricity),
    ("process", _process),
    ("axes", _axes),
    ("spindle", _spindle),
    ("cnc", _cnc),
    ("axis_monitor", _axis_monitor),
    ("two_inertia", _two_inertia),
    ("centre_wear", _centre_wear),
)

#: the parts added: what was registered (a class or a factory) -> its factory
_EXTRA: dict[Any, PartFactory] = {}


def register(part: type[Any] | PartFactory) -> None:
    """Add a part to every pipeline built from now on (after the built-in ones): a part
    class (built with the :class:`BuildContext` when its constructor takes an argument,
    else with none) or a factory."""
    _EXTRA[part] = _factory(part)


def unregister(part: type[Any] | PartFactory) -> None:
    """Take a part added by :func:`register` out again (pipelines built from now on)."""
    _EXTRA.pop(part, None)


@contextlib.contextmanager
def registered(*parts: type[Any] | PartFactory) -> Iterator[None]:
    """``parts`` added for the ``with`` block (a test's toy part)."""
    for p in parts:
        register(p)
    try:
        yield
    finally:
        for p in parts:
            unregister(p)


_LOADED: dict[str, PartFactory] = {}


def use(specs: str | list[str]) -> list[str]:
    """Load and register the parts named ``module:attribute`` (comma-separated, or a list),
    each once however often it is asked for (the service's settings are read by every
    app the process builds). The specs now in use.

    Raises
    ------
    CutwatchError
        A spec that cannot be loaded (:func:`load`).
    """
    items = specs.split(",") if isinstance(specs, str) else list(specs)
    for spec in (s.strip() for s in items):
        if spec and spec not in _LOADED:
            _LOADED[spec] = load(spec)
            _EXTRA[spec] = _LOADED[spec]
    return sorted(_LOADED)


def extra_factories() -> tuple[tuple[str, PartFactory], ...]:
    """The parts added, in order, each with a name to list it by should it fail to build
    (its class's ``name``, else what it was registered as)."""
    return tuple((_label(k), f) for k, f in _EXTRA.items())


def _label(key: Any) -> str:
    name = getattr(key, "name", None)
    if isinstance(name, str) and name:
        return name
    return str(getattr(key, "__name__", key))


def load(spec: str) -> PartFactory:
    """The part factory named ``module:attribute`` (imported now).

    Raises
    ------
    CutwatchError
        Not of the form ``module:attribute``, a module that cannot be imported, no such
        attribute, or one that is not callable: the message names which.
    """
    mod_name, sep, attr = spec.partition(":")
    if not sep or not mod_name or not attr:
        raise CutwatchError(f"part {spec!r}: expected module:attribute (e.g. mypkg.parts:MyPart)")
    try:
        mod = importlib.import_module(mod_name)
    except Exception as exc:
        raise CutwatchError(f"part {spec!r}: module {mod_name!r} not importable: {exc}") from None
    obj = getattr(mod, attr, None)
    if obj is None:
        raise CutwatchError(f"part {spec!r}: module {mod_name!r} has no attribute {attr!r}")
    if not callable(obj):
        raise CutwatchError(
            f"part {spec!r}: expected a part class or factory, found {type(obj).__name__}"
        )
    return _factory(obj)


def _factory(obj: Callable[..., Any]) -> PartFactory:
    """A part class (built with the context when its constructor takes one argument, else
    with none) or a factory, as a :data:`PartFactory`."""
    if isinstance(obj, type):
        import inspect

        takes = len(inspect.signature(obj).parameters)

        def build(c: BuildContext) -> Part | None:
            part: Part = obj(c) if takes else obj()
            return part

        return build
    return obj
