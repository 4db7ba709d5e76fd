"""The live stream's messages as typed models: the one definition of their shapes.

The loop builds the ``health`` of every frame through :class:`LoopHealth`;
:mod:`server.service.protocol` encodes every message through its model (``hello``:
:class:`Hello`, frames: :class:`Data`, events: :class:`EventMessage`; validated, then
serialised by the model) and derives its ``SCHEMA`` from these models; the REST
models of ``/api/health`` and ``/api/snapshot`` (:mod:`server.service.schemas`) reuse
:class:`LoopHealth` and :class:`Accuracy`; the dashboard's schema (``web/schema.js``) is
generated from them by ``cutwatch schema --js --out web/schema.js`` (``make schema``), with
each message's JSDoc type, and ``tests/service/test_protocol.py`` fails when that file is
stale.

The stream describes itself (version 2, issue 26): ``hello`` carries the charts and every
channel's chart, page, order and drawing, and the parts with why those that do not run do
not; the dashboard builds its charts from it and writes no channel's name.

Each model carries its own ``VERSION`` (shown as ``x-version`` in its JSON schema and in
the generated ``SCHEMA.versions``): raise it when its fields change meaning, and
:data:`VERSION`, the stream's version that ``hello`` announces, when a client of the old
stream could misread the new one.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field
from pydantic.json_schema import JsonDict

from common.event_kinds import EventKind
from server.pipeline.knobs import KnobValue
from server.records.monitor_events import EventAction

#: the stream's version, sent in ``hello`` (the page refuses a stream of another version)
VERSION = 2


def _versioned(schema: JsonDict, cls: type[Any]) -> None:
    schema["x-version"] = cls.VERSION


class Versioned(BaseModel):
    """A message shape with its own version (``x-version`` in its JSON schema)."""

    model_config = ConfigDict(json_schema_extra=_versioned)
    VERSION: ClassVar[int] = 1


Page = Literal["operator", "research"]


class Interval(Versioned):
    """An estimate's 95 % interval: the channels of its bounds and its excited flag."""

    model_config = ConfigDict(extra="forbid")
    lower: str
    upper: str
    excited: str = Field(description="1: the data determine it; 0: show it greyed, 'not excited'")


class HelloChannel(Versioned):
    """One channel announced by ``hello``: the wire shape of the
    :class:`server.pipeline.part.Channel` a part declares (its ``describe()``)."""

    VERSION: ClassVar[int] = 2
    model_config = ConfigDict(extra="forbid")
    name: str = Field(description="the key of its samples in a frame's ch")
    unit: str
    group: str = Field(description="the quantity it belongs to (force, J_L, wear...)")
    label: str
    grid: Literal["t", "ts"] = Field(description="its display grid: t (fast) or ts (slow)")
    chart: str = Field(description="the id of the chart it is drawn on ('': not drawn)")
    page: Page = Field(description="the page of its chart: operator or research")
    order: int = Field(description="its place among its chart's series")
    truth: bool = Field(description="the simulator's truth (the reference), not an estimate")
    color: str = Field(description="a CSS colour ('': the page's palette)")
    dash: list[float] = Field(description="dash pattern (empty: a solid line)")
    width: float = Field(description="line width [px]")
    axis: str = Field(description="a second y axis' name ('': the chart's first axis)")
    interval: Interval | None = Field(description="drawn with its 95 % band (None: no band)")
    fill_to: str = Field(description="the area between it and this channel is shaded ('': none)")
    role: str = Field(
        description="what the residual loop's panel compares: reference, without_effects, "
        "with_effects ('': nothing)"
    )
    legend: str = Field(description="its short name in the chart's legend ('': its label)")


class HelloChart(Versioned):
    """A chart of the dashboard announced by ``hello``: the wire shape of the
    :class:`server.pipeline.part.Chart` a part declares."""

    model_config = ConfigDict(extra="forbid")
    id: str = Field(description="its name (the page's element chart-<id>)")
    title: str
    page: Page
    order: int = Field(description="its place on its page")
    window_s: float = Field(description="seconds of the machine's time it shows")
    fast: bool = Field(description="its channels are on the fast grid t")
    wide: bool = Field(description="drawn across the page")
    markers: bool = Field(description="the events are drawn on it")
    part: str = Field(
        default="",
        description="the part that declares it (the page draws the reason instead of the "
        "chart while that part does not run; '': none named)",
    )


class PartStatus(Versioned):
    """A part of the pipeline: running, or why not."""

    model_config = ConfigDict(extra="forbid")
    name: str
    running: bool
    reason: str = Field(description="why it does not run ('' while it runs)")


class Hello(Versioned):
    """The first message after connecting, and again whenever the pipeline changes."""

    VERSION: ClassVar[int] = 2
    model_config = ConfigDict(extra="forbid")
    type: Literal["hello"] = "hello"
    version: int = Field(default=VERSION, description="the stream's version")
    channels: list[HelloChannel]
    charts: list[HelloChart]
    parts: list[PartStatus]
    sample_time: float | None = Field(
        description="the pipeline's sample time [s]; null while a live feed has not "
        "described its machine (no meta yet: a new hello follows the meta)"
    )
    scenario: str
    knobs: dict[str, KnobValue] = Field(description="knob -> value")


class LoopHealth(Versioned):
    """The live loop's health (the ``health`` of every frame, of /api/health, /api/snapshot)."""

    sim_t: float | None = Field(description="simulated time [s]")
    speed: float | None = Field(description="requested speed (x real time)")
    paused: bool
    lag_ms: float | None = Field(description="lateness of the last block [ms]")
    lag_p99_ms: float | None = Field(description="p99 lateness over the last 600 blocks [ms]")
    realtime_factor: float | None = Field(description="simulated seconds per wall second")
    clients: int = Field(description="connected WebSocket clients")
    dropped_total: int = Field(description="frames dropped for slow clients")
    stalls: int = Field(description="clock re-anchors after a stall")


class Accuracy(Versioned):
    """Rolling rms of each force estimate (the ``accuracy`` of every frame and snapshot)."""

    VERSION: ClassVar[int] = 2
    mode: Literal["truth", "measured_force", "none"] = Field(
        description="'truth': against the true force (simulator); 'measured_force': against "
        "the force the machine measures (f_ext on a feed or a log); 'none': no reference, "
        "nothing scored (the estimates are never ranked against each other)"
    )
    against: Literal["truth", "measured_force"] | None = Field(
        description="what the rms is against (null: nothing)"
    )
    reason: str = Field(description="why nothing is scored (mode 'none'); else empty")
    windows: list[float] = Field(description="window lengths [s]")
    span: list[float] = Field(description="seconds each window really covers [s]")
    rms: dict[str, list[float | None]] = Field(
        description="estimate -> rms error per window (against the truth or the measured "
        "force; null: no reference)"
    )
    rms_q: dict[str, list[float | None]] = Field(
        description="estimate -> rms against the Q(s)-filtered true force (empty: no truth)"
    )
    floor: list[float | None] = Field(
        description="rms of the Q(s)-filtered true force against the true force, per window"
    )


class MonitorStatus(Versioned):
    """The status strip: what an operator reads from across the shop."""

    state: Literal["off", "teaching", "watching", "alarm"] = Field(
        description="off: no process monitor; alarm: an unacknowledged alarm or feed hold"
    )
    VERSION: ClassVar[int] = 2
    tool: int = Field(description="tool in the spindle (0: not known)")
    program: str
    line: int
    part: int
    wear_share: float | None = Field(
        description="estimated flank wear of tool `wear_tool` / `wear_limit_mm`"
    )
    life_left_min: float | None = Field(description="remaining life of tool `wear_tool` [min]")
    wear_tool: int = Field(
        default=0, description="the tool the wear share and life are of (0: not known)"
    )
    wear_of: str = Field(
        default="",
        description="whose tool `wear_tool` is: '' the spindle's (the strip's `tool`), else "
        "the wear model's own tool in words (a machine beside the spindle's)",
    )
    wear_limit_mm: float | None = Field(
        default=None, description="the flank-wear limit the share is of [mm] (tool change)"
    )
    wear_alarm_share: float | None = Field(
        default=None, description="the wear alarm is raised at this share of the limit"
    )
    wear_lo_share: float | None = Field(
        default=None, description="lower end of the wear share's 95 % interval (None: none)"
    )
    wear_hi_share: float | None = Field(
        default=None, description="upper end of the wear share's 95 % interval (None: none)"
    )
    wear_calibrated: bool | None = Field(
        default=None,
        description="whether the wear map is fitted from this machine's labelled tool lives "
        "(False: 'uncalibrated', the prior's interval; None: not said)",
    )
    unacked: int = Field(description="events waiting for an acknowledgement")


class Data(Versioned):
    """A frame at the display rate (~20 Hz): the samples since the previous one.

    A channel on grid ``t`` has one value per entry of ``t``, one on ``ts`` one per entry
    of ``ts`` (a coarser subset of the same samples); non-finite values are ``null``.
    """

    VERSION: ClassVar[int] = 2
    model_config = ConfigDict(extra="forbid")
    type: Literal["data"] = "data"
    dropped: int = Field(default=0, description="frames this client lost since its previous frame")
    seq: int = Field(description="frame counter of the loop")
    wall: float = Field(description="wall-clock time of the frame [unix s]")
    t: list[float | None] = Field(description="fast display grid [s]")
    ts: list[float | None] = Field(description="slow display grid [s]")
    ch: dict[str, list[float | None]] = Field(description="channel -> samples on its grid")
    health: LoopHealth
    knobs: dict[str, KnobValue] = Field(description="knob -> value")
    accuracy: Accuracy
    status: MonitorStatus | None = Field(
        default=None, description="the monitor's status strip (None: not known)"
    )
    parts: list[PartStatus] = Field(
        default_factory=list, description="the pipeline's parts: running, or why not"
    )


class Event(Versioned):
    """One monitor event (:class:`server.records.monitor_events.MonitorEvent`) as the stream,
    the snapshot and the history's REST carry it, with its acknowledgement."""

    id: str
    kind: EventKind
    action: EventAction
    t: float = Field(description="simulated time of the sample that raised it [s]")
    tool: int = Field(description="tool number (0: not known)")
    program: str = Field(description="program name ('': not known)")
    line: int = Field(description="G-code line of the block (0: not known)")
    part: int = Field(description="part counter (-1: not known)")
    value: float | None = Field(description="the detector's statistic at the alarm")
    limit: float | None = Field(description="the limit it crossed")
    unit: str
    message: str
    machine: str
    acked: bool = Field(default=False, description="acknowledged by an operator")
    acked_by: str | None = Field(default=None, description="who acknowledged it")
    acked_wall: float | None = Field(default=None, description="when [unix s]")


class EventMessage(Versioned):
    """Sent to every client when the monitor raises an event, and again when it is
    acknowledged (same ``id``, ``acked`` true)."""

    model_config = ConfigDict(extra="forbid")
    type: Literal["event"] = "event"
    event: Event


#: every message shape of the stream, by the name ``SCHEMA`` lists its fields under
MESSAGES: dict[str, type[Versioned]] = {
    "hello": Hello,
    "channel": HelloChannel,
    "chart": HelloChart,
    "interval": Interval,
    "part": PartStatus,
    "data": Data,
    "health": LoopHealth,
    "accuracy": Accuracy,
    "event": EventMessage,
    "event_record": Event,
    "status": MonitorStatus,
}


def fields(model: type[BaseModel]) -> list[str]:
    """A model's field names in their order (the order they travel in)."""
    return list(model.model_fields)
