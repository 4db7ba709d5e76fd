"""The monitor's events as one record: the same shape on the stream, the broker and in the history.

An event is what a detector of the process monitor (:mod:`estimators.monitoring.process`)
or the tool-life monitor raised, with the CNC's identities of the block it happened in
(tool, program, G-code line, part) and what the detector saw (its statistic's value and
the limit it crossed). Every consumer takes it from here:

- the live pipeline collects them in an :class:`EventOutbox` (``LivePipeline.take_events``);
- the live loop sends each on ``/ws`` and keeps the latest for ``/api/snapshot``;
- the broker carries them on ``cutwatch/<machine>/events`` (QoS 1) as
  :meth:`MonitorEvent.to_wire` (``schema`` ``cutwatch.event``, ``version`` :data:`VERSION`);
- the history keeps them (with their acknowledgements) in the service's database.

The truth of a simulated event (its first sample, its size) is never part of an event:
the detectors do not know it. A reproduction joins the two by time.
"""

from __future__ import annotations

import hashlib
import math
import uuid
from collections import deque
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, TypedDict

from common.event_kinds import EventKind

#: the wire schema's name and version (``cutwatch/<machine>/events``)
SCHEMA = "cutwatch.event"
VERSION = 1

#: what raised an event (:class:`common.event_kinds.EventKind`)
KINDS: tuple[EventKind, ...] = tuple(EventKind)


class EventAction(StrEnum):
    """What the monitor asks for when it raises an event."""

    #: a command to the edge device, which the CNC carries out
    FEED_HOLD = "feed_hold"
    #: an operator must look
    ALARM = "alarm"
    #: recorded, no alarm
    NOTICE = "notice"


ACTIONS: tuple[EventAction, ...] = tuple(EventAction)
#: the action of each kind
DEFAULT_ACTIONS: dict[EventKind, EventAction] = {
    EventKind.BREAKAGE: EventAction.FEED_HOLD,
    EventKind.COLLISION: EventAction.FEED_HOLD,
    EventKind.MISSING_TOOL: EventAction.FEED_HOLD,
    EventKind.WEAR_LIMIT: EventAction.ALARM,
    EventKind.LIFE_SHORT: EventAction.NOTICE,
}


#: an event record's fields (:meth:`MonitorEvent.record`), in the stream model's order
RECORD_FIELDS = (
    "id", "kind", "action", "t", "tool", "program", "line", "part", "value", "limit",
    "unit", "message", "machine", "acked", "acked_by", "acked_wall",
)  # fmt: skip


class EventFields(TypedDict):
    """An event as :meth:`MonitorEvent.as_dict` gives it: JSON-safe (NaN -> None), in the
    dataclass's order."""

    kind: str
    action: str
    t: float
    tool: int
    program: str
    line: int
    part: int
    value: float | None
    limit: float | None
    unit: str
    message: str
    machine: str
    id: str


class EventRecord(TypedDict):
    """An event as the stream, the snapshot and the history's REST carry it
    (:meth:`MonitorEvent.record`: :data:`RECORD_FIELDS`, in order)."""

    id: str
    kind: str
    action: str
    t: float
    tool: int
    program: str
    line: int
    part: int
    value: float | None
    limit: float | None
    unit: str
    message: str
    machine: str
    acked: bool
    acked_by: str | None
    acked_wall: float | None


def event_record(r: EventRecord) -> EventRecord:
    """A copy of ``r`` holding the record's fields only, in :data:`RECORD_FIELDS`' order
    (a history row without its received time; ``acked`` a bool)."""
    return EventRecord(
        id=r["id"], kind=r["kind"], action=r["action"], t=r["t"], tool=r["tool"],
        program=r["program"], line=r["line"], part=r["part"], value=r["value"],
        limit=r["limit"], unit=r["unit"], message=r["message"], machine=r["machine"],
        acked=bool(r["acked"]), acked_by=r["acked_by"], acked_wall=r["acked_wall"],
    )  # fmt: skip


class EventWire(EventFields):
    """The broker's message (:meth:`MonitorEvent.to_wire`): the fields with the schema."""

    schema: str
    version: int


def _json_number(x: float) -> float | None:
    return x if math.isfinite(x) else None


def event_id(ev: MonitorEvent, machine: str) -> str:
    """The stable id of an event raised on ``machine``: a hash of what it is (kind, time,
    tool, program, line, part, message), so the same event raised again (a run resumed
    from a checkpoint computes the same seconds again) has the same id: the history
    keeps it once and an edge device acts on its feed hold once."""
    key = "|".join(
        (machine, ev.kind, float(ev.t).hex(), str(ev.tool), ev.program, str(ev.line),
         str(ev.part), ev.message)
    )  # fmt: skip
    return hashlib.sha256(key.encode("utf-8")).hexdigest()[:32]


def new_id() -> str:
    """A unique event id (32 hex digits), unique across restarts and machines."""
    return uuid.uuid4().hex


@dataclass(frozen=True)
class MonitorEvent:
    """One event (see the module docstring).

    Attributes
    ----------
    id : str
        Unique id (:func:`new_id`).
    kind : str
        One of :data:`KINDS`.
    action : str
        One of :data:`ACTIONS`.
    t : float
        Simulated (source) time of the sample that raised it [s].
    tool, program, line, part
        The CNC's identities of the block: tool number (0: unknown), program name ("":
        unknown), G-code line (0: unknown), part counter (-1: unknown).
    value, limit : float
        The detector's statistic at the alarm and the limit it crossed (NaN: none).
    unit : str
        Their unit.
    message : str
        One plain sentence for an operator.
    machine : str
        The machine's name ("" inside one service; the broker's topic names it).
    """

    kind: EventKind
    action: EventAction
    t: float
    tool: int = 0
    program: str = ""
    line: int = 0
    part: int = -1
    value: float = math.nan
    limit: float = math.nan
    unit: str = ""
    message: str = ""
    machine: str = ""
    id: str = field(default_factory=new_id)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind: expected one of {', '.join(KINDS)}, got {self.kind!r}")
        if self.action not in ACTIONS:
            raise ValueError(f"action: expected one of {', '.join(ACTIONS)}, got {self.action!r}")
        if not math.isfinite(self.t):
            raise ValueError(f"t: expected a finite time [s], got {self.t!r}")
        # a string read back (JSON, the database, the broker) becomes its member
        object.__setattr__(self, "kind", EventKind(self.kind))
        object.__setattr__(self, "action", EventAction(self.action))

    def as_dict(self) -> EventFields:
        """A JSON-safe dict (NaN -> None)."""
        return EventFields(
            kind=self.kind, action=self.action, t=self.t, tool=self.tool,
            program=self.program, line=self.line, part=self.part,
            value=_json_number(self.value), limit=_json_number(self.limit), unit=self.unit,
            message=self.message, machine=self.machine, id=self.id,
        )  # fmt: skip

    def record(self) -> EventRecord:
        """The event as the stream, the snapshot and the history's REST carry it (the
        fields of ``server.service.messages.Event``, in its order; :class:`EventRecord`):
        :meth:`as_dict` with its acknowledgement (none yet)."""
        d = self.as_dict()
        return event_record({**d, "acked": False, "acked_by": None, "acked_wall": None})

    def to_wire(self) -> EventWire:
        """The broker's message: :meth:`as_dict` with ``schema`` and ``version``."""
        return {"schema": SCHEMA, "version": VERSION, **self.as_dict()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MonitorEvent:
        """The inverse of :meth:`as_dict` / :meth:`to_wire` (unknown keys refused by name)."""
        d = dict(d)
        schema = d.pop("schema", SCHEMA)
        version = d.pop("version", VERSION)
        if schema != SCHEMA:
            raise ValueError(f"schema: expected {SCHEMA!r}, got {schema!r}")
        if not isinstance(version, int) or version > VERSION:
            raise ValueError(f"version: expected an integer <= {VERSION}, got {version!r}")
        known = set(cls.__dataclass_fields__)
        extra = sorted(set(d) - known)
        if extra:
            raise ValueError(
                f"{extra[0]}: not a field of an event (fields: {', '.join(sorted(known))})"
            )
        for k in ("value", "limit"):
            if d.get(k) is None:
                d[k] = math.nan
        return cls(**d)


class EventOutbox:
    """Events raised but not yet taken by the loop; bounded (the oldest are dropped and
    counted, never silently: :attr:`dropped`)."""

    def __init__(self, maxlen: int = 1000) -> None:
        self._q: deque[MonitorEvent] = deque(maxlen=maxlen)
        self.dropped = 0

    def put(self, ev: MonitorEvent) -> None:
        if len(self._q) == self._q.maxlen:
            self.dropped += 1
        self._q.append(ev)

    def take(self) -> list[MonitorEvent]:
        """Every waiting event, oldest first; the outbox is empty afterwards."""
        out = list(self._q)
        self._q.clear()
        return out

    def __len__(self) -> int:
        return len(self._q)
