"""Publish the live estimates on ``cutwatch/<machine>/estimates`` at a rate the user sets.

:class:`EstimatesPublisher` is fed every block the pipeline produces (:meth:`observe`:
cheap, no I/O) and publishes one JSON message per period (:meth:`maybe_publish`), built
from the pipeline's channels by their group, so a new estimator's channels travel without
code here:

``force``       each force estimate's latest value, and ``level``: the rms of the adaptive
                observer's estimate over the period (a tooth-passing force oscillates;
                its rms is the level a person compares);
``params``      the identified parameters (and their bounds and excited flags when the
                pipeline streams them): the stage's J_L, B_L, F_CL, and each axis' M, Fv,
                Fc, offset of a described machine (``X.M``, ``X.M_lo``..., part axes) and
                what they were learnt from (``X.reversals``, ``X.moving_s``);
``harmonics``   the harmonic observer's amplitudes;
``wear``        ``VB_mm``, ``VB_limit_mm``, ``remaining_life_min`` of one tool, and
                ``tool``: which (the status strip's ``wear_tool``; 0: not known);
``alarms``      plain sentences: wear near its limit (the tool, its share of the limit,
                the alarm's share), a short remaining life, a gap in the drive feed;
``monitor``     the process monitor's ``state`` (off, teaching, watching, alarm), ``tool``,
                ``program``, ``line``, ``part``, ``unacked`` (events waiting for an
                acknowledgement) and the wear of one tool (``wear_tool``, ``wear_of``,
                ``wear_share``, ``wear_limit_mm``, ``wear_alarm_share``,
                ``life_left_min``): the service's status strip when given (the loop's,
                which knows the acknowledgements), else ``state``/``tool``/``line`` from
                the monitor's channels ``mon_state``, ``mon_tool``, ``mon_line`` when the
                pipeline streams them (the fleet page shows the state);
``health``      the loop's health, and the drive feed's counters for a broker source.

Ground truth (``*_true`` channels, the simulator's) is not published: estimates only.
The broker may be absent: publishing never blocks or raises into the loop; ``health``
says connected or not.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping, Sequence
from typing import Any, NotRequired, TypedDict

import numpy as np
import numpy.typing as npt

from server.pipeline.broker import (
    BrokerConfig,
    connect_in_background,
    topic,
)
from server.pipeline.wear_alarms import LIFE_ALARM_MIN, WEAR_ALARM_SHARE, wear_alarm_message
from server.records.drive_wire import encode_estimates

__all__ = ["LIFE_ALARM_MIN", "WEAR_ALARM_SHARE", "EstimatesPublisher"]
GROUPS = {"force": "force", "J_L": "params", "B_L": "params", "F_CL": "params"}
#: the process monitor's ``mon_state`` channel's values
MONITOR_STATES = {0: "teaching", 1: "watching", 2: "alarm"}


class EstimatesPublisher:
    """Build and publish the estimates message (see the module docstring).

    Parameters
    ----------
    cfg : BrokerConfig
    machine : str
    rate_hz : float
        Messages per second (> 0).
    dashboard : str, optional
        The URL of this service's dashboard, for the fleet page's link.
    """

    def __init__(
        self, cfg: BrokerConfig, machine: str, rate_hz: float, dashboard: str | None = None
    ) -> None:
        if not (rate_hz > 0 and math.isfinite(rate_hz)):
            raise ValueError(f"rate_hz: expected a finite value > 0, got {rate_hz}")
        self.cfg = cfg
        self.machine = machine
        self.topic = topic(machine, "estimates")
        self.period = 1.0 / float(rate_hz)
        self.dashboard = dashboard
        self.connected = False
        self.last_error = ""
        self.published = 0
        self._last_pub = -math.inf
        self._next_t = 0.0  # the machine's time of the next message (a live feed)
        self._lock = threading.Lock()
        self._latest: dict[str, float] = {}
        #: the squares of the force over the period, block by block (summed exactly at the
        #: message: the level does not depend on how the period's blocks were cut)
        self._sq: list[np.ndarray] = []
        self._count = 0
        self._client: Any = None

    def start(self) -> None:
        self._client = connect_in_background(self.cfg, f"cutwatch-estimates-{self.machine}", self)

    def share(self, client: Any) -> None:
        """Publish through ``client``, a connection shared with other machines (a worker's;
        the owner keeps :attr:`connected` up to date) instead of one of its own."""
        self._client = client

    def stop(self) -> None:
        c, self._client = self._client, None
        if c is not None:
            c.disconnect()
            c.loop_stop()

    def observe(
        self, block: Mapping[str, npt.ArrayLike], force_channel: str = "f_adaptive"
    ) -> None:
        """Take one pipeline block (channel name -> samples)."""
        with self._lock:
            for k, v in block.items():
                if k == "t" or k.endswith("_true"):
                    continue
                a = np.asarray(v, dtype=np.float64)
                if a.size:
                    self._latest[k] = float(a[-1])
            f = block.get(force_channel)
            if f is not None:
                a = np.asarray(f, dtype=np.float64)
                a = a[np.isfinite(a)]
                self._sq.append(a * a)
                self._count += a.size

    def build(
        self,
        now: float,
        channels: Sequence[Any],
        t: float,
        source: str,
        health: RuntimeHealth | None = None,
        drive_wall: float | None = None,
        feed_health: Mapping[str, Any] | None = None,
        monitor: StatusStrip | None = None,
    ) -> EstimatesBody:
        """The message body for the period ending now (and the period restarts);
        ``monitor``: the service's monitor status (:class:`MonitorStatus` fields)."""
        with self._lock:
            latest = dict(self._latest)
            sq = math.fsum(np.concatenate(self._sq)) if self._sq else 0.0
            level = math.sqrt(sq / self._count) if self._count else math.nan
            self._sq, self._count = [], 0
        groups: dict[str, dict[str, float]] = {"force": {"level": level}, "params": {}}
        harmonics: dict[str, float] = {}
        for ch in channels:
            name, group = ch.name, ch.group
            if name.endswith("_true") or name not in latest:
                continue
            if group in GROUPS:
                groups[GROUPS[group]][name] = latest[name]
            elif group == "force_sd":  # a force estimate's uncertainty: beside it
                groups["force"][name] = latest[name]
            elif _axis_param(group):  # an axis' parameter (part axes): X.M, X.Fc...
                groups["params"][name] = latest[name]
            elif group == "harmonics":
                harmonics[name] = latest[name]
        vb, lim = latest.get("vb_est", math.nan), latest.get("vb_limit", math.nan)
        life = latest.get("life_left", math.nan)
        wear_tool = int((monitor or {}).get("wear_tool") or 0)
        alarms = []
        if math.isfinite(vb) and math.isfinite(lim) and vb >= WEAR_ALARM_SHARE * lim:
            alarms.append(wear_alarm_message(wear_tool, vb, lim))
        if math.isfinite(life) and life < LIFE_ALARM_MIN:
            who = f"tool {wear_tool}: " if wear_tool > 0 else ""
            alarms.append(f"{who}remaining tool life {life:.1f} min")
        if feed_health:
            if not feed_health.get("connected", True):
                # an OPC UA source's status names its server; a drive feed is the broker's
                who = "OPC UA server" if "server" in feed_health else "broker"
                alarms.append(f"drive feed: {who} not connected")
        body: EstimatesBody = {
            "wall": now,
            "t": t,
            "source": source,
            "force": groups["force"],
            "params": groups["params"],
            "harmonics": harmonics,
            "wear": {
                "tool": wear_tool,
                "VB_mm": vb,
                "VB_limit_mm": lim,
                "remaining_life_min": life,
            },
            "alarms": alarms,
            "health": health if health is not None else {},
            "dashboard": self.dashboard,
            "drive_wall": drive_wall,
        }
        if feed_health:
            body["feed"] = dict(feed_health)
        mon = _monitor(latest) if monitor is None else _monitor_of_status(monitor)
        if mon is not None:
            body["monitor"] = mon
        return body

    def due(self, now: float, t: float | None = None, *, paced: bool = True) -> bool:
        """A message is due: a period of wall time since the last (a paced source: the
        simulator, a replay at any speed), or, for a live feed (``paced`` False), the
        machine's time ``t`` past the next multiple of the period: a feed's messages then
        fall on the same machine times whoever runs it (``cutwatch serve`` or a worker)
        and however its blocks arrived."""
        if paced or t is None:
            return now - self._last_pub >= self.period
        # (time that went back: a new pipeline on the feed starts the grid again)
        return t >= self._next_t - 1e-9 or t < self._next_t - 2.0 * self.period

    def publish(self, body: EstimatesBody, now: float, t: float | None = None) -> bool:
        """Send ``body`` (never blocks; False when not connected); ``t``: the machine's
        time of the message (the next is due a period of it later, on its grid)."""
        # on the period's grid (a late publish does not push the next one later)
        self._last_pub = max(self._last_pub + self.period, now - self.period)
        if t is not None:
            self._next_t = (math.floor(t / self.period + 1e-9) + 1) * self.period
        c = self._client
        if c is None or not self.connected:
            return False
        info = c.publish(self.topic, encode_estimates(self.machine, body), qos=0)
        ok = info.rc == 0
        self.published += int(ok)
        return ok

    def health(self) -> EstimatesOutHealth:
        return {
            "topic": self.topic,
            "broker": self.cfg.describe(),
            "connected": self.connected,
            "error": self.last_error,
            "published": self.published,
            "rate_hz": 1.0 / self.period,
        }


class EstimatesOutHealth(TypedDict):
    """:meth:`EstimatesPublisher.health`: ``/api/health``'s ``estimates_out``."""

    topic: str
    broker: str
    connected: bool
    error: str
    published: int
    rate_hz: float


class RuntimeHealth(TypedDict):
    """The runtime's own health (``MachineRuntime.health``; the message's ``health``)."""

    runtime: str
    blocks: int
    resumed: bool
    step_ms_p50: float


class NoHealth(TypedDict):
    """No runtime's health (``{}``: :meth:`EstimatesPublisher.build` without one)."""


class StatusStrip(TypedDict, total=False):
    """The status strip (``server.service.messages.MonitorStatus``'s fields; a number not
    known is NaN, or None once JSON-safe: ``MachineRuntime.monitor_status``); what the
    ``monitor`` section carries of it (:class:`StatusSection`)."""

    state: str
    tool: int
    program: str
    line: int
    part: int
    wear_share: float | None
    life_left_min: float | None
    wear_tool: int
    wear_of: str
    wear_limit_mm: float | None
    wear_alarm_share: float | None
    wear_lo_share: float | None
    wear_hi_share: float | None
    wear_calibrated: bool | None
    unacked: int
    #: what tells the spindle's monitor the tool cuts (``server/pipeline/spindle_part.py``)
    cutting_from: str
    #: what tells the axes' monitor the tool cuts (``server/pipeline/axis_monitor_part.py``)
    axes_cutting_from: str


class StatusSection(TypedDict):
    """The ``monitor`` section taken from the service's status strip (:class:`StatusStrip`;
    a field the strip leaves out is None), in the message's order."""

    state: str | None
    tool: int | None
    program: str | None
    line: int | None
    part: int | None
    unacked: int | None
    wear_tool: int | None
    wear_of: str | None
    wear_share: float | None
    wear_limit_mm: float | None
    wear_alarm_share: float | None
    life_left_min: float | None


class WearSection(TypedDict):
    """The estimates message's ``wear``: one tool's estimated flank wear and life."""

    tool: int
    VB_mm: float
    VB_limit_mm: float
    remaining_life_min: float


class EstimatesBody(TypedDict):
    """The estimates message's body (:meth:`EstimatesPublisher.build`; ``encode_estimates``
    adds its schema, version and machine)."""

    wall: float
    t: float
    source: str
    force: dict[str, float]
    params: dict[str, float]
    harmonics: dict[str, float]
    wear: WearSection
    alarms: list[str]
    #: the runtime's health ({}: none given)
    health: RuntimeHealth | NoHealth
    dashboard: str | None
    drive_wall: float | None
    #: the drive feed's health (its source's own fields: free JSON of the feed's kind)
    feed: NotRequired[dict[str, Any]]
    monitor: NotRequired[MonitorSection | StatusSection]


class MonitorSection(TypedDict):
    """The process monitor's state, tool and line from its latest channel values."""

    state: str
    tool: int
    line: int


def _axis_param(group: str) -> bool:
    """A group ``<axis>.<parameter>`` of the axes' live identification (``X.M``)."""
    return "." in group and group.rsplit(".", 1)[1] in ("M", "Fv", "Fc", "offset", "motion")


def _monitor(latest: Mapping[str, float]) -> MonitorSection | None:
    """The process monitor's state, tool and line from its latest channel values."""
    st = latest.get("mon_state")
    if st is None or not math.isfinite(st):
        return None
    tool, line = latest.get("mon_tool", math.nan), latest.get("mon_line", math.nan)
    return {
        "state": MONITOR_STATES.get(round(st), "off"),
        "tool": round(tool) if math.isfinite(tool) else 0,
        "line": round(line) if math.isfinite(line) else 0,
    }


def _monitor_of_status(st: StatusStrip) -> StatusSection:
    """The ``monitor`` section from the service's status strip (its fields of one tool's
    wear with it: the strip, the snapshot and this section say the same; a field the
    strip leaves out is None)."""
    return {
        "state": st.get("state"),
        "tool": st.get("tool"),
        "program": st.get("program"),
        "line": st.get("line"),
        "part": st.get("part"),
        "unacked": st.get("unacked"),
        "wear_tool": st.get("wear_tool"),
        "wear_of": st.get("wear_of"),
        "wear_share": st.get("wear_share"),
        "wear_limit_mm": st.get("wear_limit_mm"),
        "wear_alarm_share": st.get("wear_alarm_share"),
        "life_left_min": st.get("life_left_min"),
    }
