"""Process monitoring, run beside the live stage (issue 21 in the loop).

:class:`ProcessPart` is the live part (:mod:`server.pipeline.part`): its channels and the
monitor's chart are declared here, its share of the status strip is the monitor's state and
the CNC's tool, program, line and part; it simulates the part program beside the stage, so
it runs with the simulator only. :class:`LiveProcess` runs a part program on seed 003's
milling machine and X/Y feed drives (:class:`machine.process.ProcessMachine`, 5 kHz),
estimates the cutting force from the drives
(:class:`harness.eccentricity_loop.ObserverForceSource`: the seed-000 observers on
each feed axis, scale quantised, current noise, a 2 % mass error; never the simulator's
force) and watches it with the teach-in monitor
(:class:`estimators.monitoring.process.ProcessMonitor`). Each block of the stage (2.5 kHz)
advances it by the same simulated time (the fractional remainder carried over, as
:mod:`server.pipeline.eccentricity_part` does) and its values are picked on the stage's
sample grid: the value at the latest machine sample not after the stage sample.

The shop it simulates: :func:`machine.process.default_program` cut part after part
(about 12 s each: a face and a slot with T1, a tool change, a contour with T2, air moves
with entries and exits between them), a feed override other than 100 % on one part in
five, the workpiece's depth varying by 2 % from blank to blank, the tools wearing (edge
force growing) and replaced by new instances (another runout) at their wear limit.
Detectors run per sample inside the monitor's kernel, so their delays do not depend on
the live block size. A broken or missing tool, once alarmed, is replaced by a fresh
instance at the end of the part (the operator's tool change after the feed hold);
undetected, a broken tooth stays broken.

Injection (:meth:`LiveProcess.inject`): an event is scheduled at a simulated time
(``at_t``: the sample at that time if the program cuts then; in an air move it waits for
the middle of the next cut: a tooth breaks, a tool collides or goes missing in a cut), at
a part (``at_part``: the middle of that part's first cut), or, with neither, at the
middle of the cut under way if it has not passed it, else of the next cut (an operator's
"now" that the detectors can see: a tooth broken on the entry ramp, before the block is
taught as cutting, changes the pattern where the breakage detector does not look).
Default sizes are the middle of the reproduction's "clear" ranges (``docs/reproductions``,
``server/experiments/reproductions/process_monitoring.py``): a breakage loses 0.4 mm of
a flute's radius (the tooth is gone), a collision drives the feed to 6x, a missing tool
has lost all its engagement.

The eccentricity canceller. The issue asks that seed 003's canceller hold its adaptation
while a breakage is suspected. The live eccentricity loop
(:mod:`server.pipeline.eccentricity_part`) runs its *own* milling machine (seed 003's
case-1 tool in a continuous cut); a tooth broken here does not change the force it
adapts on, so holding it on this monitor's flag would be a wire between two different
machines, not a hold: it is not done. The flag is streamed (``mon_suspected``) and the
hold itself is measured where one machine carries both, in the reproduction's canceller
cases (``run_canceller_case``: ESC on the monitored machine, held while suspected).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, TypedDict, cast

import numpy as np

from common.arrays import F64
from common.errors import ParameterError
from common.event_kinds import EventKind, ProcessEventKind
from estimators.monitoring.process import Alarm, MonitorParams, ProcessMonitor
from harness.eccentricity_loop import ObserverForceSource
from machine.milling import MillingRecord
from machine.process import (
    EVENT_KINDS,
    BlockRun,
    EventTruth,
    ProcessEvent,
    ProcessMachine,
    default_program,
)
from server.pipeline.estimates_out import StatusStrip
from server.pipeline.machine_view import MachineView
from server.pipeline.part import (
    Block,
    Channel,
    Chart,
    LivePart,
    Outputs,
    Setup,
    Verdict,
    needs_simulator,
)
from server.pipeline.sources import Scheduled
from server.records.history.store import ToolChange
from server.records.monitor_events import DEFAULT_ACTIONS, MonitorEvent

#: default size of each injected kind: the middle of the reproduction's clear range
CLEAR_SIZES: dict[ProcessEventKind, float] = {
    ProcessEventKind.BREAKAGE: 0.4e-3,
    ProcessEventKind.COLLISION: 6.0,
    ProcessEventKind.MISSING_TOOL: 1.0,
}
#: the sizes an injection accepts: (lower bound (open), upper bound (closed), unit, what)
SIZE_RANGES: dict[ProcessEventKind, tuple[float, float, str, str]] = {
    ProcessEventKind.BREAKAGE: (0.0, 2e-3, "m", "radius lost by the flute"),
    ProcessEventKind.COLLISION: (1.0, 20.0, "", "feed multiplier"),
    ProcessEventKind.MISSING_TOOL: (0.0, 1.0, "", "share of the engagement lost"),
}
#: the monitor's states, as streamed in ``mon_state``
STATES = ("teaching", "watching", "alarm")
#: an injected event's kind, as streamed in ``mon_event_true`` (0: none)
KIND_CODES: dict[str, int] = {k: i + 1 for i, k in enumerate(EVENT_KINDS)}
#: the detectors whose alarm means the tool is lost (the shop changes it)
_TOOL_LOST = (ProcessEventKind.BREAKAGE, ProcessEventKind.MISSING_TOOL)
#: unit of each detector's statistic
_UNITS = {
    ProcessEventKind.BREAKAGE: "1",
    ProcessEventKind.COLLISION: "N",
    ProcessEventKind.MISSING_TOOL: "N",
}

#: channel name -> (unit, label); group "monitor"
MON_CHANNELS: dict[str, tuple[str, str]] = {
    "mon_f": ("N", "force magnitude estimated from the X/Y drives"),
    "mon_mean": ("N", "its mean over the last spindle revolution"),
    "mon_upper": ("N", "upper band of the mean (taught, override and wear scaled)"),
    "mon_lower": ("N", "lower band of the mean (missing-tool limit)"),
    "mon_extreme": ("N", "extreme limit of the force (collision)"),
    "mon_state": ("", "monitor state: 0 teaching, 1 watching, 2 alarm"),
    "mon_tool": ("", "tool in the spindle (T)"),
    "mon_line": ("", "program block (G-code line N)"),
    "mon_part": ("", "part counter"),
    "mon_override": ("%", "feed override"),
    "mon_pattern": ("1", "change of the once-per-revolution pattern over a revolution"),
    "mon_pattern_limit": ("1", "breakage threshold on the pattern change"),
    "mon_suspected": ("", "breakage suspected (1) or not (0)"),
    "mon_event_true": (
        "",
        "truth: injected event from its first sample to its block's end "
        "(1 breakage, 2 collision, 3 missing tool, 0 none)",
    ),
}


@dataclass
class Injection:
    """An event scheduled and not yet placed in the simulator (:meth:`LiveProcess.inject`)."""

    kind: str
    size: float
    at_t: float | None
    at_part: int | None
    flute: int = 0


class ProgramToolChange(TypedDict):
    """A tool the part program changed (:meth:`LiveProcess.take_tool_changes`): its
    number, the instance's start and end [s], its wear (edge-coefficient growth,
    :class:`machine.process.Tool`) and the cause (``worn``, ``breakage``, ``missing_tool``)."""

    tool: int
    start_t: float
    end_t: float
    wear: float
    cause: str


@dataclass
class ProcessState:
    """Everything :class:`LiveProcess` carries from block to block but the monitor's
    taught arrays (those are :attr:`LiveProcess.taught`)."""

    machine: ProcessMachine
    observer: ObserverForceSource
    run: BlockRun | None = None
    block_index: int = 0
    part_draw: tuple[float, float] = (1.0, 1.0)
    carry: float = 0.0
    new_block: bool = True
    alarmed: bool = False
    pending: list[Injection] = field(default_factory=list)
    replace_tools: list[tuple[int, str]] = field(default_factory=list)
    truths: list[EventTruth] = field(default_factory=list)
    last: dict[str, float] = field(default_factory=dict)
    tool_since: dict[int, float] = field(default_factory=dict)
    tool_changes: list[ProgramToolChange] = field(default_factory=list)


class Relearned(TypedDict):
    """What a relearn reset (:meth:`LiveProcess.relearn`): the tool and program asked
    (None: every one) and the segments whose teach-in starts again."""

    tool: int | None
    program: str | None
    segments: int


class LiveProcess:
    """The part program, the drives' force estimate and the monitor, advanced by the
    stage's blocks (module docstring).

    Parameters
    ----------
    seed : int
        Seed of the shop's draws (overrides, depths, new tools' runout) and the current
        noise.
    teach_parts : int
        Good parts taught per (tool, program, block) before watching.
    band_factor : float
        Width of the bands in taught spreads (:class:`MonitorParams`).
    """

    def __init__(self, seed: int = 0, *, teach_parts: int = 5, band_factor: float = 4.0) -> None:
        rng = np.random.default_rng([21, int(seed)])
        machine = ProcessMachine(default_program(), rng=np.random.default_rng(rng.integers(2**32)))
        observer = ObserverForceSource(
            machine.drives,
            mass_error=0.02,
            current_noise=0.01,
            rng=np.random.default_rng(rng.integers(2**32)),
        )
        self.ps = ProcessState(machine, observer)
        self.sample_time = machine.sample_time
        self.monitor = ProcessMonitor(
            MonitorParams(
                sample_time=self.sample_time, teach_parts=int(teach_parts), band_factor=band_factor
            )
        )
        #: the monitor's state: the taught tables and its running sums (a dict of arrays)
        self.taught: dict[str, np.ndarray] = self.monitor.initial_state()
        self.fine: dict[str, F64] = {}
        #: wall seconds spent simulating the machine and its program (not estimating)
        self.sim_s = 0.0

    # ------------------------------------------------------------------ knobs
    def configure(self, teach_parts: int, band_factor: float) -> None:
        """Apply the knobs: a new ``teach_parts`` restarts the teach-in of every segment,
        a new ``band_factor`` widens or narrows the bands from the next sample on."""
        p = self.monitor.params
        if (int(teach_parts), float(band_factor)) == (p.teach_parts, p.band_factor):
            return
        self.monitor = ProcessMonitor(
            replace(p, teach_parts=int(teach_parts), band_factor=float(band_factor))
        )
        if int(teach_parts) != p.teach_parts:
            self.monitor.relearn(self.taught)

    # ------------------------------------------------------------------ operator
    @property
    def t(self) -> float:
        """The machine's simulated time [s]."""
        return self.ps.machine.t

    def inject(
        self,
        kind: str,
        size: float | None = None,
        at_t: float | None = None,
        at_part: int | None = None,
    ) -> Scheduled:
        """Schedule an event (module docstring); returns what was scheduled.

        Raises
        ------
        ParameterError
            An unknown ``kind``, a ``size`` outside its kind's range, ``at_t`` in the past
            or not finite, ``at_part`` not a part still to come, or both given.
        """
        if kind not in EVENT_KINDS:
            raise ParameterError("kind", "one of " + ", ".join(EVENT_KINDS), kind)
        lo, hi, unit, what = SIZE_RANGES[ProcessEventKind(kind)]
        if size is None:
            size = CLEAR_SIZES[ProcessEventKind(kind)]
        if (
            isinstance(size, bool)
            or not isinstance(size, int | float)
            or not (math.isfinite(size) and lo < size <= hi)
        ):
            raise ParameterError("size", f"a {what} in ({lo:g}, {hi:g}] {unit}".rstrip(), size)
        if at_t is not None and at_part is not None:
            raise ParameterError("at_t", "no time when at_part is given (one of them)", at_t)
        now = self.t
        if at_part is not None:
            first = self._first_part_free()
            if isinstance(at_part, bool) or not isinstance(at_part, int) or at_part < first:
                raise ParameterError("at_part", f"a part number >= {first}", at_part)
        elif at_t is None:
            pass  # the middle of the cut under way, or of the next one
        elif (
            isinstance(at_t, bool)
            or not isinstance(at_t, int | float)
            or not math.isfinite(at_t)
            or at_t < now - 1e-9
        ):
            raise ParameterError("at_t", f"a simulated time >= {now:.4f} s (now)", at_t)
        inj = Injection(kind, float(size), None if at_t is None else float(at_t), at_part)
        self.ps.pending.append(inj)
        return {
            "kind": kind,
            "size": inj.size,
            "unit": unit,
            "at_t": inj.at_t,
            "at_part": at_part,
            "now": now,
            "where": self._where(inj),
        }

    @staticmethod
    def _where(inj: Injection) -> str:
        if inj.at_part is not None:
            return "the middle of that part's first cut"
        if inj.at_t is None:
            return "the middle of the cut under way (if not past it), else of the next cut"
        return "the sample at at_t if the program cuts then, else the middle of the next cut"

    def _first_part_free(self) -> int:
        """The first part whose first cut has not started."""
        m, ps = self.ps.machine, self.ps
        blocks = m.program.blocks
        first_cut = next(i for i, b in enumerate(blocks) if b.cut)
        started = ps.block_index > first_cut or (
            ps.block_index == first_cut and ps.run is not None and ps.run.done > 0
        )
        return m.part + 1 if started else m.part

    def relearn(self, tool: int | None = None, program: str | None = None) -> Relearned:
        """Restart the teach-in of a tool's and/or a program's segments (both None: all);
        returns the segments reset.

        Raises
        ------
        ParameterError
            ``tool`` not a tool number >= 1, ``program`` not a name of 1-32 characters.
        """
        if tool is not None and (isinstance(tool, bool) or not isinstance(tool, int) or tool < 1):
            raise ParameterError("tool", "a tool number >= 1", tool)
        if program is not None and (not isinstance(program, str) or not 0 < len(program) <= 32):
            raise ParameterError("program", "a program name of 1-32 characters", program)
        n = self.monitor.relearn(self.taught, tool=tool, program=program)
        return {"tool": tool, "program": program, "segments": n}

    # ------------------------------------------------------------------ stepping
    def step(self, t: F64, dt: float) -> tuple[dict[str, F64], list[MonitorEvent]]:
        """Advance by ``t.size * dt`` of simulated time; channels picked at the times ``t``,
        and the events the monitor raised."""
        ps = self.ps
        n = t.size
        want = n * dt / self.sample_time + ps.carry
        m = int(math.floor(want + 1e-9))
        ps.carry = want - m
        if m <= 0:
            return self._hold(n), []
        parts: list[dict[str, F64]] = []
        events: list[MonitorEvent] = []
        left = m
        while left > 0:
            w0 = time.perf_counter()
            run = self._block()
            c = min(left, run.left)
            self._place_pending(run, c)
            self.sim_s += time.perf_counter() - w0
            rows, evs = self._chunk(run, c)
            parts.append(rows)
            events += evs
            left -= c
            if run.left == 0:
                w0 = time.perf_counter()
                self._close_block(run)
                self.sim_s += time.perf_counter() - w0
        if len(parts) == 1:
            cols = parts[0]
        else:
            cols = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        #: the last step's columns at the machine's own rate (5 kHz, with "t"): for a
        #: sample-exact look at the detectors
        self.fine = dict(cols)
        te = cols.pop("t")
        idx = np.clip(np.searchsorted(te, t + 1e-12, side="right") - 1, 0, te.size - 1)
        res = {k: v[idx] for k, v in cols.items()}
        ps.last = {k: float(v[-1]) for k, v in res.items()}
        return res, events

    def _block(self) -> BlockRun:
        """The block under way, starting the next one (and the next part) if none is."""
        ps = self.ps
        if ps.run is None:
            m = ps.machine
            if ps.block_index == 0:
                ps.part_draw = m.begin_part()
            blk = m.program.blocks[ps.block_index]
            ps.run = m.begin_block(blk, override=ps.part_draw[0], depth_scale=ps.part_draw[1])
            ps.new_block = True
            ps.alarmed = False
            run = ps.run
            if blk.cut:
                # events waiting for a cut: at_t passed in an air move, or this part's first
                self._place_at_start(run)
        return ps.run

    def _place_at_start(self, run: BlockRun) -> None:
        ps, m = self.ps, self.ps.machine
        first_cut = next(b.line for b in m.program.blocks if b.cut)
        for inj in list(ps.pending):
            soon = inj.at_t is None and inj.at_part is None
            due = (
                soon
                or (inj.at_t is not None and inj.at_t <= m.t)
                or (inj.at_part == run.part and run.blk.line == first_cut)
            )
            if due and not run.event:
                self._place(run, inj, run.n_total // 2)

    def _place_pending(self, run: BlockRun, c: int) -> None:
        """An event due at a time inside the next ``c`` samples of a cut block."""
        if not run.blk.cut or run.event:
            return
        m = self.ps.machine
        for inj in self.ps.pending:
            if inj.at_t is None:
                if inj.at_part is None and run.done <= run.n_total // 2:
                    self._place(run, inj, run.n_total // 2)  # "now": this cut's middle
                    return
                continue
            k = max(math.ceil(inj.at_t / self.sample_time - 1e-9), m.k)
            if k < m.k + c:
                self._place(run, inj, k - run.k_start)
                return

    def _place(self, run: BlockRun, inj: Injection, at: int) -> None:
        ps = self.ps
        flute = inj.flute
        if inj.kind == ProcessEventKind.BREAKAGE:
            # the flute with the most edge left (a flute broken already, and not yet
            # changed, would lose nothing more)
            flute = int(np.argmax(run.dr1[: run.tool.n_flutes]))
        ev = ProcessEvent(inj.kind, run.part, run.blk.line, 0.0, inj.size, flute)
        ps.truths.append(ps.machine.place_event(run, ev, at))
        ps.pending.remove(inj)

    def _chunk(self, run: BlockRun, c: int) -> tuple[dict[str, F64], list[MonitorEvent]]:
        """``c`` samples of the block through the drives' observer and the monitor."""
        ps = self.ps
        w0 = time.perf_counter()
        rec = ps.machine.advance(run, c)
        self.sim_s += time.perf_counter() - w0
        # the observer reads what both records share: ix, iy, x, y
        fx, fy = ps.observer(cast(MillingRecord, rec))
        mr = self.monitor.step(
            self.taught,
            fx,
            fy,
            rec.psi,
            tool=rec.tool,
            program=rec.program,
            line=rec.line,
            new_block=ps.new_block,
            override=rec.override,
            # what the program says of the block before it runs: a feed at its feed per
            # tooth (a cut) or an air move at the air speed (watched for collisions only)
            cutting=bool(run.blk.cut),
        )
        ps.new_block = False
        # the block's segment (the monitor's running state, _RUN "seg"): taught or not
        teaching = self.monitor.teaching(self.taught, int(self.taught["run"][0]))
        state = np.full(c, 0.0 if teaching else 1.0)
        if ps.alarmed:
            state[:] = 2.0
        k_first = int(self.taught["samples"][0]) - c
        events = []
        for a in mr.alarms:
            j = a.sample - k_first
            state[j:] = 2.0
            ps.alarmed = True
            events.append(self._event(a, float(rec.t[j]), run.part))
            if a.detector in _TOOL_LOST and all(
                number != rec.tool for number, _ in ps.replace_tools
            ):
                ps.replace_tools.append((rec.tool, a.detector))
        # the truth: the injected event's kind from its first sample to its block's end
        true = np.full(
            c, float(KIND_CODES.get(run.event, 0)) if run.k_ev < rec.k0 - run.k_start else 0.0
        )
        for tr in rec.events:
            true[tr.sample - rec.k0 :] = KIND_CODES[tr.kind]
        rows = {
            "t": rec.t,
            "mon_f": mr.f,
            "mon_mean": mr.f_mean,
            "mon_upper": mr.upper,
            "mon_lower": mr.lower,
            "mon_extreme": mr.extreme,
            "mon_state": state,
            "mon_tool": np.full(c, float(rec.tool)),
            "mon_line": np.full(c, float(rec.line)),
            "mon_part": np.full(c, float(rec.part)),
            "mon_override": np.full(c, 100.0 * rec.override),
            "mon_pattern": mr.pattern,
            "mon_pattern_limit": mr.pattern_limit,
            "mon_suspected": mr.suspected.astype(np.float64),
            "mon_event_true": true,
        }
        return rows, events

    def _event(self, a: Alarm, t: float, part: int) -> MonitorEvent:
        kind = EventKind(a.detector)
        where = f"T{a.tool} at N{a.line} (program {a.program}, part {part})"
        if kind == EventKind.BREAKAGE:
            msg = (
                f"Tool breakage suspected on {where}: the once-per-revolution force pattern "
                f"changed by {a.value:.2f} of the mean force (limit {a.limit:.2f})."
            )
        elif kind == EventKind.COLLISION:
            msg = (
                f"Collision or overload on {where}: force {a.value:.0f} N over the extreme "
                f"limit {a.limit:.0f} N."
            )
        else:
            msg = (
                f"Missing or broken-off tool on {where}: mean force {a.value:.1f} N under "
                f"the lower limit {a.limit:.1f} N."
            )
        return MonitorEvent(
            kind=kind,
            action=DEFAULT_ACTIONS[kind],
            t=t,
            tool=a.tool,
            program=a.program,
            line=a.line,
            part=part,
            value=a.value,
            limit=a.limit,
            unit=_UNITS[a.detector],
            message=msg,
        )

    def _close_block(self, run: BlockRun) -> None:
        ps, m = self.ps, self.ps.machine
        number = run.tool.number
        wear = m.instances[number].wear
        changes = m.tool_changes
        m.end_block(run)
        if m.tool_changes != changes:
            wear = wear + run.tool.wear_per_s * run.done * self.sample_time
            self._tool_change(number, wear, "worn")
        ps.run = None
        ps.block_index += 1
        if ps.block_index == len(m.program.blocks):
            ps.block_index = 0
            m.part += 1
            # the operator's tool change after a breakage or missing-tool alarm
            for number, cause in ps.replace_tools:
                wear = m.instances[number].wear
                m.replace_tool(number)
                self._tool_change(number, wear, cause)
            ps.replace_tools = []

    def _tool_change(self, number: int, wear: float, cause: str) -> None:
        ps = self.ps
        t = self.t
        ps.tool_changes.append(
            {
                "tool": number,
                "start_t": ps.tool_since.get(number, 0.0),
                "end_t": t,
                "wear": wear,
                "cause": cause,
            }
        )
        ps.tool_since[number] = t
        del ps.tool_changes[:-100]

    def take_tool_changes(self) -> list[ProgramToolChange]:
        """The part program's tool changes since the last call, oldest first: ``tool``,
        ``start_t`` and ``end_t`` of the instance [s], ``wear`` (its edge-coefficient
        growth, :class:`machine.process.Tool`; the limit is the tool's ``wear_limit``)
        and ``cause`` (``worn``: at its wear limit; ``breakage``, ``missing_tool``: changed
        by the operator after that alarm)."""
        out = list(self.ps.tool_changes)
        self.ps.tool_changes.clear()
        return out

    def _hold(self, n: int) -> dict[str, F64]:
        return {k: np.full(n, self.ps.last.get(k, math.nan)) for k in MON_CHANNELS}

    # ------------------------------------------------------------------ status
    def status(self) -> StatusStrip:
        """State (teaching, watching, alarm), tool, program, line and part of the latest
        sample (before the first step: the program's first block, teaching)."""
        last = self.ps.last
        m = self.ps.machine
        if not last:
            b = m.program.blocks[0]
            return {"state": "teaching", "tool": b.tool, "program": m.program.name,
                    "line": b.line, "part": m.part}  # fmt: skip
        return {
            "state": STATES[int(last["mon_state"])],
            "tool": int(last["mon_tool"]),
            "program": m.program.name,
            "line": int(last["mon_line"]),
            "part": int(last["mon_part"]),
        }

    def state(self) -> tuple[ProcessState, dict[str, np.ndarray]]:
        """The part's state and the monitor's (taught) arrays, not copied."""
        return self.ps, self.taught

    def restore(
        self,
        ps: ProcessState,
        taught: dict[str, np.ndarray],
        teach_parts: int,
        band_factor: float,
    ) -> None:
        """Continue from a :meth:`state` (taken over with no copy) with the knobs it was
        taken with (the taught limits are kept)."""
        self.ps = ps
        self.taught = taught
        self.sample_time = ps.machine.sample_time
        p = replace(
            self.monitor.params,
            sample_time=self.sample_time,
            teach_parts=int(teach_parts),
            band_factor=float(band_factor),
        )
        self.monitor = ProcessMonitor(p)


#: the monitor's chart: the force, its mean over a revolution and the taught limits
MONITOR = Chart(
    "monitor",
    "Process monitor: force and taught limits (red lines: events waiting for an "
    "acknowledgement; grey: acknowledged)",
    page="operator",
    order=10,
    window_s=20.0,
    wide=True,
    markers=True,
)
_BAND = "#009e73"


def _channels() -> tuple[Channel, ...]:
    """:data:`MON_CHANNELS` declared: the force and the limits on the monitor's chart (the
    taught band shaded), the rest streamed beside it."""

    def ch(k: str, **kw: Any) -> Channel:
        u, lab = MON_CHANNELS[k]
        return Channel(k, u, lab, "monitor", **kw)

    drawn = MONITOR.series(
        ch("mon_f", legend="force estimate [N]", color="#9aa0a6", width=1.0),
        ch("mon_mean", legend="mean over a revolution [N]", color="#0072b2", width=2.0),
        ch(
            "mon_upper", legend="taught upper band [N]", color=_BAND, width=1.2, fill_to="mon_lower"
        ),
        ch("mon_lower", legend="taught lower band [N]", color=_BAND, width=1.2),
        ch("mon_extreme", legend="extreme limit [N]", color="#7b3294", width=1.6, dash=(8.0, 5.0)),
    )
    names = {c.name for c in drawn}
    rest = tuple(ch(k, truth=k == "mon_event_true") for k in MON_CHANNELS if k not in names)
    return drawn + rest


@dataclass
class ProcessPartState:
    """The process part's state (checkpointed): the part program under way (the machine,
    the drives' observers, the block, the injections waiting), the monitor's taught
    tables and running sums, and the monitor's parameters in effect."""

    process: ProcessState
    taught: dict[str, np.ndarray]
    teach_parts: int
    band_factor: float


class ProcessPart(LivePart):
    """The part program and the process monitor beside the stage (module docstring).

    Parameters
    ----------
    live
        The program, the drives' force estimate and the monitor.
    """

    name = "process"
    charts = (MONITOR,)
    channels = _channels()

    def __init__(self, live: LiveProcess) -> None:
        self.live = live

    @property
    def simulated_s(self) -> float:  # type: ignore[override]
        """Seconds in the simulated machine and its program (the rest: observers, monitor)."""
        return self.live.sim_s

    @classmethod
    def from_knobs(cls, seed: int, k: Mapping[str, float | bool | str]) -> ProcessPart:
        """The part of seed ``seed`` as the knobs set it (teach parts, band factor)."""
        return cls(
            LiveProcess(
                seed, teach_parts=int(float(k["teach_parts"])), band_factor=float(k["band_factor"])
            )
        )

    def requires(self, machine: MachineView) -> Verdict:
        return needs_simulator(machine, "a part program on seed 003's milling machine")

    def configure(self, setup: Setup) -> None:
        k = setup.knobs
        self.live.configure(int(float(k["teach_parts"])), float(k["band_factor"]))

    def step(self, block: Block) -> Outputs:
        return self.live.step(block.t, block.sample_time)

    def status(self) -> StatusStrip:
        return self.live.status()

    def take_tool_changes(self) -> list[ToolChange]:
        """The part program's tool changes as tool lives: the simulated machine's wear as
        a share of the tool's limit (a truth: no estimate of it), the cause ``wear_limit``
        for a worn tool, else the alarm after which the operator changed it."""
        program = self.live.ps.machine.program
        out: list[ToolChange] = []
        for c in self.live.take_tool_changes():
            number, wear, cause = c["tool"], c["wear"], c["cause"]
            out.append(
                {
                    "tool": number,
                    "index": None,
                    "start_t": c["start_t"],
                    "end_t": c["end_t"],
                    "wear_at_change_mm": None,
                    "wear_true_share": float(wear) / program.tool(number).wear_limit,
                    "cause": EventKind.WEAR_LIMIT if cause == "worn" else cause,
                }
            )
        return out

    def state(self) -> ProcessPartState:
        p = self.live.monitor.params
        return ProcessPartState(
            self.live.ps, self.live.taught, int(p.teach_parts), float(p.band_factor)
        )

    def restore(self, state: object) -> None:
        if not isinstance(state, ProcessPartState):
            raise ParameterError("state.parts.process", "a ProcessPartState", type(state).__name__)
        self.live.restore(state.process, state.taught, state.teach_parts, state.band_factor)


__all__ = [
    "CLEAR_SIZES",
    "KIND_CODES",
    "MONITOR",
    "MON_CHANNELS",
    "STATES",
    "Injection",
    "LiveProcess",
    "ProcessPart",
    "ProcessPartState",
    "ProcessState",
]
