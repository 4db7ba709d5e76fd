"""Pipeline wiring for the live service: the simulated stage feeding every force observer.

The public surface is the contract the live service builds on:

- ``LivePipeline(scenario: str = "default", seed: int = 0, source=None)``; a log replay
  is ``LivePipeline.from_log(path)``
- ``.sample_time`` (s), ``.t`` (time of the source, s), ``.finished`` (a log has ended)
- ``.channels() -> list[Channel]``: every per-sample output, with unit and group
- ``.step(n) -> dict[str, np.ndarray]``: advance ``n`` samples; one float64 array of
  length ``n`` per channel name (plus ``"t"``)
- ``.knobs() -> dict[str, Knob]``: live-tweakable parameters with their ranges (frozen
  copies; :mod:`server.pipeline.knobs` holds the table)
- ``.set_knob(name, value)``, ``.set_knobs(changes)``: validated (``Knob.check``); raise
  ``ParameterError`` naming the field, the allowed range and the value; nothing changes
  on error
- ``.reset()``; ``.snapshot() -> dict`` (latest values, truths, knob values, accuracy)
- ``.state() -> PipelineState``, ``.restore(state)``: everything carried from block to
  block as one value (:mod:`server.pipeline.checkpoint`, docs/checkpoints.md)
- ``.accuracy() -> dict``: rolling rms of each force estimate over 1 s and 10 s
  (:mod:`server.pipeline.accuracy`)
- ``SCENARIOS``: name -> one-line description

The parts: the scenario (:mod:`server.pipeline.scenarios`: the plant, the script of
spindle steps and mounted weights, the workpiece, tool-wear and eccentricity processes:
:mod:`server.pipeline.workpiece`, :mod:`server.pipeline.wear_passes`,
:mod:`server.pipeline.eccentricity_part`), the observer bank
(:mod:`server.pipeline.observer_bank`) and the channel assembly
(:mod:`server.pipeline.channels`). The pipeline asks its scenario what to do; it never
compares a scenario's name and never reaches into the simulator.

Behind the bank is :class:`server.pipeline.stage_run.StageRun`: a measurement source
(:mod:`server.pipeline.sources`; by default the simulated two-inertia stage of seed 000,
or a replayed log, or a live feed) with the fixed-parameter, adaptive (ordinary RLS) and
switching-RLS force observers. The estimators see the Measurements only; the truth
columns are for display (NaN, but for the reference force, from a source without Truth).
A source's block marked as a discontinuity resets every observer before it is run; a
block of no samples changes nothing.

Scenario events are scheduled on simulated time, so a run is the same whatever the
wall-clock speed. The default scenario: the stage reciprocates while milling; the
workpiece (an inertia of the size of seed 000's added weight) loses mass at
``removal_rate`` % per second until a fresh blank is clamped; every 15 s the spindle
speed steps between the knob's value and 80 % of it (force gain and frequencies, as in
seed 001 Fig. 9).

Identification you can trust (issue 13, ``docs/live-identification.md``): the gated
segment identifier (:mod:`estimators.segment_id`) streams J_L, B_L, F_CL with 95 %
interval bounds and an excited flag (channels ``<p>_seg``, ``<p>_lo``, ``<p>_hi``,
``<p>_excited``). The pipeline tells it what the CNC knows: a spindle step and a tool
change change the cutting force's DC (the reversal segment around them is discarded), a
fresh workpiece changes J_L (it restarts). The wear grows the force smoothly (no steps
at pass boundaries, which fall on the reversals), and a fresh blank is clamped just before
a reversal (the table at its stroke end), not in the middle of a stroke.
"""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from common.errors import ParameterError
from estimators.observer_effects import ObserverEffect
from estimators.rls import IdentifierParams
from machine.effects import EFFECT_NAMES, PlantEffects
from machine.params import ADDED_WEIGHT_INERTIA
from machine.stage import SEED000_FORCE, CuttingForce, StageConfig
from server.pipeline.accuracy import RollingAccuracy
from server.pipeline.channels import (
    CHANNELS,
    FORCE_ESTIMATES,
    BlockParts,
    Channel,
    empty_block,
    finish,
    no_eccentricity,
    stage_channels,
)
from server.pipeline.checkpoint import PipelineState, ScriptState, ToolState
from server.pipeline.eccentricity_part import ECC_BASE_RPM, LiveEccentricity
from server.pipeline.knobs import BASE_RPM, Knob, KnobValue, KnobValues
from server.pipeline.observer_bank import ObserverBank
from server.pipeline.process_part import LiveProcess, no_process
from server.pipeline.scenarios import (
    SCENARIO_OBJECTS,
    SCENARIOS,
    Plant,
    Scenario,
    source_scenario,
)
from server.pipeline.sources import (
    RESUMED,
    MeasurementSource,
    ReplaySource,
    SimulatorSource,
    SourceBlock,
    open_replay,
)
from server.pipeline.stage_run import StageRun
from server.pipeline.wear_alarms import WearAlarms
from server.pipeline.wear_passes import VB_LIMIT, ToolWearPasses
from server.pipeline.workpiece import Workpiece
from server.records.monitor_events import EventOutbox, MonitorEvent

__all__ = [
    "BASE_RPM",
    "CHANNELS",
    "FORCE_ESTIMATES",
    "SCENARIOS",
    "Channel",
    "Knob",
    "LivePipeline",
]


class LivePipeline:
    """The stage and its observers, advanced block by block, with live knobs.

    Parameters
    ----------
    scenario
        One of :data:`SCENARIOS`, when the source is a simulation.
    seed
        Seed of the simulation's random generator.
    source
        Where the measurements come from (:mod:`server.pipeline.sources`). Default: the
        simulator of ``scenario``. A source the knobs do not apply to (a log, a live
        feed) runs with its own name as the scenario (``"replay"``) and the observers
        built from its nominal parameters.
    """

    def __init__(
        self, scenario: str = "default", seed: int = 0, source: MeasurementSource | None = None
    ) -> None:
        if source is not None and not source.knobs_apply:
            sc = source_scenario(source.name)
        elif scenario in SCENARIO_OBJECTS:
            sc = SCENARIO_OBJECTS[scenario]
        else:
            raise ParameterError("scenario", f"one of {sorted(SCENARIOS)}", scenario)
        self.script: Scenario = sc
        self.seed = seed
        self._knobs = KnobValues(sc.knobs)
        self.effects: tuple[ObserverEffect, ...] = ()
        plant = self._plant(source)
        self._plant_cfg = plant
        self._force0: CuttingForce = plant.config.force
        self.source = source or SimulatorSource(plant.config, seed=seed)
        #: events raised and not yet taken (:meth:`take_events`); kept over a reset
        self.events = EventOutbox()
        #: tools taken out of the spindle, not yet taken (:meth:`take_tool_changes`)
        self._tool_changes: list[dict[str, object]] = []
        #: the tool-life monitor's alarms as events, once per tool (wear_limit, life_short)
        self.wear_alarms = WearAlarms()
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
        every estimator again (knobs kept)."""
        sc, k = self.script, self._knobs
        self.source.reset()
        self.bank = ObserverBank(
            self.source,
            self._plant_cfg.ident,
            self._plant_cfg.design,
            tuple(self._force0.frequencies),
            self.effects,
        )
        self.sample_time = float(self.source.sample_time)
        self.last_block: SourceBlock | None = None
        self._weight = math.nan  # seed 000's weight on the load (none applied yet)
        self._prev_factor = self._spindle_factor(0.0)
        self._last: dict[str, float] = {}
        self._applied: tuple[object, ...] = ()
        self._force_applied = self._force0
        # the workpiece needs the table's reversals: the simulated trajectory's
        hp = self._plant_cfg.config.trajectory.half_period
        self.workpiece = Workpiece(hp, self._spindle_factor) if sc.workpiece else None
        self.tool = ToolWearPasses(k.number("wear_rate")) if sc.tool_wear else None
        self._accuracy = RollingAccuracy(
            FORCE_ESTIMATES, self.sample_time, has_truth=self.source.has_truth
        )
        # seed 003's milling machine with eccentricity and its tuner
        self._ecc: LiveEccentricity | None = None
        if sc.eccentricity:
            self._ecc = LiveEccentricity(
                k.number("eccentricity_um"),
                k.number("eccentricity_deg"),
                tuner=str(k["tuner"]),
                enabled=bool(k["esc_on"]),
                force=str(k["ecc_force"]),
                mass_error_pct=k.number("ecc_mass_error"),
            )
        # issue 21: a part program watched by the process monitor
        self._proc: LiveProcess | None = None
        if sc.process:
            self._proc = LiveProcess(
                self.seed,
                teach_parts=int(k.number("teach_parts")),
                band_factor=k.number("band_factor"),
            )
        self._apply(0.0)

    @property
    def run(self) -> StageRun:
        """The stage observers and identifiers (:class:`~server.pipeline.stage_run.StageRun`)."""
        return self.bank.run

    def set_observer_effects(self, effects: tuple[ObserverEffect, ...]) -> None:
        """Install identified effects (issue 4 section 4) into the live observer; ``()``
        removes them. Their terms are subtracted from the fixed-parameter observer's
        force as :mod:`estimators.residual_two_inertia` does (channel ``f_effects``).

        Raises
        ------
        ParameterError
            An effect without its fitted coefficients.
        """
        self.bank.set_effects(tuple(effects))
        self.effects = self.bank.effects

    @property
    def t(self) -> float:
        """Time elapsed: samples taken from the source times the sample time [s]."""
        return float(self.source.t)

    @property
    def finished(self) -> bool:
        """True once the source hands out no more samples (the end of a replayed log)."""
        return bool(self.source.finished)

    # ------------------------------------------------------------------ scenario
    def _spindle_factor(self, t: float) -> float:
        return self.script.spindle_factor(t, self._knobs)

    def _apply(self, t: float) -> None:
        """Set the stage's configuration for the block starting at ``t``."""
        k = self._knobs
        sf = self._spindle_factor(t)
        freq = k.number("spindle_rpm") / BASE_RPM * sf
        wear_gain = self.tool.gain(t) if self.tool is not None else 1.0
        gain = k.number("feed_scale") * sf * wear_gain
        extra = ADDED_WEIGHT_INERTIA if k["weight_on"] else 0.0
        scripted = self.script.extra_inertia(t, k)
        if scripted is not None:
            extra = scripted
        if extra != self._weight:  # the weight mounted or removed: a known J_L change
            if not math.isnan(self._weight) and self.source.knobs_apply:
                self.run.note_restart(J_L=True)
            self._weight = extra
        if self.workpiece is not None:
            extra += self.workpiece.inertia(t)
        if self._ecc is not None:
            self._ecc.configure(
                k.number("eccentricity_um"),
                k.number("eccentricity_deg"),
                str(k["tuner"]),
                bool(k["esc_on"]),
                ECC_BASE_RPM * freq,
                str(k["ecc_force"]),
                k.number("ecc_mass_error"),
            )
        if self._proc is not None:
            self._proc.configure(int(k.number("teach_parts")), k.number("band_factor"))
        noise = k.number("current_noise")
        effects = tuple(e for e in EFFECT_NAMES if k[f"effect_{e}"])
        key = (freq, gain, extra, noise, effects)
        if key == self._applied:
            return
        self._applied = key
        self.bank.retune(tuple(f * freq for f in self._force0.frequencies))
        self._force_applied = replace(self._force0, freq_scale=freq, gain=gain)
        # a log or a live feed ignores it (sources.MeasurementSource.knobs_apply)
        self.source.reconfigure(
            force=self._force_applied,
            extra_inertia=extra,
            current_noise=noise,
            effects=PlantEffects().with_enabled(*effects),
        )

    # ------------------------------------------------------------------ contract
    def channels(self) -> list[Channel]:
        """Every per-sample output of :meth:`step`, with unit and display group."""
        return list(CHANNELS)

    def knobs(self) -> dict[str, Knob]:
        """Live-tweakable parameters with their ranges and current values (frozen copies:
        change them with :meth:`set_knob`)."""
        return self._knobs.knobs()

    def knob_values(self) -> dict[str, KnobValue]:
        """Name -> current value of every knob."""
        return self._knobs.as_dict()

    def set_knob(self, name: str, value: object) -> None:
        """Set one knob; validated (:meth:`server.pipeline.knobs.Knob.check`), nothing
        changes on error.

        Raises
        ------
        ParameterError
            Unknown name, wrong type, or a value outside the knob's range.
        """
        self._knobs.set(name, value)

    def set_knobs(self, changes: Mapping[str, object]) -> None:
        """Set several knobs, all or nothing.

        Raises
        ------
        ParameterError
            The first refused change (nothing is changed then).
        """
        self._knobs.update(changes)

    def step(self, n: int) -> dict[str, np.ndarray]:
        """Advance ``n`` samples; return ``"t"`` and every channel, ``n`` values each.

        Estimates refer to the previous sample (see :mod:`server.pipeline.stage_run`); ``t`` is the
        time they refer to, and the truth columns are aligned to it. A source that has
        fewer samples (the end of a log, a live feed) gives fewer values, or none: then
        nothing changes, not even ``t``. A block the source marks as a discontinuity
        resets every observer first (:meth:`_discontinuity`).
        """
        t0 = float(self.source.t)
        self._script(t0, n)
        block = self.source.step(n)
        self.last_block = block  # the measurements as the source gave them (recording)
        n = block.n
        if n == 0:
            return empty_block()
        if block.discontinuity is not None:
            self._discontinuity(block.discontinuity, float(block.meas.t[0]))
        bb = self.bank.process(block)
        if self.tool is not None:
            nominal = self._force0.offset * self._knobs.number("feed_scale")
            nominal *= self._spindle_factor(t0)
            worn = self.tool.accumulate(n, bb.stage.f_adaptive, nominal, self.sample_time)
            self._wear_events(float(block.meas.t[-1]))  # before a change resets the estimate
            if worn:
                self._new_tool()
        parts = BlockParts(
            b=bb.stage,
            dfo=bb.dfo,
            f_effects=bb.f_effects,
            true_amplitudes=self._true_amplitudes(),
            wear=self._wear_values(),
            spindle_rpm=self._knobs.number("spindle_rpm") * self._spindle_factor(t0),
        )
        out = stage_channels(parts, self.sample_time)
        if self._ecc is not None:
            out.update(self._ecc.step(out["t"], self.sample_time))
        else:
            out.update(no_eccentricity(n))
        if self._proc is not None:
            mon, events = self._proc.step(out["t"], self.sample_time)
            out.update(mon)
            for ev in events:
                self.events.put(ev)
        else:
            out.update(no_process(n))
        out = finish(out, has_truth=self.source.has_truth)
        self._score(out, bb.stage.f_true, bb.stage.f_ideal)
        self._last = {k: float(v[-1]) for k, v in out.items()}
        return out

    def _script(self, t0: float, n: int) -> None:
        """The scenario's events before the block of ``n`` samples starting at ``t0``:
        the workpiece's removal and clamp, the tool's pass, a spindle step; then the
        stage's configuration for the block."""
        if self.workpiece is not None:
            rate = self._knobs.number("removal_rate") / 100.0
            if self.workpiece.advance(t0, n, self.sample_time, rate):
                self.run.note_restart(J_L=True)  # a fresh blank: J_L changes
        if self.tool is not None:
            self.tool.begin(t0, self._knobs.number("wear_rate"))
        factor = self._spindle_factor(t0)
        if factor != self._prev_factor:  # a spindle step: the force's DC changes
            self.run.note_disturbance(t0)
            self._prev_factor = factor
        self._apply(t0)

    def _new_tool(self) -> None:
        """A sharp tool at the flank-wear limit; the CNC knows a tool change: the force's
        DC steps back to the sharp tool's. The worn tool's life is recorded
        (:meth:`take_tool_changes`)."""
        assert self.tool is not None
        self._tool_changes.append(self._tool_life_record("wear_limit"))
        self.tool.new_tool(self._knobs.number("wear_rate"))
        self.tool.state.tool_start_t = self.t
        self.run.note_disturbance(self.t)

    def _tool_life_record(self, cause: str) -> dict[str, object]:
        """The life of the tool in the spindle, ending now: its tool number (the CNC's,
        when the source gives one; else the wearing tool's place in the sequence),
        its index (1 for the first tool of the run), the source times it was mounted
        and changed, the estimated flank wear at the change (what the service knows;
        None before the first estimate), the simulator's true wear (None without
        truth) and the cause."""
        assert self.tool is not None
        st = self.tool.state
        index = st.tools_changed + 1
        number = self.monitor_status().get("tool")
        vb_est = st.vb_est if math.isfinite(st.vb_est) else None
        return {
            "tool": number if isinstance(number, int) and number > 0 else index,
            "index": index,
            "start_t": st.tool_start_t,
            "end_t": self.t,
            "wear_at_change_mm": vb_est,
            "wear_true_mm": st.vb_true if self.source.has_truth else None,
            "wear_true_share": st.vb_true / VB_LIMIT if self.source.has_truth else None,
            "cause": cause,
        }

    def _part_tool_changes(self) -> list[dict[str, object]]:
        """The part program's tool changes (:meth:`LiveProcess.take_tool_changes`) as
        tool lives: the simulated machine's wear as a share of the tool's limit (a truth:
        no estimate of it), the cause ``wear_limit`` for a worn tool, else the alarm after
        which the operator changed it."""
        if self._proc is None:
            return []
        program = self._proc.ps.machine.program
        out: list[dict[str, object]] = []
        for c in self._proc.take_tool_changes():
            number, wear = c["tool"], c["wear"]
            assert isinstance(number, int) and isinstance(wear, float | int)
            cause = str(c["cause"])
            out.append(
                {
                    "tool": number,
                    "index": None,
                    "start_t": c["start_t"],
                    "end_t": c["end_t"],
                    "wear_at_change_mm": None,
                    "wear_true_share": float(wear) / program.tool(number).wear_limit,
                    "cause": "wear_limit" if cause == "worn" else cause,
                }
            )
        return out

    def take_tool_changes(self) -> list[dict[str, object]]:
        """The tools taken out of the spindle since the last call, oldest first: ``tool``,
        ``index``, ``start_t``, ``end_t`` [s], ``wear_at_change_mm``, ``wear_true_mm``,
        ``wear_true_share``, ``cause``; the history records them. Two kinds: the wearing
        tool of the stage (seed 004's wear, changed at its flank-wear limit; ``index`` its
        place in the run) and the part program's tools (changed worn, or after a breakage
        or missing-tool alarm; ``index`` None, no estimate of the wear)."""
        out, self._tool_changes = self._tool_changes, []
        return out + self._part_tool_changes()

    def _wear_events(self, t: float) -> None:
        """The tool-life monitor's alarms on the wear estimate (:mod:`server.pipeline.wear_alarms`)
        into :attr:`events`, once per tool."""
        assert self.tool is not None
        s = self.tool.state
        for ev in self.wear_alarms.check(
            t, s.tools_changed, s.vb_est, VB_LIMIT, s.life_left, self.monitor_status()
        ):
            self.events.put(ev)

    @property
    def tools_changed(self) -> int:
        """Tools changed at the flank-wear limit since the start (0 without tool wear)."""
        return self.tool.state.tools_changed if self.tool is not None else 0

    # ------------------------------------------------------------------ state
    def state(self) -> PipelineState:
        """Everything the pipeline carries from block to block, as one detached value
        (:class:`~server.pipeline.checkpoint.PipelineState`)."""
        tool = ToolState(self.tool.state, self.tool.wear) if self.tool is not None else None
        proc, taught = self._proc.state() if self._proc is not None else (None, {})
        st = PipelineState(
            scenario=self.scenario,
            source=self.source.name,
            seed=self.seed,
            t=self.t,
            knobs=self._knobs.as_dict(),
            effects=self.effects,
            source_state=self.source.state(),
            estimators=self.bank.state(),
            script=ScriptState(self._prev_factor, self._weight, self._applied, self._force_applied),
            workpiece=self.workpiece.state if self.workpiece is not None else None,
            tool=tool,
            eccentricity=self._ecc,
            latest=dict(self._last),
            process=proc,
            taught=taught,
        )
        return copy.deepcopy(st)

    def restore(self, state: PipelineState) -> None:
        """Continue from ``state`` (taken from a pipeline of the same scenario and source
        kind): the next :meth:`step` gives what the pipeline that took it would have
        given. The rolling accuracy starts empty.

        Raises
        ------
        ParameterError
            Another scenario or source, or parts the scenario does not have; nothing is
            changed then.
        """
        if (state.scenario, state.source) != (self.scenario, self.source.name):
            raise ParameterError(
                "state",
                f"a state of scenario {self.scenario!r} on the {self.source.name} source",
                f"scenario {state.scenario!r} on the {state.source} source",
            )
        for part, mine, theirs in (
            ("workpiece", self.workpiece, state.workpiece),
            ("tool", self.tool, state.tool),
            ("eccentricity", self._ecc, state.eccentricity),
            ("process", self._proc, state.process),
        ):
            if (mine is None) != (theirs is None):
                raise ParameterError(f"state.{part}", "as the scenario has it", theirs)
        st = copy.deepcopy(state)
        self._knobs.update(st.knobs)
        self.seed = st.seed
        self.set_observer_effects(st.effects)
        self.source.restore(st.source_state)
        self.bank.restore(st.estimators)
        sc = st.script
        self._prev_factor, self._weight = sc.spindle_factor, sc.weight
        self._applied, self._force_applied = sc.applied, sc.force
        if self.workpiece is not None and st.workpiece is not None:
            self.workpiece.state = st.workpiece
        if self.tool is not None and st.tool is not None:
            self.tool.state, self.tool.wear = st.tool.passes, st.tool.wear
        self._ecc = st.eccentricity
        if self._proc is not None and st.process is not None:
            k = self._knobs
            self._proc.restore(
                st.process, st.taught, int(k.number("teach_parts")), k.number("band_factor")
            )
        self._last = dict(st.latest)
        self._accuracy = RollingAccuracy(
            FORCE_ESTIMATES, self.sample_time, has_truth=self.source.has_truth
        )

    def _true_amplitudes(self) -> np.ndarray:
        """The harmonics' true amplitudes of the force the stage is given (NaN when the
        source has no truth: the force applied is then not the one measured)."""
        if not self.source.has_truth:
            return np.full(len(self._force0.amplitudes), math.nan)
        f = self._force_applied
        return np.asarray(f.amplitudes, dtype=np.float64) * f.gain

    def _wear_values(self) -> dict[str, float]:
        s = self.tool.state if self.tool is not None else None
        return {
            "vb_true": s.vb_true if s is not None else 0.0,
            "vb_est": s.vb_est if s is not None else math.nan,
            "vb_limit": VB_LIMIT,
            "life_left": s.life_left if s is not None else math.nan,
        }

    def _score(self, out: dict[str, np.ndarray], f_true: np.ndarray, f_ideal: np.ndarray) -> None:
        """The block into the rolling accuracy (:mod:`server.pipeline.accuracy`): against
        the truth, or without one the estimates' agreement with their mean (f_effects
        left out of it while no effect is installed: it is then f_fixed again)."""
        if self.source.has_truth:
            self._accuracy.update(out, f_true, f_ideal)
        else:
            skip = () if self.bank.fx is not None else ("f_effects",)
            self._accuracy.update(out, mean_of=[k for k in FORCE_ESTIMATES if k not in skip])

    def accuracy(self, digits: int | None = None) -> dict[str, object]:
        """Rolling rms of every force estimate over the last 1 s and 10 s
        (:meth:`server.pipeline.accuracy.RollingAccuracy.summary`; ``digits``: rounded,
        JSON-safe)."""
        return self._accuracy.summary(digits)

    def _discontinuity(self, reason: str, t: float) -> None:
        """The source's next block (starting at ``t``) does not continue the last one (a
        gap, a restart): every observer starts again from its initial state, as in a
        fresh pipeline; after a restart from a checkpoint (:data:`RESUMED`) only the
        filters on the measurements do. The wear pass under way is not given to the
        monitor."""
        if reason == RESUMED:
            self.bank.restart_filters(t)
        else:
            self.bank.reset()
        if self.tool is not None:  # a wear pass under way spans the gap
            self.tool.interrupt()

    def take_events(self) -> list[MonitorEvent]:
        """The monitor's events raised since the last call, oldest first
        (:mod:`server.records.monitor_events`)."""
        return self.events.take()

    def monitor_status(self) -> dict[str, object]:
        """What an operator reads from across the shop: the monitor's ``state``
        (``off`` without a process monitor, ``teaching``, ``watching``, ``alarm``: the
        block under way raised an event), the tool in the spindle and its flank wear as a
        share of the limit, the life left [min] (NaN: not known), and the CNC's program,
        line and part (empty / 0 / -1: not known). ``unacked`` is the service's (0 here).
        """
        w = self._wear_values()
        share = w["vb_est"] / w["vb_limit"] if math.isfinite(w["vb_est"]) else math.nan
        status: dict[str, object] = {
            "state": "off",
            "tool": 0,
            "program": "",
            "line": 0,
            "part": -1,
        }
        if self._proc is not None:
            status.update(self._proc.status())
        return status | {"wear_share": share, "life_left_min": w["life_left"], "unacked": 0}

    def _process(self, field: str) -> LiveProcess:
        if self._proc is None:
            raise ParameterError(
                field, "a scenario with a part program (default)", f"scenario {self.scenario!r}"
            )
        return self._proc

    def inject(
        self,
        kind: str,
        size: float | None = None,
        at_t: float | None = None,
        at_part: int | None = None,
    ) -> dict[str, object]:
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
        return self._process("kind").inject(kind, size, at_t, at_part)

    def relearn(self, tool: int | None = None, program: str | None = None) -> dict[str, object]:
        """Restart the monitor's teach-in for a tool's and/or a program's blocks (both
        None: every block); returns ``{"tool", "program", "segments"}`` (segments reset).

        Raises
        ------
        ParameterError
            A bad tool number or program name, or a scenario without a part program.
        """
        return self._process("tool").relearn(tool, program)

    def process_truths(self) -> list[dict[str, object]]:
        """The injected events placed so far, with their truth (kind, first sample's time
        ``t`` and index ``sample``, size, tool, line, part): for scoring, never given to a
        detector."""
        if self._proc is None:
            return []
        return [dict(tr.__dict__) for tr in self._proc.ps.truths]

    @property
    def latest(self) -> dict[str, float]:
        """Last value of every channel (empty before the first step)."""
        return dict(self._last)

    @property
    def workpiece_removed(self) -> float:
        """Fraction of the current blank removed (default scenario; else 0)."""
        return self.workpiece.state.removed if self.workpiece is not None else 0.0

    def snapshot(self) -> dict[str, object]:
        """Latest value of every channel, the truth the source knows and the knob values;
        a source's own status under its name (``"replay"``: path, samples, fed, finished).
        """
        truth = self.source.truth_summary()
        if self.source.has_truth:
            truth["workpiece_removed"] = self.workpiece_removed
        snap: dict[str, object] = {
            "t": self.t,
            "scenario": self.scenario,
            "latest": dict(self._last),
            "truth": truth,
            "knobs": self._knobs.as_dict(),
            "observer_effects": [
                {"name": e.name, "shape": dict(e.shape), "coef": list(e.coef)} for e in self.effects
            ],
            "accuracy": self.accuracy(),
        }
        status = self.source.status()
        if status:
            snap[self.source.name] = status
        return snap
