"""The live part: what it needs, what it streams, how it runs. The live pipeline's contract.

A part is one estimator (or one simulated process beside the machine) in the live
pipeline (:class:`server.pipeline.live_pipeline.LivePipeline`). It says

- what it needs: :meth:`Part.requires` answers, for a :class:`~server.pipeline.
  machine_view.MachineView` (the signals the source delivers, its sample rate, the
  spindle speed), :data:`OK` or a :class:`Verdict` with the reason it cannot run; the
  pipeline asks again whenever the view changes (a spindle step, a new meta), and a part
  whose band or pattern passes the Nyquist frequency pauses with that reason;
  :attr:`Part.needs` names the parts whose outputs it reads (they run before it);
- what it streams: :attr:`Part.channels` (name, unit, label, group, the chart it is
  drawn on, the page, its order, whether it is the simulator's truth, how it is drawn)
  and :attr:`Part.charts`, declared beside the code that computes them; the stream's
  ``hello`` carries them and the dashboard builds its charts from them;
- how it runs: :meth:`Part.configure` (the knobs and the machine, when either changed),
  :meth:`Part.step` (one :class:`Block` -> its channels and the events it raised),
  :meth:`Part.state` / :meth:`Part.restore` (its state as a value, never the part
  itself: the checkpoint).

Optional hooks, with do-nothing defaults in :class:`LivePart`: :meth:`LivePart.before`
(the simulated machine's script before the source's block: a workpiece losing mass, a
tool wearing), :meth:`LivePart.force_gain` and :meth:`LivePart.added_inertia` (what the
part does to the simulated stage), :meth:`LivePart.notice` (a change the CNC knows of: a
spindle step, a tool change, a fresh workpiece), :meth:`LivePart.status` (its share of
the status strip), :meth:`LivePart.take_tool_changes` (the tool lives it ended).

A part that raises in :meth:`Part.step` is stopped with the exception as its reason; the
others go on. A part that does not run streams NaN on its channels.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, ClassVar, Literal, Protocol, TypedDict, runtime_checkable

import numpy as np

from common.arrays import F64
from machine.stage import CuttingForce, Measurements, Truth
from server.pipeline.machine_view import MachineView
from server.pipeline.sources import SourceBlock
from server.records.monitor_events import MonitorEvent

if TYPE_CHECKING:
    from server.pipeline.estimates_out import StatusStrip
    from server.records.history.store import ToolChange

__all__ = [
    "OK",
    "PAGES",
    "Block",
    "Channel",
    "Chart",
    "LivePart",
    "Notice",
    "Part",
    "PartStatus",
    "Plan",
    "Setup",
    "Verdict",
    "needs_axis",
    "needs_band",
    "needs_signals",
    "needs_simulator",
]

#: the dashboard's pages: what an operator watches, and the estimators' research views
PAGES = ("operator", "research")
Page = Literal["operator", "research"]
KnobMap = Mapping[str, float | bool | str]


# ---------------------------------------------------------------------- requirements
@dataclass(frozen=True)
class Verdict:
    """Whether a part can run on a machine, and if not, why (a sentence naming what it
    needs and what the machine has)."""

    ok: bool
    reason: str = ""

    def __bool__(self) -> bool:
        return self.ok


#: the part can run
OK = Verdict(True)


def refuse(reason: str) -> Verdict:
    """A part cannot run, for ``reason``."""
    return Verdict(False, reason)


def needs_signals(machine: MachineView, *names: str, what: str = "") -> Verdict:
    """:data:`OK` when the source delivers every signal of ``names``."""
    missing = machine.lacks(*names)
    if not missing:
        return OK
    have = ", ".join(sorted(machine.signals)) or "none"
    why = f" ({what})" if what else ""
    return refuse(
        f"needs the signal(s) {', '.join(missing)}{why}; the {machine.source} "
        f"source delivers {have}"
    )


def needs_axis(
    machine: MachineView, *roles: str, kind: str | None = None, effort: bool = True, what: str = ""
) -> Verdict:
    """:data:`OK` when an axis (of ``kind``, if given) carries every one of ``roles`` and,
    with ``effort``, a motor effort (``tau_m`` or ``i_m``); else the reason, with the axes
    the machine has."""
    for a in machine.axes_with(*roles, kind=kind):
        if not effort or a.has("tau_m") or a.has("i_m"):
            return OK
    want = " ".join(x for x in (kind or "", "axis") if x)
    sigs = ", ".join(roles) + (" and tau_m or i_m" if effort else "")
    have = "; ".join(f"{a.name} ({a.kind}: {', '.join(sorted(a.roles))})" for a in machine.axes)
    why = f" ({what})" if what else ""
    return refuse(f"needs a {want} with {sigs}{why}; the {machine.source} source's machine has "
                  f"{have or 'no axis'}")  # fmt: skip


def needs_band(machine: MachineView, hz: float, what: str) -> Verdict:
    """:data:`OK` when ``hz`` (a band edge, a harmonic, a pattern's frequency) lies below
    the machine's Nyquist frequency; else the reason, with both frequencies."""
    if not math.isfinite(hz):
        return refuse(f"needs {what} to be known (the spindle speed is not known)")
    if hz < machine.nyquist:
        return OK
    return refuse(
        f"{what} at {hz:.4g} Hz is above the Nyquist frequency {machine.nyquist:.4g} "
        f"Hz of a {machine.sample_rate:.4g} Hz source"
    )


def needs_simulator(machine: MachineView, what: str) -> Verdict:
    """:data:`OK` on a simulated machine (the part simulates ``what`` beside it)."""
    if machine.simulated:
        return OK
    return refuse(
        f"simulates {what}: runs with the simulator only, not on the {machine.source} source"
    )


# ---------------------------------------------------------------------- what it streams
@dataclass(frozen=True)
class Chart:
    """A chart of the dashboard, declared by the part whose channels it draws.

    Attributes
    ----------
    id
        Its name (the element ``chart-<id>`` on the page).
    title
        What it shows, in words.
    page
        ``operator`` (what an operator watches) or ``research`` (the estimators'
        views, true against estimated).
    order
        Its place on its page (ascending).
    window_s
        Seconds of the machine's time it shows.
    fast
        Its channels are sent on the fast display grid ``t`` (else the slow ``ts``).
    wide
        Drawn across the page's width.
    markers
        The events are drawn on it (a vertical line each).
    part
        The part that declares it (set by the pipeline: ``LivePipeline.charts``).
    """

    id: str
    title: str
    page: Page = "research"
    order: int = 100
    window_s: float = 30.0
    fast: bool = False
    wide: bool = False
    markers: bool = False
    part: str = ""

    def describe(self) -> ChartInfo:
        """The chart as ``hello`` carries it (``server.service.messages.HelloChart``)."""
        return {
            "id": self.id,
            "title": self.title,
            "page": self.page,
            "order": self.order,
            "window_s": self.window_s,
            "fast": self.fast,
            "wide": self.wide,
            "markers": self.markers,
            "part": self.part,
        }

    def series(self, *channels: Channel, start: int = 0) -> tuple[Channel, ...]:
        """``channels`` drawn on this chart, in this order from ``start`` (their chart,
        page, order and grid set from it; another part's channels on the same chart
        start after the owner's)."""
        return tuple(
            replace(c, chart=self.id, page=self.page, order=start + i, fast=self.fast)
            for i, c in enumerate(channels)
        )


class ChartInfo(TypedDict):
    """A chart as ``hello`` carries it (:meth:`Chart.describe`;
    ``server.service.messages.HelloChart``)."""

    id: str
    title: str
    page: Page
    order: int
    window_s: float
    fast: bool
    wide: bool
    markers: bool
    part: str


class IntervalInfo(TypedDict):
    """A channel's 95 % band: the names of its lower, upper and excited channels."""

    lower: str
    upper: str
    excited: str


class ChannelInfo(TypedDict):
    """A channel as ``hello`` carries it (:meth:`Channel.describe`;
    ``server.service.messages.HelloChannel``), in its order."""

    name: str
    unit: str
    group: str
    label: str
    grid: str
    chart: str
    page: Page
    order: int
    truth: bool
    color: str
    dash: list[float]
    width: float
    axis: str
    interval: IntervalInfo | None
    fill_to: str
    role: str
    legend: str


@dataclass(frozen=True)
class Channel:
    """One per-sample output of a part, as the stream announces it.

    Attributes
    ----------
    name, unit, label
        Its key in a block and a frame, its unit, what it is in words.
    group
        The quantity it belongs to (``force``, ``J_L``, ``wear``...): the force estimates
        (group ``force``, not truth) are scored by the accuracy panel; the estimates
        message sorts by it.
    chart, page, order
        The chart it is drawn on (``""``: not drawn), that chart's page, its place among
        the chart's series (:meth:`Chart.series` sets them).
    truth
        The simulator's truth (drawn as the reference; never published as an estimate).
    fast
        On the fast display grid ``t`` (else ``ts``).
    color, dash, width, axis
        How it is drawn: a CSS colour (``""``: the page's palette), a dash pattern, the
        line width, a second y axis' name (``""``: the chart's first axis).
    interval
        ``(lower, upper, excited)`` channel names: the estimate is drawn with its 95 %
        band, greyed and labelled "not excited" where the flag is 0.
    fill_to
        Another channel of the chart: the area between the two is shaded.
    role
        What the residual loop's panel compares: ``reference`` (the force to compare
        with), ``without_effects`` and ``with_effects`` (the observer without and with
        the identified effects).
    legend
        Its short name in the chart's legend (``""``: the label and the unit).
    """

    name: str
    unit: str
    label: str
    group: str
    chart: str = ""
    page: Page = "research"
    order: int = 0
    truth: bool = False
    fast: bool = False
    color: str = ""
    dash: tuple[float, ...] = ()
    width: float = 1.4
    axis: str = ""
    interval: tuple[str, str, str] | None = None
    fill_to: str = ""
    role: str = ""
    legend: str = ""

    @property
    def grid(self) -> str:
        """``"t"`` (the fast display grid) or ``"ts"`` (the slow one)."""
        return "t" if self.fast else "ts"

    def describe(self) -> ChannelInfo:
        """The channel as ``hello`` carries it (``server.service.messages.HelloChannel``)."""
        return {
            "name": self.name,
            "unit": self.unit,
            "group": self.group,
            "label": self.label,
            "grid": self.grid,
            "chart": self.chart,
            "page": self.page,
            "order": self.order,
            "truth": self.truth,
            "color": self.color,
            "dash": list(self.dash),
            "width": self.width,
            "axis": self.axis,
            "interval": None if self.interval is None else {
                "lower": self.interval[0],
                "upper": self.interval[1],
                "excited": self.interval[2],
            },
            "fill_to": self.fill_to,
            "role": self.role,
            "legend": self.legend,
        }  # fmt: skip


# ---------------------------------------------------------------------- how it runs
@dataclass(frozen=True)
class Notice:
    """A change of the cut the CNC knows of, told to every part (:meth:`LivePart.notice`).

    ``kind``: ``disturbance`` (the cutting condition changed at ``t``: a spindle step, a
    tool change) or ``restart`` (load parameters changed: ``params``, e.g. ``("J_L",)``
    for a fresh workpiece)."""

    kind: Literal["disturbance", "restart"]
    t: float = 0.0
    params: tuple[str, ...] = ()


@dataclass(frozen=True)
class Setup:
    """What :meth:`Part.configure` is given: the knob values and the machine."""

    knobs: KnobMap
    machine: MachineView


@dataclass
class Plan:
    """The block about to be taken from the source (:meth:`LivePart.before`): its start
    ``t0`` [s], its ``n`` samples, the knobs; ``notice`` tells every part of a known
    change (at once)."""

    t0: float
    n: int
    sample_time: float
    knobs: KnobMap
    notice: Callable[[Notice], None]


@dataclass
class Plant:
    """What the simulated machine applied over a block (None fields: not simulated)."""

    #: the cutting force the stage was given (its harmonics' true amplitudes)
    force: CuttingForce | None = None
    #: the mean force a sharp tool would give at this feed and spindle speed [N m]
    nominal_force: float = math.nan


@dataclass
class Block:
    """One block of the source, wrapped once, as every part sees it.

    Attributes
    ----------
    source
        The source's block: its measurements, truth and discontinuity.
    t
        The time each estimate refers to (one sample behind the measurement: the
        observers lag one sample) [s].
    t_end
        The source's time after the block [s].
    machine, knobs
        The machine view and the knob values in effect.
    plant
        What the simulated machine applied (``Plant()`` without a simulator).
    outputs
        The channels of the parts stepped before this one (read-only for a part).
    shared
        What parts hand to later parts beside their channels (e.g. the stage
        observers' block under ``"stage"``).
    notice
        Tell every part of a known change (:class:`Notice`), at once.
    status
        The status strip as the parts stepped so far leave it.
    """

    source: SourceBlock
    t: F64
    t_end: float
    machine: MachineView
    knobs: KnobMap
    plant: Plant
    notice: Callable[[Notice], None]
    status: Callable[[], StatusStrip]
    outputs: dict[str, F64] = field(default_factory=dict)
    shared: dict[str, Any] = field(default_factory=dict)

    @property
    def meas(self) -> Measurements:
        return self.source.meas

    @property
    def n(self) -> int:
        return self.source.n

    @property
    def sample_time(self) -> float:
        return self.machine.sample_time

    @property
    def discontinuity(self) -> str | None:
        """Why this block does not continue the last (None: it does)."""
        return self.source.discontinuity

    @property
    def has_truth(self) -> bool:
        return self.machine.has_truth

    @property
    def truth(self) -> Truth:
        """The simulator's truth, or the reference force ``f_ext`` of a source without it
        (everything else NaN)."""
        if self.source.truth is not None:
            return self.source.truth
        from server.pipeline.sources import no_truth

        return no_truth(self.source.meas)

    def held(self, value: float) -> F64:
        """A channel holding ``value`` over the block."""
        return np.full(self.n, float(value))


Outputs = tuple[dict[str, F64], list[MonitorEvent]]


@runtime_checkable
class Part(Protocol):
    """A live part (see the module docstring). Write one as a :class:`LivePart`
    subclass: it has every member, the optional hooks doing nothing."""

    @property
    def name(self) -> str:
        """Its name (unique in a pipeline; the key of its state and status)."""

    @property
    def needs(self) -> tuple[str, ...]:
        """The parts whose outputs it reads (they run before it)."""

    @property
    def charts(self) -> tuple[Chart, ...]:
        """The charts its channels are drawn on."""

    @property
    def channels(self) -> tuple[Channel, ...]:
        """What it streams."""

    @property
    def simulated_s(self) -> float:
        """Seconds of its steps spent simulating, not estimating (a running count)."""

    def requires(self, machine: MachineView) -> Verdict: ...

    def configure(self, setup: Setup) -> None: ...

    def before(self, plan: Plan) -> None: ...

    def force_gain(self, t: float) -> float: ...

    def added_inertia(self, t: float) -> float: ...

    def step(self, block: Block) -> Outputs: ...

    def notice(self, change: Notice) -> None: ...

    def status(self) -> StatusStrip: ...

    def take_tool_changes(self) -> list[ToolChange]: ...

    def state(self) -> object: ...

    def restore(self, state: object) -> None: ...


class LivePart:
    """A part's defaults: runs on any machine, needs no other part, keeps no state.

    A subclass sets :attr:`name`, :attr:`channels` (and :attr:`charts`) and writes
    :meth:`step`; the rest is there when it needs it.
    """

    name: ClassVar[str] = ""
    needs: tuple[str, ...] = ()
    charts: tuple[Chart, ...] = ()
    channels: tuple[Channel, ...] = ()
    #: seconds of its steps spent simulating (a simulated machine beside the stage), not
    #: estimating: ``cutwatch bench`` reports the two apart
    simulated_s: float = 0.0

    def requires(self, machine: MachineView) -> Verdict:
        """:data:`OK`, or why the part cannot run on ``machine``."""
        return OK

    def configure(self, setup: Setup) -> None:
        """Apply the knobs and the machine (called when either changed)."""

    def before(self, plan: Plan) -> None:
        """The simulated machine's script before the source's block (simulating parts)."""

    def force_gain(self, t: float) -> float:
        """The factor this part puts on the simulated stage's cutting force at ``t``."""
        return 1.0

    def added_inertia(self, t: float) -> float:
        """The inertia this part adds to the simulated stage's load at ``t`` [kg m^2]."""
        return 0.0

    def step(self, block: Block) -> Outputs:
        """One block: the part's channels (``block.n`` values each) and its events."""
        raise NotImplementedError

    def notice(self, change: Notice) -> None:
        """A change the CNC knows of (a spindle step, a tool change, a fresh workpiece)."""

    def status(self) -> StatusStrip:
        """The part's share of the status strip (``MonitorStatus`` fields)."""
        return {}

    def take_tool_changes(self) -> list[ToolChange]:
        """The tool lives the part ended since the last call (the history keeps them)."""
        return []

    def state(self) -> object:
        """Everything the part carries from block to block, as a value (a checkpoint)."""
        return None

    def restore(self, state: object) -> None:
        """Continue from :meth:`state`'s value."""


class PartInfo(TypedDict):
    """A part as ``/api/health``, ``hello`` and the data frames list it
    (:meth:`PartStatus.as_dict`)."""

    name: str
    running: bool
    reason: str


@dataclass(frozen=True)
class PartStatus:
    """A part as ``/api/health`` and the stream list it: running, or why not."""

    name: str
    running: bool
    reason: str = ""

    def as_dict(self) -> PartInfo:
        return {"name": self.name, "running": self.running, "reason": self.reason}


def nan_to_num(a: F64, nan: float = 0.0) -> F64:
    """``np.nan_to_num(a, nan=nan)`` (NaN to ``nan``, an infinity to the largest float of
    its sign) without its cost when every value is finite, the case of almost every
    block: then ``a`` itself (not a copy: the callers only read it)."""
    if np.isfinite(a).all():
        return a
    return np.nan_to_num(a, nan=nan)


def column_or(cols: Mapping[str, Any], name: str, n: int, fill: float) -> Any:
    """``cols[name]``, or ``n`` values of ``fill`` when it has none (built only then,
    not as ``cols.get(name, np.full(n, fill))`` builds it at every block)."""
    v = cols.get(name)
    return np.full(n, fill) if v is None else v


def diff_from(a: F64, prev: float) -> F64:
    """``np.diff(a, prepend=prev)`` (the same subtractions) without its concatenation:
    each sample less the one before it, the first less ``prev``."""
    out = np.empty(len(a))
    if len(a):
        out[0] = a[0] - prev
        np.subtract(a[1:], a[:-1], out=out[1:])
    return out


def nan_channels(channels: Iterable[Channel], n: int) -> dict[str, F64]:
    """The channels of a part that does not run: NaN, ``n`` values each (the rows of one
    array: one allocation per part and block, each channel its own contiguous row)."""
    names = [c.name for c in channels]
    rows = np.full((len(names), n), math.nan)
    return {name: rows[i] for i, name in enumerate(names)}
