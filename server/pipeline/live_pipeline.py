"""The live pipeline: a measurement source and the parts that watch it, block by block.

The public surface is the contract the live runtime builds on
(:mod:`server.pipeline.runtime`):

- ``LivePipeline(scenario: str = DEFAULT_SCENARIO, seed: int = 0, source=None)`` (the
  default: the machining centre, ``machining-centre``); a log replay
  is ``LivePipeline.from_log(path)``
- ``.sample_time`` (s), ``.t`` (time of the source, s), ``.finished`` (a log has ended)
- ``.channels() -> list[Channel]``, ``.charts() -> list[Chart]``: what the parts stream
  and where the dashboard draws it (:mod:`server.pipeline.part`)
- ``.parts() -> list[dict]``: every part with ``name``, ``running`` and ``reason``
- ``.step(n) -> dict[str, np.ndarray]``: advance ``n`` samples; one float64 array of
  length ``n`` per channel name (plus ``"t"``)
- ``.knobs() -> dict[str, Knob]``: the live-tweakable parameters its parts read, with
  their ranges (frozen copies; :mod:`server.pipeline.knobs` holds the table and says
  which parts read each knob)
- ``.set_knob(name, value)``, ``.set_knobs(changes)``: validated (``Knob.check``); raise
  ``ParameterError`` naming the field, the allowed range and the value (a knob no part
  of the pipeline reads: the parts that would); nothing changes on error
- ``.reset()``; ``.snapshot() -> dict`` (latest values, truths, knob values, accuracy,
  parts)
- ``.state() -> PipelineState``, ``.restore(state)``: everything carried from block to
  block as one value (:mod:`server.pipeline.checkpoint`, docs/checkpoints.md)
- ``.accuracy() -> dict``: rolling rms of each force estimate over 1 s and 10 s
  (:mod:`harness.accuracy`)
- ``SCENARIOS``: name -> one-line description

The pipeline is a coordinator. Its parts (:mod:`server.pipeline.part`; which ones:
:mod:`server.pipeline.part_registry`) each say what they need of the machine
(``requires``, asked of a :class:`~server.pipeline.machine_view.MachineView` at build and
again whenever the view changes: a spindle step, a new sample rate), what they stream
(their channels and charts) and how they run; the pipeline loops over them in order:

1. the scenario's script before the source's block (:meth:`LivePipeline._prepare`): the
   simulating parts' ``before`` (the workpiece's removal, the tool's pass), a spindle
   step, the knobs and the machine given to the parts (``configure``) when they changed,
   and the simulated stage reconfigured (:meth:`LivePipeline._apply`: force gain and
   frequencies, added inertia, noise, plant effects);
2. the source's block, wrapped once in a :class:`~server.pipeline.part.Block`;
3. every running part's ``step``: its channels (later parts read earlier ones' from the
   block), its events; a part that raises is stopped with its reason (and the parts
   that need it), the others go on; a part that does not run streams NaN;
4. the force estimates scored (:mod:`harness.accuracy`).

What each costs is measured as it runs (:meth:`LivePipeline.costs`): per part, the wall
time of its estimation apart from its simulation (the simulated machine's script, and
what a simulating part reports as :attr:`~server.pipeline.part.LivePart.simulated_s`),
the source's (the simulator's stage), and the pipeline's own coordination; ``cutwatch
bench pipeline`` reports them per machine-second.

What the CNC knows (a spindle step, a tool change, a fresh workpiece, a weight put on)
goes to every part at once as a :class:`~server.pipeline.part.Notice`.

Scenario events are scheduled on simulated time, so a run is the same whatever the
wall-clock speed. The seeds' scenario (``default``, the default before issue 31): the
stage reciprocates while milling; the
workpiece (an inertia of the size of seed 000's added weight) loses mass at
``removal_rate`` % per second until a fresh blank is clamped; every 15 s the spindle
speed steps between the knob's value and 80 % of it (force gain and frequencies, as in
seed 001 Fig. 9). Identification you can trust (issue 13,
``docs/live-identification.md``): the gated segment identifier streams J_L, B_L, F_CL
with 95 % interval bounds and an excited flag.
"""

from __future__ import annotations

import collections
import copy
import logging
import math
import os
import time
from collections.abc import Iterable, Mapping
from dataclasses import replace
from typing import Any, TypedDict

import numpy as np

from common.errors import ParameterError
from common.machine_description import MachineDict
from estimators.observer_effects import ObserverEffect
from estimators.rls import IdentifierParams
from harness.accuracy import AccuracySummary, RollingAccuracy
from machine.effects import EFFECT_NAMES, PlantEffects
from machine.stage import SEED000_FORCE, CuttingForce, StageConfig
from machine.stage_params import ADDED_WEIGHT_INERTIA
from server.errors import CutwatchError
from server.pipeline.checkpoint import PipelineState, ScriptState
from server.pipeline.estimates_out import StatusStrip
from server.pipeline.knobs import (
    BASE_RPM,
    KNOBS,
    SIMULATOR,
    Knob,
    KnobValue,
    KnobValues,
    not_read,
)
from server.pipeline.machine_view import MachineView, description_of
from server.pipeline.part import (
    Block,
    Channel,
    Chart,
    LivePart,
    Notice,
    Part,
    PartInfo,
    PartStatus,
    Plan,
    Setup,
    Verdict,
    nan_channels,
)
from server.pipeline.part import (
    Plant as BlockPlant,
)
from server.pipeline.part_registry import BUILTIN, BuildContext, extra_factories
from server.pipeline.process_part import Relearned
from server.pipeline.scenarios import (
    DEFAULT_SCENARIO,
    SCENARIO_OBJECTS,
    SCENARIOS,
    Plant,
    Scenario,
    source_scenario,
)
from server.pipeline.sources import (
    MeasurementSource,
    ReplaySource,
    Scheduled,
    SimulatorSource,
    SourceBlock,
    open_replay,
)
from server.pipeline.stage_run import StageRun
from server.records.history.store import ToolChange
from server.records.monitor_events import EventOutbox, MonitorEvent

__all__ = [
    "BASE_RPM",
    "DEFAULT_SCENARIO",
    "FORCE_ESTIMATES",
    "SCENARIOS",
    "Channel",
    "Knob",
    "LivePipeline",
]

log = logging.getLogger("uvicorn.error")


def _force_estimates(channels: Iterable[Channel]) -> tuple[str, ...]:
    """The force estimates the accuracy panel scores: group ``force``, not the truth."""
    return tuple(c.name for c in channels if c.group == "force" and not c.truth)


def _builtin_force_estimates() -> tuple[str, ...]:
    from server.pipeline.dfo_part import DfoPart
    from server.pipeline.effects_part import EffectsPart
    from server.pipeline.stage_part import StagePart

    return _force_estimates(c for p in (StagePart, EffectsPart, DfoPart) for c in p.channels)


#: the force estimates of the built-in parts, in the order the pipeline streams them
FORCE_ESTIMATES = _builtin_force_estimates()


class PartCosts(TypedDict):
    """A part's wall time: estimating, and simulating a machine beside the stage [s]."""

    estimation_s: float
    simulation_s: float


class SimulationCost(TypedDict):
    """The source's wall time simulating (or reading) the machine [s]."""

    simulation_s: float


class EstimationCost(TypedDict):
    """The pipeline's own coordination's wall time [s]."""

    estimation_s: float


class AxisInfo(TypedDict):
    """A feed axis in :meth:`LivePipeline.machine`: its name, kind and signals' roles."""

    name: str
    kind: str
    signals: list[str]


class SpindleInfo(TypedDict):
    """The spindle in :meth:`LivePipeline.machine`: its signals' roles."""

    signals: list[str]


class MachineInfo(TypedDict):
    """What :meth:`LivePipeline.machine` gives (``GET /api/machine``)."""

    source: str
    scenario: str
    sample_time: float
    axes: list[AxisInfo]
    spindle: SpindleInfo | None
    identities: list[str]
    description: MachineDict | None
    parts: list[PartInfo]


class InjectedTruth(TypedDict):
    """An injected event's truth (:meth:`LivePipeline.process_truths`, the fields of
    :class:`machine.process.EventTruth`): for scoring, never given to a detector."""

    kind: str
    t: float
    sample: int
    size: float
    tool: int
    line: int
    part: int


class PipelineCosts(TypedDict):
    """:meth:`LivePipeline.costs`: wall time over the machine's seconds stepped."""

    machine_s: float
    wall_s: float
    parts: dict[str, PartCosts]
    source: SimulationCost
    pipeline: EstimationCost


#: the status strip before any part says more (``MonitorStatus`` fields)
_STATUS: StatusStrip = {
    "state": "off",
    "tool": 0,
    "program": "",
    "line": 0,
    "part": -1,
    "wear_share": math.nan,
    "life_left_min": math.nan,
    "wear_tool": 0,
    "wear_of": "",
    "wear_limit_mm": math.nan,
    "wear_alarm_share": math.nan,
    "wear_lo_share": math.nan,
    "wear_hi_share": math.nan,
    "wear_calibrated": None,
}


class LivePipeline:
    """A source and its parts, advanced block by block, with live knobs (module docstring).

    Parameters
    ----------
    scenario
        One of :data:`SCENARIOS`, when the source is a simulation (default:
        :data:`~server.pipeline.scenarios.DEFAULT_SCENARIO`, the machining centre).
    seed
        Seed of the simulation's random generator.
    source
        Where the measurements come from (:mod:`server.pipeline.sources`). Default: the
        simulator of ``scenario``. A source the knobs do not apply to (a log, a live
        feed) runs with its own name as the scenario (``"replay"``) and the observers
        built from its nominal parameters.
    """

    #: the last block's outputs (:attr:`_last` takes their last values when asked)
    _last_out: dict[str, np.ndarray] | None = None
    #: the outputs the last values were taken from, and those values: one tuple, rebound
    #: whole, so a reader on another thread (a worker's HTTP answers read ``latest``
    #: without the loop's lock) never stores an older block's values over a newer one's
    _last_memo: tuple[object, dict[str, float]] = (None, {})

    def __init__(
        self,
        scenario: str = DEFAULT_SCENARIO,
        seed: int = 0,
        source: MeasurementSource | None = None,
    ) -> None:
        if source is not None and not source.knobs_apply:
            sc = source_scenario(source.name)
        elif scenario in SCENARIO_OBJECTS:
            sc = SCENARIO_OBJECTS[scenario]
        else:
            raise ParameterError("scenario", f"one of {sorted(SCENARIOS)}", scenario)
        self.script: Scenario = sc
        self.seed = seed
        if source is None and sc.source is not None:
            source = sc.source(seed)  # the scenario's own machine (the machining centre)
        self._knobs = KnobValues(sc.knobs)
        self._effects0: tuple[ObserverEffect, ...] = ()
        #: per axis, the residual report's effects the axes' live models hold
        self.axis_effects: dict[str, tuple[Any, ...]] = {}
        plant = self._plant(source)
        self._plant_cfg = plant
        self._force0: CuttingForce = plant.config.force
        self.source = source or SimulatorSource(plant.config, seed=seed)
        #: events raised and not yet taken (:meth:`take_events`); kept over a reset
        self.events = EventOutbox()
        self.reset()

    @property
    def scenario(self) -> str:
        """The scenario's name (a source's own name when the knobs do not apply)."""
        return self.script.name

    @classmethod
    def from_log(cls, path: str | os.PathLike[str], seed: int = 0) -> LivePipeline:
        """The live observers fed by a measured log (:func:`server.pipeline.sources.open_replay`
        checks it); ``finished`` turns true at its last sample.

        Raises
        ------
        LogFormatError, CutwatchError
            The log is missing, unreadable or not a two-inertia log with its nominal
            parameters.
        """
        return cls(seed=seed, source=ReplaySource(open_replay(path)))

    # ------------------------------------------------------------------ set-up
    def _plant(self, source: MeasurementSource | None) -> Plant:
        """The scenario's stage, identifier and observer design; for a given source, its
        sample time and the default design (the stage configuration then only gives the
        nominal cutting force: the harmonic observer's frequencies)."""
        if source is not None:
            ident = IdentifierParams(sample_time=source.sample_time)
            return Plant(StageConfig(force=SEED000_FORCE), ident, {})
        if self.script.plant is None:
            raise ParameterError("source", f"a measurement source for {self.scenario!r}", None)
        return self.script.plant()

    def reset(self) -> None:
        """Start the source (the simulation from t = 0, a log from its first sample) and
        every part again, built afresh (knobs and installed effects kept)."""
        effects = self.effects if hasattr(self, "_parts") else self._effects0
        self.source.reset()
        self.sample_time = float(self.source.sample_time)
        self.last_block: SourceBlock | None = None
        self._weight = math.nan  # seed 000's weight on the load (none applied yet)
        self._prev_factor = self._spindle_factor(0.0)
        self._last = {}
        self._applied: tuple[object, ...] = ()
        self._force_applied = self._force0
        self._knob_version = 0
        self._configured: tuple[int, MachineView] | None = None
        self._view = MachineView.of(self.source, self._spindle_rpm(0.0))
        self.reset_costs()
        self._build(effects)
        self._accuracy = self._new_accuracy()
        self._apply(0.0)

    def _build(self, effects: tuple[ObserverEffect, ...]) -> None:
        """Every part of this pipeline, built in order; one that cannot be built is
        listed with the reason (and so are the parts that need it)."""
        ctx = BuildContext(
            self.script,
            self.source,
            self.seed,
            self._knobs,
            self._plant_cfg,
            self._spindle_factor,
            effects,
            dict(self.axis_effects),
        )
        self._parts: list[Part] = []
        self._status: dict[str, PartStatus] = {}
        self._order: list[str] = []  # every part's name, built or not, in order
        factories = [*BUILTIN, *extra_factories()]
        for name, factory in factories:
            try:
                part = factory(ctx)
            except Exception as exc:  # a part that cannot be built is said, not fatal
                why = str(exc) if isinstance(exc, CutwatchError | ParameterError) else _why(exc)
                ctx.failed[name] = why
                self._status[name] = PartStatus(name, False, f"not built: {why}")
                self._order.append(name)
                continue
            if part is None:
                continue
            ctx.parts[part.name] = part
            self._parts.append(part)
            self._order.append(part.name)
        # the parts that simulate beside the machine (the others keep the hooks' defaults:
        # not called, not timed)
        self._hooks = {
            h: [p for p in self._parts if _overrides(p, h)]
            for h in ("before", "force_gain", "added_inertia")
        }
        self._check(self._view)

    @property
    def run(self) -> StageRun:
        """The stage observers and identifiers (:class:`~server.pipeline.stage_run.StageRun`).

        Raises
        ------
        ParameterError
            The pipeline has no stage part.
        """
        return self._part("stage", "run").run

    @property
    def tool(self) -> Any:
        """The wearing tool (:class:`~server.pipeline.wear_passes.ToolWearPasses`), None
        without the wear part."""
        wear = self.part("wear")
        return wear.tool if wear is not None else None

    @property
    def workpiece(self) -> Any:
        """The workpiece (:class:`~server.pipeline.workpiece.Workpiece`), None without it."""
        wp = self.part("workpiece")
        return wp.workpiece if wp is not None else None

    def part(self, name: str) -> Any:
        """The part ``name`` of this pipeline (None: it has none)."""
        return next((p for p in self._parts if p.name == name), None)

    def _part(self, name: str, field: str) -> Any:
        p = self.part(name)
        if p is None:
            raise ParameterError(
                field, f"a pipeline with the {name} part", f"the {self.scenario} pipeline"
            )
        return p

    @property
    def effects(self) -> tuple[ObserverEffect, ...]:
        """The observer effects installed (the effects part's)."""
        fx = self.part("effects")
        return tuple(fx.effects) if fx is not None else ()

    def set_observer_effects(self, effects: tuple[ObserverEffect, ...]) -> None:
        """Install identified effects (issue 4 section 4) into the live observer; ``()``
        removes them. Their terms are subtracted from the fixed-parameter observer's
        force as :mod:`estimators.residual.two_inertia` does (channel ``f_effects``).

        Raises
        ------
        ParameterError
            An effect without its fitted coefficients, or a pipeline without the effects
            part.
        """
        self._part("effects", "effects").install(tuple(effects))

    def set_axis_effects(self, effects: Mapping[str, tuple[Any, ...]]) -> None:
        """The residual report's effects each axis' live rigid model holds (issue 30 item
        4; by axis, ``"*"``: every axis; ``{}`` removes them): the axes part is built
        again with them, its identified parameters kept (the effects' coefficients start
        empty), and beside each axis with effects the same axis without them (its process
        force ``<axis>.F_base``). Without an axes part (no machine described yet) they are
        kept for it."""
        from server.pipeline.axis_part import AxisPart

        self.axis_effects = {k: tuple(v) for k, v in effects.items()}
        old = self.part("axes")
        if old is None:
            return
        new = AxisPart(old.machine, self.axis_effects)
        new.carry(old, self.t)
        self._parts[self._parts.index(old)] = new
        loaded = {n: [e.name for e in new.effects[n]] for n in new.with_effects}
        said = "; ".join(f"{n}: {', '.join(v)}" for n, v in loaded.items())
        if self._status["axes"].running:
            why = f"the report's effects in the live model ({said})" if said else ""
            self._status["axes"] = PartStatus("axes", True, why)
        self._accuracy = self._new_accuracy()

    @property
    def t(self) -> float:
        """Time elapsed: samples taken from the source times the sample time [s]."""
        return float(self.source.t)

    @property
    def finished(self) -> bool:
        """True once the source hands out no more samples (the end of a replayed log)."""
        return bool(self.source.finished)

    # ------------------------------------------------------------------ the parts
    def parts(self) -> list[PartInfo]:
        """Every part with ``name``, ``running`` and ``reason`` (why not), in order."""
        return [self._status[n].as_dict() for n in self._order]

    def _running(self, part: Part) -> bool:
        return self._status[part.name].running

    def idle(self) -> str:
        """Why nothing is estimated (``""``: something is): no part runs on this machine,
        or a live feed has handed out no sample yet (its state: waiting for meta, the
        broker not connected...). Health is never ``ok`` while this says something."""
        if not any(s.running for s in self._status.values()):
            return "no part runs on this machine (parts says why)"
        src = self.source
        if not src.paced and not src.knobs_apply and float(src.t) == 0.0:
            st = src.status()
            said = str(st.get("state", "")) or "nothing received"
            if st.get("problem"):
                said += f": {st['problem']}"
            return f"no sample from the {src.name} feed yet ({said})"
        return ""

    def carry(self, old: LivePipeline) -> None:
        """Continue ``old``'s identification (the same machine's feed, described again:
        a new meta, a new sample rate): every part that can (``carry``) takes the
        identified parameters of ``old``'s part of its name, its filters restarted; the
        knob values set on ``old`` that this pipeline's parts read go on too."""
        offered = self.knobs()
        kept = {n: v for n, v in old.knob_values().items() if n in offered}
        if kept:
            self._knobs.update(kept)
            self._knob_version += 1
        for part in self._parts:
            take = getattr(part, "carry", None)
            prev = old.part(part.name)
            if take is not None and prev is not None:
                take(prev, old.t)
                said = getattr(part, "said", "")
                if said and self._status[part.name].running:
                    self._status[part.name] = PartStatus(part.name, True, said)

    def _check(self, view: MachineView) -> None:
        """Ask every part whether it can run on ``view`` (in order: a part whose needed
        part does not run cannot run either); a part that stops or starts running is
        logged (not a paused part's reason that changed: the DFO's names the spindle's
        harmonic, which moves with every speed of a program, a line per speed change and
        machine in a plant's worker)."""
        for part in self._parts:
            old = self._status.get(part.name, PartStatus(part.name, True))
            if old.reason.startswith("stopped"):
                continue  # stopped on an error: until the next reset
            v = self._verdict(part, view)
            new = PartStatus(part.name, v.ok, v.reason)
            if old.running != new.running and part.name in self._status:
                log.warning(
                    "cutwatch: part %s %s",
                    part.name,
                    "runs again" if v.ok else f"paused: {v.reason}",
                )
            self._status[part.name] = new

    def _verdict(self, part: Part, view: MachineView) -> Verdict:
        """Whether ``part`` can run on ``view``: the parts it needs first; a part lacking
        one says, too, why it could not run on this machine anyway (its own refusal)."""
        try:
            own = part.requires(view)
        except Exception as exc:
            own = Verdict(False, f"requires: {_why(exc)}")
        also = "" if own.ok else f"; and {own.reason}"
        for need in part.needs:
            st = self._status.get(need)
            if st is None:
                why = f"needs the {need} part, which this pipeline does not run"
                return Verdict(False, why + also)
            if not st.running:
                why = f"needs the {need} part, which does not run ({st.reason})"
                return Verdict(False, why + also)
        return own

    def _stop(self, part: Part, exc: BaseException, where: str) -> None:
        """Stop ``part`` (it raised in ``where``) and every part that needs it."""
        reason = f"stopped: {where} raised {_why(exc)}"
        log.warning("cutwatch: part %s %s", part.name, reason)
        self._status[part.name] = PartStatus(part.name, False, reason)
        for other in self._parts:
            if part.name in other.needs and self._running(other):
                self._status[other.name] = PartStatus(
                    other.name, False, f"stopped: needs the {part.name} part, which stopped"
                )

    def channels(self) -> list[Channel]:
        """Every per-sample output of :meth:`step`, part by part, with how to draw it."""
        return [c for p in self._parts for c in p.channels]

    def charts(self) -> list[Chart]:
        """The charts the parts' channels are drawn on (each once, in part order), each
        with the name of the part that declares it."""
        seen: dict[str, Chart] = {}
        for p in self._parts:
            for c in p.charts:
                seen.setdefault(c.id, replace(c, part=c.part or p.name))
        return list(seen.values())

    def force_estimates(self) -> tuple[str, ...]:
        """The force estimates the accuracy panel scores, in stream order."""
        return _force_estimates(self.channels())

    def _notice(self, change: Notice) -> None:
        """Tell every running part of a change the CNC knows of, at once."""
        for part in self._parts:
            if self._running(part):
                part.notice(change)

    # ------------------------------------------------------------------ scenario
    def _spindle_factor(self, t: float) -> float:
        return self.script.spindle_factor(t, self._knobs)

    def _spindle_rpm(self, t: float) -> float:
        """The spindle speed in effect [rpm]: the machine's own when its source measures
        it (a feed's spindle speed signal), else the knob's (times the scenario's step)."""
        measured = float(getattr(self.source, "spindle_rpm", math.nan))
        if not self.source.knobs_apply and math.isfinite(measured):
            return measured
        return self._knobs.number("spindle_rpm") * self._spindle_factor(t)

    def _prepare(self, t0: float, n: int) -> None:
        """The scenario's script before the block of ``n`` samples starting at ``t0``: the
        simulating parts' ``before`` (the workpiece's removal and clamp, the tool's pass),
        a spindle step; then the stage's configuration for the block."""
        plan = Plan(t0, n, self.sample_time, self._knobs, self._notice)
        for part in self._hooks["before"]:
            if self._running(part):
                w0 = time.perf_counter()
                part.before(plan)
                self._cost[part.name][1] += time.perf_counter() - w0
        factor = self._spindle_factor(t0)
        if factor != self._prev_factor:  # a spindle step: the force's DC changes
            self._notice(Notice("disturbance", t0))
            self._prev_factor = factor
        self._apply(t0)

    def _apply(self, t: float) -> None:
        """The machine and the knobs to the parts (when either changed), and the simulated
        stage's configuration for the block starting at ``t``."""
        k = self._knobs
        sf = self._spindle_factor(t)
        self._configure(self._view.with_spindle(self._spindle_rpm(t)))
        freq = k.number("spindle_rpm") / BASE_RPM * sf
        part_gain = 1.0
        for part in self._hooks["force_gain"]:
            if self._running(part):
                w0 = time.perf_counter()
                part_gain *= part.force_gain(t)
                self._cost[part.name][1] += time.perf_counter() - w0
        gain = k.number("feed_scale") * sf * part_gain
        extra = ADDED_WEIGHT_INERTIA if k["weight_on"] else 0.0
        scripted = self.script.extra_inertia(t, k)
        if scripted is not None:
            extra = scripted
        if extra != self._weight:  # the weight mounted or removed: a known J_L change
            if not math.isnan(self._weight) and self.source.knobs_apply:
                self._notice(Notice("restart", t, ("J_L",)))
            self._weight = extra
        for part in self._hooks["added_inertia"]:
            if self._running(part):
                w0 = time.perf_counter()
                extra += part.added_inertia(t)
                self._cost[part.name][1] += time.perf_counter() - w0
        noise = k.number("current_noise")
        effects = tuple(e for e in EFFECT_NAMES if k[f"effect_{e}"])
        key = (freq, gain, extra, noise, effects)
        if key == self._applied:
            return
        self._applied = key
        self._force_applied = replace(self._force0, freq_scale=freq, gain=gain)
        w0 = time.perf_counter()
        # a log or a live feed ignores it (sources.MeasurementSource.knobs_apply)
        self.source.reconfigure(
            force=self._force_applied,
            extra_inertia=extra,
            current_noise=noise,
            effects=PlantEffects().with_enabled(*effects),
        )
        self._cost["source"][1] += time.perf_counter() - w0

    def _configure(self, view: MachineView) -> None:
        """A new machine view: every part asked again whether it can run; new knobs or a
        new view: every running part configured."""
        if view != self._view:
            self._view = view
            self._check(view)
        now = (self._knob_version, view)
        if now == self._configured:
            return
        self._configured = now
        setup = Setup(self._knobs, view)
        for part in self._parts:
            if self._running(part):
                try:
                    part.configure(setup)
                except Exception as exc:  # a part's failure is its own
                    self._stop(part, exc, "configure")

    # ------------------------------------------------------------------ knobs
    def knobs(self) -> dict[str, Knob]:
        """The knobs this pipeline's parts read (:attr:`Knob.parts`: the simulated stage's
        when the source is the simulator), with their ranges and current values (frozen
        copies: change them with :meth:`set_knob`). Each names its readers here, and
        ``waiting`` says why none of them runs now (a paused part: the value is kept for
        when it runs again)."""
        readers = {p.name for p in self._parts}
        if self.source.knobs_apply:
            readers.add(SIMULATOR)
            readers.update(self.script.knob_readers)
        out: dict[str, Knob] = {}
        for name, k in self._knobs.knobs().items():
            mine = tuple(p for p in k.parts if p in readers)
            if mine:
                out[name] = replace(k, parts=mine, waiting=self._knob_waiting(mine))
        return out

    def _knob_waiting(self, parts: tuple[str, ...]) -> str:
        """Why none of ``parts`` runs now (``""``: one does)."""
        if any(p not in self._status or self._status[p].running for p in parts):
            return ""
        why = "; ".join(f"the {p} part does not run ({self._status[p].reason})" for p in parts)
        return f"{why}: the value is kept for when it runs"

    def knob_values(self) -> dict[str, KnobValue]:
        """Name -> current value of every knob this pipeline's parts read."""
        return {name: k.value for name, k in self.knobs().items()}

    def _offered(self, changes: Mapping[str, object]) -> None:
        """Refuse a knob of the table that no part of this pipeline reads (the unknown
        names are :class:`KnobValues`' to refuse)."""
        offered = self.knobs()
        for name, value in changes.items():
            if name in KNOBS and name not in offered:
                expected, why = not_read(name, tuple(offered))
                raise ParameterError(name, f"{expected} ({why})", value)

    def set_knob(self, name: str, value: object) -> None:
        """Set one knob; validated (:meth:`server.pipeline.knobs.Knob.check`), nothing
        changes on error.

        Raises
        ------
        ParameterError
            Unknown name, a knob no part of this pipeline reads (field: its name; the
            parts that would read it said), wrong type, or a value outside the knob's
            range.
        """
        self._offered({name: value})
        self._knobs.set(name, value)
        self._knob_version += 1

    def set_knobs(self, changes: Mapping[str, object]) -> None:
        """Set several knobs, all or nothing.

        Raises
        ------
        ParameterError
            The first refused change (nothing is changed then), as :meth:`set_knob`.
        """
        self._offered(changes)
        self._knobs.update(changes)
        self._knob_version += 1

    # ------------------------------------------------------------------ stepping
    def step(self, n: int) -> dict[str, np.ndarray]:
        """Advance ``n`` samples; return ``"t"`` and every channel, ``n`` values each.

        Estimates refer to the previous sample (see :mod:`server.pipeline.stage_run`); ``t`` is the
        time they refer to, and the truth columns are aligned to it. A source that has
        fewer samples (the end of a log, a live feed) gives fewer values, or none: then
        nothing changes, not even ``t``. A block the source marks as a discontinuity
        restarts every part's estimators on it (each part knows how).
        """
        w_start = time.perf_counter()
        t0 = float(self.source.t)
        self._prepare(t0, n)
        w0 = time.perf_counter()
        src = self.source.step(n)
        self._cost["source"][1] += time.perf_counter() - w0
        self.last_block = src  # the measurements as the source gave them (recording)
        if src.n == 0:
            return {"t": np.zeros(0)} | {c.name: np.zeros(0) for c in self.channels()}
        if not self.source.knobs_apply:  # the block may carry a new spindle speed
            self._configure(self._view.with_spindle(self._spindle_rpm(t0)))
        block = self._block(src, t0)
        out = block.outputs
        for part in self._parts:
            if self._running(part):
                self._step_part(part, block)
            else:
                out.update(nan_channels(part.channels, src.n))
        res = {k: np.ascontiguousarray(v, dtype=np.float64) for k, v in out.items()}
        self._score(res, block)
        self._last_out = res  # the last values taken when asked for (:attr:`_last`)
        self._samples += src.n
        self._wall += time.perf_counter() - w_start
        return res

    def _step_part(self, part: Part, block: Block) -> None:
        """One part's block: its channels into the block, its events kept, its cost
        counted (its simulation apart); a part that raises is stopped, NaN streamed."""
        sim0 = part.simulated_s
        w0 = time.perf_counter()
        try:
            ch, events = part.step(block)
        except Exception as exc:  # a part's failure is its own: the others go on
            self._stop(part, exc, "step")
            block.outputs.update(nan_channels(part.channels, block.n))
            return
        sim = part.simulated_s - sim0
        cost = self._cost[part.name]
        cost[0] += time.perf_counter() - w0 - sim
        cost[1] += sim
        block.outputs.update(ch)
        for ev in events:
            self.events.put(ev)

    @property
    def _last(self) -> dict[str, float]:
        """Last value of every channel: taken from the last block's outputs when first
        asked for after a step (not at every block: a worker asks a few times a second).
        Writes nothing but its memo, whole: a read racing a step can only recompute."""
        out = self._last_out
        memo = self._last_memo
        if memo[0] is out:
            return memo[1]
        d = {} if out is None else {k: float(v[-1]) for k, v in out.items()}
        self._last_memo = (out, d)
        return d

    @_last.setter
    def _last(self, values: dict[str, float]) -> None:
        # one rebind, as a step's: values of a restored state as one-sample outputs
        self._last_out = {k: np.array([v], dtype=float) for k, v in values.items()}

    # ------------------------------------------------------------------ costs
    def reset_costs(self) -> None:
        """Start counting the costs (:meth:`costs`) again."""
        self._cost: dict[str, list[float]] = collections.defaultdict(lambda: [0.0, 0.0])
        self._samples = 0
        self._wall = 0.0

    def costs(self) -> PipelineCosts:
        """Wall time spent since :meth:`reset_costs` (or the start), over the machine's
        seconds stepped: ``machine_s``; ``wall_s`` (every step); ``parts``: per part its
        ``estimation_s`` and ``simulation_s``; ``source`` (the simulator's stage, or a
        log's or a feed's reading, and the stage's reconfiguration); ``pipeline`` (the
        coordination: the block, the NaN of parts that do not run, the accuracy)."""
        parts: dict[str, PartCosts] = {
            p.name: {"estimation_s": self._cost[p.name][0], "simulation_s": self._cost[p.name][1]}
            for p in self._parts
        }
        source = self._cost["source"][1]
        spent = source + sum(v["estimation_s"] + v["simulation_s"] for v in parts.values())
        return {
            "machine_s": self._samples * self.sample_time,
            "wall_s": self._wall,
            "parts": parts,
            "source": {"simulation_s": source},
            "pipeline": {"estimation_s": max(self._wall - spent, 0.0)},
        }

    def _block(self, src: SourceBlock, t0: float) -> Block:
        """The source's block, wrapped once for every part."""
        nominal = self._force0.offset * self._knobs.number("feed_scale")
        nominal *= self._spindle_factor(t0)
        sim = self.source.knobs_apply
        t = src.meas.t - self.sample_time
        return Block(
            source=src,
            t=t,
            t_end=float(self.source.t),
            machine=self._view,
            knobs=self._knobs,
            plant=BlockPlant(self._force_applied if sim else None, nominal if sim else math.nan),
            notice=self._notice,
            status=self.monitor_status,
            outputs={"t": t},
        )

    def _reference(self) -> str:
        """What the force estimates are scored against: the simulator's ``truth``, the
        ``measured_force`` when the machine measures one (``f_ext``), else ``none``."""
        if self.source.has_truth:
            return "truth"
        return "measured_force" if "f_ext" in self._view.signals else "none"

    def _new_accuracy(self) -> RollingAccuracy:
        return RollingAccuracy(self.force_estimates(), self.sample_time, self._reference())

    def _score(self, out: dict[str, np.ndarray], block: Block) -> None:
        """The block into the rolling accuracy (:mod:`harness.accuracy`): against
        the truth, or the measured force; without either nothing is scored."""
        ref = self._accuracy.reference
        if ref == "truth":
            stage = block.shared.get("stage")
            if stage is not None:
                self._accuracy.update(out, stage.f_true, stage.f_ideal)
        elif ref == "measured_force":
            self._accuracy.update(out, measured=block.source.meas.f_ext)

    def running_force_estimates(self) -> tuple[str, ...]:
        """The force estimates of the parts that run now, in stream order (a part that
        does not run, such as the stage's observers on the machining centre, streams NaN:
        nothing to list)."""
        return _force_estimates(c for p in self._parts if self._running(p) for c in p.channels)

    def accuracy(self, digits: int | None = None) -> AccuracySummary:
        """Rolling rms of the force estimates of the parts that run now, over the last 1 s
        and 10 s (:meth:`harness.accuracy.RollingAccuracy.summary`, every estimate
        scored, those of parts that do not run left out: a part that runs again has its
        row back, its windows kept; ``digits``: rounded, JSON-safe)."""
        summary = self._accuracy.summary(digits)
        live = set(self.running_force_estimates())
        summary["rms"] = {k: v for k, v in summary["rms"].items() if k in live}
        summary["rms_q"] = {k: v for k, v in summary["rms_q"].items() if k in live}
        return summary

    # ------------------------------------------------------------------ what the parts end
    def take_tool_changes(self) -> list[ToolChange]:
        """The tools taken out of the spindle since the last call, part by part, oldest
        first: ``tool``, ``index``, ``start_t``, ``end_t`` [s], ``wear_at_change_mm``,
        ``wear_true_mm``, ``wear_true_share``, ``cause``; the history records them (the
        wear part's tool, changed at its flank-wear limit; the part program's tools)."""
        out: list[ToolChange] = []
        for part in self._parts:
            out += part.take_tool_changes()
        return out

    def take_events(self) -> list[MonitorEvent]:
        """The parts' events raised since the last call, oldest first
        (:mod:`server.records.monitor_events`)."""
        return self.events.take()

    @property
    def tools_changed(self) -> int:
        """Tools changed at the flank-wear limit since the start (0 without tool wear)."""
        wear = self.part("wear")
        return int(wear.tools_changed) if wear is not None else 0

    # ------------------------------------------------------------------ state
    def state(self) -> PipelineState:
        """Everything the pipeline carries from block to block, as one detached value
        (:class:`~server.pipeline.checkpoint.PipelineState`)."""
        st = PipelineState(
            scenario=self.scenario,
            source=self.source.name,
            seed=self.seed,
            t=self.t,
            knobs=self._knobs.as_dict(),
            source_state=self.source.state(),
            script=ScriptState(self._prev_factor, self._weight, self._applied, self._force_applied),
            parts={p.name: p.state() for p in self._parts},
            latest=dict(self._last),
        )
        return copy.deepcopy(st)

    def restore(self, state: PipelineState) -> None:
        """Continue from ``state`` (taken from a pipeline of the same scenario, source
        kind and parts): the next :meth:`step` gives what the pipeline that took it would
        have given. The rolling accuracy starts empty.

        Raises
        ------
        ParameterError
            Another scenario or source, or other parts; nothing is changed then.
        """
        if (state.scenario, state.source) != (self.scenario, self.source.name):
            raise ParameterError(
                "state",
                f"a state of scenario {self.scenario!r} on the {self.source.name} source",
                f"scenario {state.scenario!r} on the {state.source} source",
            )
        mine = [p.name for p in self._parts]
        if sorted(state.parts) != sorted(mine):
            raise ParameterError(
                "state.parts", f"the parts {', '.join(mine)}", ", ".join(state.parts) or "none"
            )
        st = copy.deepcopy(state)
        self._knobs.update(st.knobs)
        self._knob_version += 1
        self.seed = st.seed
        self.source.restore(st.source_state)
        sc = st.script
        self._prev_factor, self._weight = sc.spindle_factor, sc.weight
        self._applied, self._force_applied = sc.applied, sc.force
        for part in self._parts:
            part.restore(st.parts[part.name])
        self._last = dict(st.latest)
        self._accuracy = self._new_accuracy()

    # ------------------------------------------------------------------ status
    def monitor_status(self) -> StatusStrip:
        """What an operator reads from across the shop: the monitor's ``state`` (``off``
        without a process monitor, ``teaching``, ``watching``, ``alarm``: the block under
        way raised an event), the tool in the spindle and the CNC's program, line and
        part (0 / empty / 0 / -1: not known); the wear of one tool, ``wear_tool``, from one
        source: its flank wear as a share of its limit ``wear_limit_mm`` (the alarm at
        ``wear_alarm_share`` of it) and its life left [min] (NaN: not known), with
        ``wear_of`` saying whose tool that is when it is not the spindle's (issue 28: the
        default scenario's wear model is seed 004's turning tool on the stage, not the
        milling machine's T1/T2). Each field comes from the running part that says it
        (the process monitor: state, tool, program, line, part; the wear part: the
        ``wear_*`` fields and the life). ``unacked`` is the runtime's (0 here)."""
        status = _STATUS.copy()
        for part in self._parts:
            if self._running(part):
                status.update(part.status())
        status["unacked"] = 0
        return status

    def machine(self) -> MachineInfo:
        """The machine the source delivers and the parts that watch it (``GET
        /api/machine``): ``source``, ``sample_time`` [s]; ``axes`` (``name``, ``kind``,
        ``signals``: the roles it gives), ``spindle`` (its ``signals``; None without one),
        ``identities``; ``description``: the machine description when the source has one
        (``common/machine.schema.json``; None for the simulated stage, whose one axis
        the rest says); ``parts`` (``name``, ``running``, ``reason``)."""
        v = self._view
        desc = description_of(self.source)
        return {
            "source": self.source.name,
            "scenario": self.scenario,
            "sample_time": v.sample_time,
            "axes": [{"name": a.name, "kind": a.kind, "signals": sorted(a.roles)} for a in v.axes],
            "spindle": {"signals": sorted(v.spindle)} if v.spindle else None,
            "identities": sorted(v.identities),
            "description": desc.to_dict() if desc is not None else None,
            "parts": self.parts(),
        }

    def inject(
        self,
        kind: str,
        size: float | None = None,
        at_t: float | None = None,
        at_part: int | None = None,
    ) -> Scheduled:
        """Schedule an event in the simulated part program
        (:meth:`server.pipeline.process_part.LiveProcess.inject`): ``kind`` one of
        breakage, collision, missing_tool; ``size`` (default: the reproduction's clear
        size) a flute's radius lost [m], a feed multiplier, a share of the engagement
        lost; ``at_t`` a simulated time (the sample then if the program cuts, else the
        middle of the next cut) or ``at_part`` a part number (the middle of its first
        cut); neither: the middle of the cut under way if not past it, else of the next
        cut. Returns what was scheduled.

        Raises
        ------
        ParameterError
            Named by the field: an unknown kind, a size out of range, a time in the past,
            a part already under way, both a time and a part; or a scenario without a
            part program.
        """
        centre = getattr(self.source, "inject", None)
        if self.part("process") is None and callable(centre):
            scheduled: Scheduled = centre(kind, size, at_t, at_part)  # the centre's program
            return scheduled.copy()
        proc = self._process("kind")
        return proc.live.inject(kind, size, at_t, at_part)

    def relearn(self, tool: int | None = None, program: str | None = None) -> Relearned:
        """Restart the monitor's teach-in for a tool's and/or a program's blocks (both
        None: every block); returns ``{"tool", "program", "segments"}`` (segments reset).

        Raises
        ------
        ParameterError
            A bad tool number or program name, or a scenario without a part program.
        """
        return self._process("tool").live.relearn(tool, program)

    def _process(self, field: str) -> Any:
        proc = self.part("process")
        if proc is None:
            raise ParameterError(
                field, "a scenario with a part program (default)", f"scenario {self.scenario!r}"
            )
        return proc

    def process_truths(self) -> list[InjectedTruth]:
        """The injected events placed so far, with their truth (kind, first sample's time
        ``t`` and index ``sample``, size, tool, line, part): for scoring, never given to a
        detector."""
        proc = self.part("process")
        if proc is None:
            return []
        return [
            InjectedTruth(kind=tr.kind, t=tr.t, sample=tr.sample, size=tr.size, tool=tr.tool,
                          line=tr.line, part=tr.part)
            for tr in proc.live.ps.truths
        ]  # fmt: skip

    @property
    def latest(self) -> dict[str, float]:
        """Last value of every channel (empty before the first step)."""
        return dict(self._last)

    @property
    def workpiece_removed(self) -> float:
        """Fraction of the current blank removed (default scenario; else 0)."""
        wp = self.workpiece
        return float(wp.state.removed) if wp is not None else 0.0

    def snapshot(self) -> dict[str, object]:
        """Latest value of every channel, the truth the source knows, the knob values, the
        parts; a source's own status under its name (``"replay"``: path, samples, fed,
        finished)."""
        truth = self.source.truth_summary()
        if self.source.has_truth:
            truth["workpiece_removed"] = self.workpiece_removed
        snap: dict[str, object] = {
            "t": self.t,
            "scenario": self.scenario,
            "latest": dict(self._last),
            "truth": truth,
            "knobs": self.knob_values(),
            "observer_effects": [
                {"name": e.name, "shape": dict(e.shape), "coef": list(e.coef)} for e in self.effects
            ],
            "accuracy": self.accuracy(),
            "parts": self.parts(),
        }
        axes = self.part("axes")
        if axes is not None:  # per axis, what does not run and why
            snap["axes"] = axes.notes()
        status = self.source.status()
        if status:
            snap[self.source.name] = status
        return snap


def _overrides(part: Part, hook: str) -> bool:
    """``part`` has its own ``hook`` (not :class:`LivePart`'s default)."""
    mine = getattr(type(part), hook, None)
    return not isinstance(part, LivePart) or mine is not getattr(LivePart, hook)


def _why(exc: BaseException) -> str:
    """An exception as a reason: its type and message."""
    return f"{type(exc).__name__}: {exc}"
