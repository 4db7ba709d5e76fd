"""Simulated machining centres as their edge devices: the CNC's trace in drive blocks.

``cutwatch feed --simulate`` publishes this (issue 31, item 4): each machine is a
:class:`machine.centre.sim.MachiningCentre` running its own program
(:func:`machine.centre.program.program_variant`: machine k runs ``O{2001 + k}``, its
spindle speeds scaled), its own seed (noise, overrides, depths, tool lives, runouts) and
its own events, exported as a CNC's trace (:mod:`machine.centre.trace`) and encoded as
drive blocks of the broker's wire format with the machine description as the meta
(:mod:`machine.centre.signals`). A block is simulated when it is asked for, so a feed
costs the simulation's time (about 0.6 % of a core per machine at 1x on a quiet
machine of this kind, docs/machining-centre.md); a plant's bench replays recorded traces instead.

Events (a choice, as a shop would see them): each part draws, with probability
``event_rate``, one event into one of its cut blocks (kind, line, where in the block,
and the flute, uniformly; sizes :data:`EVENT_SIZES`). A tool broken (breakage) or lost
(missing tool) in a part is replaced at the part's end, as the operator does after the
alarm. The events' truth is kept (:attr:`CentreFeed.events`), never sent.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from common.event_kinds import ProcessEventKind
from common.machine_description import from_dict
from machine.centre import signals
from machine.centre.program import program_variant
from machine.centre.sim import MachiningCentre
from machine.centre.trace import MODES, RATES, CncTrace, TraceParams
from machine.errors import ParameterError, require_in
from machine.process import EVENT_KINDS, EventTruth, ProcessEvent
from server.records.drive_wire import encode_drive, encode_meta, identity_segments

#: the size of each event a feed draws: a broken tooth (0.3 mm, more than any feed per
#: tooth of the default part), a collision at 3x the feed, a tool lost whole
EVENT_SIZES: dict[str, float] = {
    ProcessEventKind.BREAKAGE: 0.3e-3,
    ProcessEventKind.COLLISION: 3.0,
    ProcessEventKind.MISSING_TOOL: 1.0,
}
#: the events after which the tool is replaced at the next part
_LOSES_TOOL = frozenset({ProcessEventKind.BREAKAGE, ProcessEventKind.MISSING_TOOL})
#: the columns of a trace record that travel as identities, not as signals
_IDENTITY_COLUMNS = ("t", "tool", "line", "override")


@dataclass(frozen=True)
class CentreFeedParams:
    """A simulated feed: the trace's ``rate_hz`` and ``mode``, ``block_ms`` of trace per
    drive block, and ``event_rate`` (chance per part of one event, in [0, 1])."""

    rate_hz: float = 500.0
    mode: str = "sample"
    block_ms: float = 50.0
    event_rate: float = 0.05

    def __post_init__(self) -> None:
        if self.rate_hz not in RATES:
            raise ParameterError("rate_hz", f"one of {list(RATES)} Hz", self.rate_hz)
        if self.mode not in MODES:
            raise ParameterError("mode", f"one of {list(MODES)}", self.mode)
        require_in("block_ms", self.block_ms, 1.0, 1000.0)
        require_in("event_rate", self.event_rate, 0.0, 1.0)


@dataclass
class CentreFeed:
    """Machine ``index`` of a plant, seeded ``seed``: its meta and its drive blocks, in
    order (:meth:`next_block`)."""

    index: int
    seed: int
    params: CentreFeedParams = field(default_factory=CentreFeedParams)
    events: list[EventTruth] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.machine = MachiningCentre(program=program_variant(self.index))
        self.state = self.machine.initial_state(seed=self.seed)
        self.trace = CncTrace(TraceParams(self.params.rate_hz, self.params.mode),
                              self.machine.sample_time)  # fmt: skip
        self.tstate = self.trace.initial_state()
        self.rng = np.random.default_rng([self.seed, 31])
        self.sample_time = 1.0 / self.params.rate_hz
        self.per = max(1, round(self.params.block_ms * 1e-3 * self.params.rate_hz))
        desc = signals.description_dict(self.machine.params, self.params.rate_hz)
        self.meta = encode_meta(desc)
        self.units = {s.source: s.unit for s in from_dict(desc).signals()
                      if s.owner != "identities"}  # fmt: skip
        self._part = -1
        self._broken: set[int] = set()
        self._cuts = [b.line for b in self.machine.program.blocks if b.cut is not None]

    @property
    def program(self) -> str:
        return self.machine.program.name

    def next_block(self, seq: int, wall: float | None = None) -> bytes:
        """The next ``block_ms`` of the trace as a drive block (``seq``: its number)."""
        self._next_part()
        self.state, rec = self.machine.step(self.state, self.per * self.trace.factor)
        self.tstate, tr = self.trace.export(self.tstate, rec)
        for e in tr.events:
            self.events.append(e)
            if e.kind in _LOSES_TOOL:
                self._broken.add(e.tool)
        cols = {c: v for c, v in signals.columns(tr, self.machine.params).items()
                if c not in _IDENTITY_COLUMNS}  # fmt: skip
        return encode_drive(
            seq, float(tr.t[0]), self.sample_time, cols, self.units, wall=wall,
            program=tr.program, segments=identity_segments(tr.tool, tr.line, tr.override),
        )  # fmt: skip

    def _next_part(self) -> None:
        """At a new part: replace the tools the last one broke, draw this one's event."""
        part = self.state.part
        if part == self._part:
            return
        self._part = part
        for tool in sorted(self._broken):
            self.state = self.machine.replace_tool(self.state, tool)
        self._broken.clear()
        if self.rng.random() >= self.params.event_rate:
            return
        kind = str(self.rng.choice(EVENT_KINDS))
        line = int(self.rng.choice(self._cuts))
        ev = ProcessEvent(kind, part, line, float(self.rng.uniform(0.2, 0.8)),
                          EVENT_SIZES[kind], int(self.rng.integers(0, 8)))  # fmt: skip
        self.state = self.machine.schedule(self.state, ev)


def plant(n: int, seed: int, params: CentreFeedParams) -> list[CentreFeed]:
    """``n`` machines, machine k seeded ``seed + k`` and running ``O{2001 + k}``."""
    if int(n) != n or not 1 <= n <= 1000:
        raise ParameterError("machines", "a count in [1, 1000]", n)
    return [CentreFeed(k, seed + k, params) for k in range(int(n))]


__all__ = ["EVENT_SIZES", "CentreFeed", "CentreFeedParams", "plant"]
