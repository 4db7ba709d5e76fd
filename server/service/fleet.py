"""The fleet page: one row per machine, from the estimates and events every service publishes.

``cutwatch fleet --broker URL`` subscribes to ``cutwatch/+/estimates`` and
``cutwatch/+/events`` (the process monitor's events, :meth:`MonitorEvent.to_wire`, QoS 1)
and serves a page (``/``) with one row per machine — status, the process monitor's state
and its latest unacknowledged event, force level, wear and remaining life, alarms, last
seen, a link to that machine's dashboard — pushed to the browser over ``/ws`` as each
message arrives (no polling delay). A machine with an unacknowledged ``feed_hold`` or
``alarm`` event is in alarm (its row highlighted) until the event is acknowledged: an
acknowledged copy of it (the same ``id`` with ``acked`` true) arrives, or the machine's
estimates say nothing waits (``monitor.unacked`` 0, which clears the events received
:data:`ACK_GRACE_S` before them or earlier: an estimate built before an event was raised
may arrive just after it). A machine that has not published for
``stale_after`` seconds shows as stale until it publishes again. ``/api/fleet`` gives the
same rows as JSON, ``/metrics`` the counters.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import threading
import time
from collections.abc import AsyncIterator, Iterable
from dataclasses import dataclass
from typing import Any, TypedDict
from urllib.parse import urlsplit, urlunsplit

from fastapi import FastAPI, WebSocket, WebSocketDisconnect
from fastapi.responses import PlainTextResponse
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from server.errors import CutwatchError
from server.pipeline.broker import BrokerConfig, check_machine, make_client, reason_text
from server.records.drive_wire import ESTIMATES_SCHEMA, VERSION
from server.records.monitor_events import MonitorEvent
from server.service import web_files
from server.service.auth import Origin, origin_of
from server.service.front import protect
from server.service.settings import Settings

TOPIC = "cutwatch/+/estimates"
#: the process monitor's events of every machine (QoS 1, as published)
EVENTS_TOPIC = "cutwatch/+/events"
#: events kept per machine (the newest)
EVENTS_KEPT = 50
#: the acknowledgement fields an event may carry beside :meth:`MonitorEvent.to_wire`'s
ACK_FIELDS = ("acked", "acked_by", "acked_wall")
#: an estimate saying no event waits clears the events received this long before it [s]
ACK_GRACE_S = 1.0


class FleetEvent(BaseModel):
    """A machine's event as the fleet page shows it."""

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
    acked: bool = False


class MachineRow(BaseModel):
    """One machine as the fleet page shows it."""

    machine: str
    status: str
    last_seen_s: float
    force: float | None = None
    wear_vb_mm: float | None = None
    remaining_life_min: float | None = None
    alarms: list[str] = []
    #: the process monitor's state (off / teaching / watching / alarm; None: not known)
    monitor: str | None = None
    #: the newest event waiting for an acknowledgement (feed hold or alarm), if any
    event: FleetEvent | None = None
    #: events waiting for an acknowledgement
    unacked: int = 0
    dashboard: str | None = None
    source: str | None = None
    messages: int = 0
    #: the drive block's publish time behind this estimate (unix s; for latency)
    drive_wall: float | None = None


class _Force(BaseModel):
    model_config = ConfigDict(extra="ignore", strict=True)
    level: float | None = None


class _Wear(BaseModel):
    model_config = ConfigDict(extra="ignore", strict=True)
    VB_mm: float | None = None
    remaining_life_min: float | None = None


class _Monitor(BaseModel):
    model_config = ConfigDict(extra="ignore", strict=True)
    state: str | None = None
    unacked: int | None = None


class Estimates(BaseModel):
    """What the fleet reads of an estimates message (``cutwatch.estimates``, version 1,
    docs/broker.md), each field checked by its type (JSON numbers, ``null`` for an
    unknown one); the message's other fields are not read."""

    model_config = ConfigDict(extra="ignore", strict=True, populate_by_name=True)
    schema_: str = Field(alias="schema")
    version: int
    machine: str
    force: _Force = Field(default_factory=_Force)
    wear: _Wear = Field(default_factory=_Wear)
    alarms: list[str] = []
    monitor: _Monitor | None = None
    dashboard: str | None = None
    source: str | None = None
    drive_wall: float | None = None

    @field_validator("schema_")
    @classmethod
    def _schema(cls, v: str) -> str:
        if v != ESTIMATES_SCHEMA:
            raise ValueError(f"schema: expected {ESTIMATES_SCHEMA!r}, got {v!r}")
        return v

    @field_validator("version")
    @classmethod
    def _version(cls, v: int) -> int:
        if v != VERSION:  # the wire format's (server.records.drive_wire)
            raise ValueError(f"version: expected {VERSION}, got {v}")
        return v


def machine_of(topic: str) -> str:
    """The machine of a topic ``cutwatch/<machine>/<kind>`` (a valid machine name).

    Raises
    ------
    ValueError
        Not such a topic, or not a machine name (``check_machine``).
    """
    parts = topic.split("/")
    if len(parts) != 3 or parts[0] != "cutwatch":
        raise ValueError(f"topic {topic!r}: expected cutwatch/<machine>/<kind>")
    try:
        return check_machine(parts[1])
    except CutwatchError as exc:
        raise ValueError(str(exc)) from None


@dataclass(frozen=True)
class Links:
    """Where a row's link to its machine's page goes, decided by the fleet's own
    configuration, never by a message alone.

    ``template`` (``cutwatch fleet --machine-url``, e.g. ``http://plant.lan/m/{machine}/``):
    every row links it, ``{machine}`` being the machine of the row's topic. Otherwise a
    message's ``dashboard`` is linked when it is an http(s) URL whose origin (scheme,
    host and port) is one of ``origins`` (``--dashboard-origin``: the workers' and the
    services' public URLs). Otherwise no link.
    """

    template: str | None = None
    origins: frozenset[Origin] = frozenset()

    @classmethod
    def parse(cls, template: str | None, origins: Iterable[str]) -> Links:
        """From the options' text.

        Raises
        ------
        CutwatchError
            A template without ``{machine}`` or not an http(s) URL, or an origin that is
            not ``http(s)://host[:port]``; the option and what it was given are named.
        """
        found: set[Origin] = set()
        for o in origins:
            parsed = origin_of(o)
            if parsed is None or urlsplit(o).path not in ("", "/"):
                raise CutwatchError(
                    f"--dashboard-origin: expected http(s)://host[:port], got {o!r}"
                )
            found.add(parsed)
        if template is not None:
            u = urlsplit(template.replace("{machine}", "m"))
            if "{machine}" not in template or origin_of(f"{u.scheme}://{u.netloc}") is None:
                raise CutwatchError(
                    "--machine-url: expected an http(s) URL holding {machine}, e.g. "
                    f"http://plant.lan/m/{{machine}}/, got {template!r}"
                )
        return cls(template, frozenset(found))

    def link(self, machine: str, claimed: str | None) -> str | None:
        """The link of ``machine``'s row; ``claimed``: its message's ``dashboard``."""
        if self.template is not None:
            return self.template.replace("{machine}", machine)
        if claimed is None or not claimed.isprintable() or " " in claimed:
            return None
        try:
            u = urlsplit(claimed)
        except ValueError:
            return None
        if origin_of(f"{u.scheme}://{u.netloc}") not in self.origins:
            return None
        return urlunsplit((u.scheme.lower(), u.netloc, u.path or "/", u.query, ""))


class FleetState:
    """The latest estimate of every machine; thread-safe (paho's thread writes)."""

    def __init__(self, stale_after: float = 5.0, links: Links | None = None) -> None:
        self.stale_after = float(stale_after)
        self.links = links if links is not None else Links()
        self._lock = threading.Lock()
        self._last: dict[str, tuple[float, Estimates, int]] = {}
        #: machine -> (wall time of its latest event, event id -> (event, received at))
        self._events: dict[str, tuple[float, dict[str, tuple[FleetEvent, float]]]] = {}
        self.malformed = 0
        self.events_received = 0
        self.latencies: list[float] = []  # drive block publish -> arrival here [s]
        self.listeners: list[tuple[asyncio.AbstractEventLoop, asyncio.Queue[str]]] = []

    def update(self, topic: str, payload: bytes, now: float | None = None) -> str | None:
        """Take one message of ``cutwatch/<machine>/estimates``, checked by its model
        (:class:`Estimates`); the row is the topic's machine, and a message whose body
        names another machine is refused. None (counted as malformed) when refused."""
        now = time.time() if now is None else now
        try:
            machine = machine_of(topic)
            d = Estimates.model_validate_json(payload)
            if d.machine != machine:
                raise ValueError(f"body says machine {d.machine!r} on {topic!r}")
        except (ValidationError, ValueError):
            self.malformed += 1
            return None
        with self._lock:
            _, _, count = self._last.get(machine, (0.0, d, 0))
            self._last[machine] = (now, d, count + 1)
            if d.monitor is not None and d.monitor.unacked == 0 and machine in self._events:
                for eid, (fe, got) in self._events[machine][1].items():
                    if not fe.acked and got <= now - ACK_GRACE_S:
                        self._events[machine][1][eid] = (fe.model_copy(update={"acked": True}), got)
            if d.drive_wall is not None:
                self.latencies.append(now - d.drive_wall)
                del self.latencies[:-10_000]
        self._push(machine, now)
        return machine

    def _push(self, machine: str, now: float) -> None:
        row = json.dumps(self.row(machine, now).model_dump())
        for loop, q in list(self.listeners):
            loop.call_soon_threadsafe(_offer, q, row)

    def event(self, topic: str, payload: bytes, now: float | None = None) -> str | None:
        """Take one message of ``cutwatch/<machine>/events``: the event (schema
        ``cutwatch.event``, checked by :meth:`MonitorEvent.from_dict`), with ``acked``
        when it is an acknowledged copy; the machine's row is pushed. The machine is the
        topic's; an event that names another is refused. None (and counted as malformed)
        when it is not one."""
        now = time.time() if now is None else now
        try:
            machine = machine_of(topic)
            d = json.loads(payload)
            if not isinstance(d, dict):
                raise ValueError("not an object")
            ack = {k: d.pop(k) for k in ACK_FIELDS if k in d}
            ev = MonitorEvent.from_dict(d)
            if ev.machine and ev.machine != machine:
                raise ValueError(f"event of machine {ev.machine!r} on {topic!r}")
            fe = FleetEvent.model_validate({**ev.as_dict(), "acked": bool(ack.get("acked"))})
        except (ValueError, TypeError):
            self.malformed += 1
            return None
        with self._lock:
            self.events_received += 1
            _, evs = self._events.get(machine, (0.0, {}))
            old = evs.get(fe.id)
            if old is None or not old[0].acked:  # an acknowledgement is never undone
                evs[fe.id] = (fe, now)
            while len(evs) > EVENTS_KEPT:
                del evs[min(evs.values(), key=lambda e: e[0].t)[0].id]
            self._events[machine] = (now, evs)
        self._push(machine, now)
        return machine

    def row(self, machine: str, now: float | None = None) -> MachineRow:
        now = time.time() if now is None else now
        with self._lock:
            seen, d, count = self._last.get(machine, (-math.inf, _NO_ESTIMATES, 0))
            ev_seen, evs = self._events.get(machine, (-math.inf, {}))
            events = sorted((e for e, _ in evs.values()), key=lambda e: e.t, reverse=True)
        seen = max(seen, ev_seen)
        age = now - seen
        waiting = [e for e in events if not e.acked and e.action != "notice"]
        monitor = d.monitor.state if d.monitor is not None else None
        if waiting:
            monitor = "alarm"
        bad = bool(d.alarms) or monitor == "alarm"
        status = "stale" if age > self.stale_after else ("alarm" if bad else "ok")
        return MachineRow(
            machine=machine,
            status=status,
            last_seen_s=round(age, 3),
            monitor=monitor,
            event=waiting[0] if waiting else None,
            unacked=len(waiting),
            force=_num(d.force.level),
            wear_vb_mm=_num(d.wear.VB_mm),
            remaining_life_min=_num(d.wear.remaining_life_min),
            alarms=list(d.alarms),
            dashboard=self.links.link(machine, d.dashboard),
            source=d.source,
            messages=count,
            drive_wall=_num(d.drive_wall),
        )

    def rows(self) -> list[MachineRow]:
        now = time.time()
        with self._lock:
            names = sorted(set(self._last) | set(self._events))
        return [self.row(m, now) for m in names]


def _num(v: float | None) -> float | None:
    return float(v) if v is not None and math.isfinite(v) else None


#: a machine known only from its events: no estimate yet
_NO_ESTIMATES = Estimates.model_validate({"schema": ESTIMATES_SCHEMA, "version": VERSION,
                                          "machine": "-"})  # fmt: skip


def _offer(q: asyncio.Queue[str], item: str) -> None:
    if q.full():  # latest wins: a slow page loses rows, never slows the fleet
        with contextlib.suppress(asyncio.QueueEmpty):
            q.get_nowait()
    q.put_nowait(item)


class BrokerLink(TypedDict):
    """The fleet page's broker subscription: connected, or why not."""

    connected: bool
    error: str  # the broker's refusal ('' while connected)


class FleetHealth(BaseModel):
    """``GET /api/health`` of the fleet page."""

    status: str = Field(description="'ok': the page answers (the broker's state: connected)")
    broker: str = Field(description="the broker, host:port")
    connected: bool = Field(description="subscribed to the broker")
    error: str = Field(description="the broker's refusal ('' while connected)")
    machines: int = Field(description="rows on the page")


def create_fleet_app(
    cfg: BrokerConfig, stale_after: float = 5.0, settings: Settings | None = None,
    links: Links | None = None,
) -> FastAPI:  # fmt: skip
    """The fleet page's app; the broker subscription lives as long as the app.

    ``settings``: the tokens, Host allow-list and limits (every process's, read from
    ``CUTWATCH_*`` when omitted; :func:`server.service.front.protect`); ``links``: where
    a row's link goes (:class:`Links`; none by default)."""
    state = FleetState(stale_after, links)
    status: BrokerLink = {"connected": False, "error": ""}

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        c: Any = make_client(cfg, client_id=f"cutwatch-fleet-{id(app)}")

        def on_connect(cl: Any, _u: object, _f: object, rc: Any, _p: object = None) -> None:
            if getattr(rc, "is_failure", False):
                status.update({"connected": False, "error": f"refused: {reason_text(rc)}"})
                return
            status.update({"connected": True, "error": ""})
            cl.subscribe([(TOPIC, 0), (EVENTS_TOPIC, 1)])

        def on_disconnect(_c: object, _u: object, _f: object, rc: Any, _p: object = None) -> None:
            status["connected"] = False

        c.on_connect = on_connect
        c.on_disconnect = on_disconnect

        def on_message(_c: object, _u: object, m: Any) -> None:
            if m.topic.endswith("/events"):
                state.event(str(m.topic), bytes(m.payload))
            else:
                state.update(str(m.topic), bytes(m.payload))

        c.on_message = on_message
        c.connect_async(cfg.host, cfg.port, keepalive=cfg.keepalive)
        c.loop_start()
        app.state.fleet = state
        try:
            yield
        finally:
            c.disconnect()
            c.loop_stop()

    app = FastAPI(title="cutwatch fleet", lifespan=lifespan)
    # the service's tokens, login, Host/Origin checks, headers and 4xx shape
    protect(app, settings if settings is not None else Settings())

    @app.get("/api/fleet", summary="one row per machine")
    def fleet() -> list[MachineRow]:
        return state.rows()

    @app.get("/api/health", summary="broker connection of the fleet page")
    def health() -> FleetHealth:
        return FleetHealth(status="ok", broker=cfg.describe(), **status, machines=len(state.rows()))

    @app.get("/metrics", response_class=PlainTextResponse, summary="Prometheus metrics")
    def metrics() -> str:
        rows = state.rows()
        lines = [
            f"cutwatch_fleet_machines {len(rows)}",
            f"cutwatch_fleet_stale_machines {sum(r.status == 'stale' for r in rows)}",
            f"cutwatch_fleet_malformed_total {state.malformed}",
            f"cutwatch_fleet_events_total {state.events_received}",
            f"cutwatch_fleet_alarm_machines {sum(r.monitor == 'alarm' for r in rows)}",
            f"cutwatch_fleet_broker_connected {int(status['connected'])}",
        ]
        return "\n".join(lines) + "\n"

    @app.websocket("/ws")
    async def ws(sock: WebSocket) -> None:
        await sock.accept()
        q: asyncio.Queue[str] = asyncio.Queue(maxsize=256)
        entry = (asyncio.get_running_loop(), q)
        state.listeners.append(entry)
        try:
            await sock.send_text(json.dumps({"rows": [r.model_dump() for r in state.rows()]}))
            refreshed = time.monotonic()
            while True:
                # each estimate as it arrives; all rows once a second, so ages and stale
                # states move even while other machines keep the queue busy
                wait = max(0.0, refreshed + 1.0 - time.monotonic())
                try:
                    row = await asyncio.wait_for(q.get(), timeout=wait)
                    await sock.send_text(row)
                except TimeoutError:
                    pass
                if time.monotonic() - refreshed >= 1.0:
                    refreshed = time.monotonic()
                    rows = [r.model_dump() for r in state.rows()]
                    await sock.send_text(json.dumps({"rows": rows}))
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            state.listeners.remove(entry)

    app.mount("/", web_files.page_files(web_files.FLEET, index=web_files.FLEET_PAGE), name="web")
    return app
