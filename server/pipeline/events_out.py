"""The monitor's events on the broker, and the feed-hold command for the machine's edge device.

Every event the live loop takes from the pipeline is published on
``cutwatch/<machine>/events`` (QoS 1, not retained) as
:meth:`~server.records.monitor_events.MonitorEvent.to_wire` (schema ``cutwatch.event``,
version 1). An event whose action is ``feed_hold`` is preceded, on
``cutwatch/<machine>/command`` (QoS 1, not retained), by the command::

    {"schema": "cutwatch.command", "version": 1, "command": "feed_hold",
     "event_id": "<the event's id>", "machine": "<machine>", "t": <the event's t [s]>,
     "wall": <when the service sent it [unix s]>}

cutwatch does not stop the machine: the stop belongs in the CNC. An edge device on the
machine (a PLC gateway, the CNC's OPC UA client) subscribes to the command topic and
sets the CNC's feed hold; it acts on each ``event_id`` once (QoS 1 delivers at least
once). The command is sent before its event so the edge device gets it first. Neither
message is retained: a retained feed hold would stop the machine again on every
reconnect of the edge device.

Publishing never blocks or raises into the loop: paho queues the message for its
network thread (while the broker is away, QoS 1 messages wait in paho's queue, at most
:data:`MAX_QUEUED`, and go out when it is back; beyond that they are counted in
``refused``). :meth:`EventsPublisher.health` says connected or not and counts what was
handed over.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Iterable
from typing import Any, TypedDict

from server.pipeline.broker import (
    BrokerConfig,
    connect_in_background,
    topic,
)
from server.records.monitor_events import EventWire, MonitorEvent

#: the command's wire schema and version (``cutwatch/<machine>/command``)
COMMAND_SCHEMA = "cutwatch.command"
COMMAND_VERSION = 1
#: QoS of both topics: at least once
QOS = 1
#: messages paho keeps while the broker is away (beyond: refused, counted)
MAX_QUEUED = 1000
#: paho's results of a publish that will reach the broker: MQTT_ERR_SUCCESS, and
#: MQTT_ERR_NO_CONN (a QoS 1 message kept and sent once connected)
_HANDED_OVER = (0, 4)

log = logging.getLogger("uvicorn.error")


class FeedHoldCommand(TypedDict):
    """The command's message on ``cutwatch/<machine>/command``."""

    schema: str
    version: int
    command: str
    event_id: str
    machine: str
    t: float
    wall: float


class PublisherHealth(TypedDict):
    """:meth:`EventsPublisher.health`: topics, broker, connection and counters."""

    topics: list[str]
    broker: str
    connected: bool
    error: str
    events: int
    commands: int
    refused: int


def command_body(ev: MonitorEvent, machine: str, wall: float) -> FeedHoldCommand:
    """The feed-hold command for the event ``ev`` (see the module docstring)."""
    return {
        "schema": COMMAND_SCHEMA,
        "version": COMMAND_VERSION,
        "command": "feed_hold",
        "event_id": ev.id,
        "machine": machine,
        "t": ev.t,
        "wall": wall,
    }


class EventsPublisher:
    """Publish events and feed-hold commands of one machine (see the module docstring).

    Parameters
    ----------
    cfg : BrokerConfig
    machine : str
        The machine's name (checked: letters, digits, ``_ . -``).
    """

    def __init__(self, cfg: BrokerConfig, machine: str) -> None:
        self.cfg = cfg
        self.machine = machine
        self.events_topic = topic(machine, "events")
        self.command_topic = topic(machine, "command")
        self.connected = False
        self.last_error = ""
        self.events = 0  # events handed to the client
        self.commands = 0  # feed-hold commands handed to the client
        self.refused = 0  # messages the client refused (its queue full)
        self._lock = threading.Lock()
        self._client: Any = None
        self._shared = False

    def start(self) -> None:
        """Connect in the background (paho's network thread; it reconnects by itself)."""
        self._client = connect_in_background(
            self.cfg, f"cutwatch-events-{self.machine}", self, max_queued=MAX_QUEUED
        )

    def share(self, client: Any) -> None:
        """Publish through ``client``, a connection shared with other machines (a worker's;
        the owner keeps :attr:`connected` up to date) instead of one of its own."""
        self._client = client
        self._shared = True

    def stop(self, timeout: float = 2.0) -> None:
        """Give the messages in flight up to ``timeout`` seconds, then disconnect (a
        shared connection is its owner's to close)."""
        c, self._client = self._client, None
        if c is None or self._shared:
            return
        deadline = time.monotonic() + timeout
        while self.connected and c.want_write() and time.monotonic() < deadline:
            time.sleep(0.01)
        c.disconnect()
        c.loop_stop()

    def publish(self, events: Iterable[MonitorEvent]) -> None:
        """Hand ``events`` (and a command before each ``feed_hold``) to the client; never
        blocks on the broker, never raises."""
        c = self._client
        if c is None:
            return
        for ev in events:
            try:
                if ev.action == "feed_hold":
                    body = command_body(ev, self.machine, time.time())
                    self._send(c, self.command_topic, body, "commands")
                self._send(c, self.events_topic, ev.to_wire(), "events")
            except Exception as exc:  # a bad event must not stop the loop: say so
                with self._lock:
                    self.refused += 1
                    self.last_error = f"{type(exc).__name__}: {exc}"
                log.warning("cutwatch: event %s not published: %s", ev.id, exc)

    def _send(self, c: Any, leaf: str, body: FeedHoldCommand | EventWire, counter: str) -> None:
        payload = json.dumps(body, allow_nan=False, separators=(",", ":"))
        info = c.publish(leaf, payload, qos=QOS, retain=False)
        ok = int(info.rc) in _HANDED_OVER  # else MQTT_ERR_QUEUE_SIZE: refused
        with self._lock:
            if ok:
                setattr(self, counter, getattr(self, counter) + 1)
            else:
                self.refused += 1

    def health(self) -> PublisherHealth:
        """Topics, broker, connection and counters (``/api/health``'s ``events_out``)."""
        return {
            "topics": [self.events_topic, self.command_topic],
            "broker": self.cfg.describe(),
            "connected": self.connected,
            "error": self.last_error,
            "events": self.events,
            "commands": self.commands,
            "refused": self.refused,
        }
