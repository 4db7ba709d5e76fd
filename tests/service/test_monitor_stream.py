"""The monitor's events through the real service: on /ws (an event message, frames with the
status strip, the unacknowledged ones to a new client), in /api/snapshot and /metrics,
on a real Mosquitto; an acknowledgement announced to every client; inject and relearn
refused by name.

The events here are the tool-life monitor's own (the default scenario's first tool
passes 90 % of its wear limit at ~60 s of simulated time), run at the loop's top speed.
"""

from __future__ import annotations

import json
import queue
import socket
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import httpx
import paho.mqtt.client as mqtt
import pytest
import uvicorn
from _broker import broker
from _live import in_thread, serve
from _wait import poll
from websockets.sync.client import ClientConnection, connect

from server.cli.commands.serve import uvicorn_options
from server.records.monitor_events import MonitorEvent
from server.service.app import create_app
from server.service.loop import LiveLoop
from server.service.messages import Data, Event, EventMessage, MonitorStatus
from server.service.settings import Settings


@contextmanager
def serve_app(**settings: Any) -> Iterator[tuple[str, LiveLoop]]:
    """The real app on a free loopback port in this process; ``host:port`` and its loop."""
    with tempfile.TemporaryDirectory(prefix="cutwatch-data-") as d, socket.socket() as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(("127.0.0.1", 0))
        port = int(sock.getsockname()[1])
        s = Settings(port=port, viser=False, data_dir=d, **settings)
        app = create_app(s)
        options = uvicorn_options(s)
        del options["workers"]
        cfg = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", **options)
        with in_thread(uvicorn.Server(cfg), sock):
            yield f"127.0.0.1:{port}", app.state.loop


@dataclass
class Run:
    """What one run of the service showed: the stream up to and after the first event,
    the broker's messages, the loop."""

    hp: str
    loop: LiveLoop
    stream: list[dict[str, Any]] = field(default_factory=list)
    mqtt: list[mqtt.MQTTMessage] = field(default_factory=list)

    def events(self) -> list[dict[str, Any]]:
        return [m["event"] for m in self.stream if m["type"] == "event"]


def _recv(ws: ClientConnection) -> dict[str, Any]:
    msg: dict[str, Any] = json.loads(ws.recv(timeout=10))
    return msg


@pytest.fixture(scope="module")
def run() -> Iterator[Run]:
    with broker() as port:
        got: queue.Queue[mqtt.MQTTMessage] = queue.Queue()
        sub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        sub.on_message = lambda _c, _u, m: got.put(m)
        sub.connect("127.0.0.1", port)
        sub.loop_start()
        sub.subscribe("cutwatch/m1/#", qos=1)
        try:
            # paused until the stream and the subscriber listen
            url = f"mqtt://127.0.0.1:{port}"
            with serve_app(speed=0, mqtt_broker=url, mqtt_machine="m1") as (hp, loop):
                r = Run(hp, loop)
                health = f"http://{hp}/api/health"
                poll(lambda: httpx.get(health).json()["events_out"]["connected"], 10)
                with connect(f"ws://{hp}/ws") as ws:
                    r.stream.append(_recv(ws))  # hello
                    httpx.post(f"http://{hp}/api/control", json={"action": "speed", "value": 1000})
                    deadline = time.monotonic() + 60
                    while not r.events() and time.monotonic() < deadline:
                        r.stream.append(_recv(ws))
                    for _ in range(5):  # frames after the event
                        r.stream.append(_recv(ws))
                    httpx.post(f"http://{hp}/api/control", json={"action": "pause"})
                poll(lambda: got.qsize() >= 1, 10, 0.05)
                r.mqtt = [got.get_nowait() for _ in range(got.qsize())]
                yield r
        finally:
            sub.loop_stop()
            sub.disconnect()


def test_an_event_reaches_the_stream_with_its_machine(run: Run) -> None:
    assert run.stream[0]["type"] == "hello"
    evs = run.events()
    assert evs, "no event in 60 s"
    msg = next(m for m in run.stream if m["type"] == "event")
    EventMessage.model_validate(msg)  # the typed shape
    e = evs[0]
    assert (e["kind"], e["action"], e["unit"]) == ("wear_limit", "alarm", "mm")
    assert e["machine"] == "m1" and e["acked"] is False and e["acked_by"] is None
    assert e["value"] >= e["limit"] > 0 and 50 < e["t"] < 70


def test_frames_carry_the_status_and_turn_to_alarm(run: Run) -> None:
    frames = [m for m in run.stream if m["type"] == "data"]
    assert len(frames) >= 5
    for f in frames:
        Data.model_validate(f)
        MonitorStatus.model_validate(f["status"])
    i = next(i for i, m in enumerate(run.stream) if m["type"] == "event")
    before = [m["status"] for m in run.stream[:i] if m["type"] == "data"]
    after = [m["status"] for m in run.stream[i:] if m["type"] == "data"]
    assert before and all(s["state"] == "off" and s["unacked"] == 0 for s in before)
    assert after and all(s["state"] == "alarm" and s["unacked"] >= 1 for s in after)
    # the wear share the strip shows rises towards the limit
    shares = [s["wear_share"] for s in before if s["wear_share"] is not None]
    assert shares and 0.5 < shares[-1] < 1.0


def test_snapshot_and_metrics_carry_the_events(run: Run) -> None:
    snap = httpx.get(f"http://{run.hp}/api/snapshot").json()
    kept = [Event.model_validate(e) for e in snap["events"]]
    assert [e.id for e in kept][-1] == run.events()[0]["id"]  # newest first
    assert snap["status"]["state"] == "alarm" and snap["status"]["unacked"] == len(kept)
    m = httpx.get(f"http://{run.hp}/metrics").text
    n_wear = sum(e.kind == "wear_limit" for e in kept)
    assert f'cutwatch_events_total{{kind="wear_limit"}} {n_wear}' in m
    assert 'cutwatch_events_total{kind="breakage"} 0' in m
    assert f"cutwatch_events_unacked {len(kept)}" in m
    assert f"cutwatch_events_published_total {len(kept)}" in m
    assert "cutwatch_commands_published_total 0" in m  # an alarm: no feed hold


def test_the_broker_carries_the_event_and_no_command_for_an_alarm(run: Run) -> None:
    assert {m.topic for m in run.mqtt} == {"cutwatch/m1/events"}
    wire = json.loads(run.mqtt[0].payload)
    assert run.mqtt[0].qos == 1
    assert MonitorEvent.from_dict(wire).id == run.events()[0]["id"]
    assert wire["schema"] == "cutwatch.event" and wire["machine"] == "m1"


def test_a_new_client_gets_the_unacknowledged_events_after_hello(run: Run) -> None:
    with connect(f"ws://{run.hp}/ws") as ws:
        first = [_recv(ws) for _ in range(2)]
    assert first[0]["type"] == "hello"
    assert first[1]["type"] == "event" and first[1]["event"]["id"] == run.events()[0]["id"]


def test_an_acknowledgement_is_announced_and_clears_the_alarm(run: Run) -> None:
    kept = httpx.get(f"http://{run.hp}/api/snapshot").json()["events"]
    with connect(f"ws://{run.hp}/ws") as ws:
        assert _recv(ws)["type"] == "hello"
        backlog = [_recv(ws) for _ in kept]
        assert {m["event"]["id"] for m in backlog} == {e["id"] for e in kept}
        for e in kept:  # what the history's acknowledgement route hands the loop
            run.loop.announce_event({**e, "acked": True, "acked_by": "op", "acked_wall": 1.0})
        acks = []
        while len(acks) < len(kept):
            m = _recv(ws)
            if m["type"] == "event":
                acks.append(m["event"])
        frame = _recv(ws)
        while frame["type"] != "data":
            frame = _recv(ws)
    assert all(a["acked"] and a["acked_by"] == "op" for a in acks)
    assert frame["status"]["unacked"] == 0 and frame["status"]["state"] == "off"
    snap = httpx.get(f"http://{run.hp}/api/snapshot").json()
    assert all(e["acked"] for e in snap["events"]) and snap["status"]["state"] == "off"
    assert "cutwatch_events_unacked 0" in httpx.get(f"http://{run.hp}/metrics").text
    with connect(f"ws://{run.hp}/ws") as ws:  # nothing left to catch up on
        assert _recv(ws)["type"] == "hello" and _recv(ws)["type"] == "data"


# ------------------------------------------------------------------ inject, relearn: refused


@pytest.fixture(scope="module")
def hp() -> Iterator[str]:
    with serve(speed=0) as hostport:
        yield hostport


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"action": "inject"}, "kind"),
        ({"action": "inject", "kind": "meteor"}, "kind"),
        ({"action": "inject", "kind": "collision", "size": 0.5}, "size"),
        ({"action": "inject", "kind": "missing_tool", "size": 1.5}, "size"),
        ({"action": "inject", "kind": "breakage", "size": -0.1}, "size"),
        ({"action": "inject", "kind": "breakage", "size": "big"}, "size"),
        ({"action": "inject", "kind": "breakage", "at_t": -1}, "at_t"),
        ({"action": "inject", "kind": "breakage", "at_part": -2}, "at_part"),
        ({"action": "inject", "kind": "breakage", "at_part": 1.5}, "at_part"),
        ({"action": "inject", "kind": "breakage", "at_t": 3, "at_part": 2}, "at_part"),
        ({"action": "inject", "kind": "breakage", "tool": 2}, "tool"),
        ({"action": "relearn", "tool": 0}, "tool"),
        ({"action": "relearn", "program": ""}, "program"),
        ({"action": "relearn", "program": "P" * 65}, "program"),
        ({"action": "relearn", "kind": "breakage"}, "kind"),
        ({"action": "pause", "at_t": 3}, "at_t"),
    ],
)
def test_inject_and_relearn_refusals_name_the_field(
    hp: str, body: dict[str, Any], field: str
) -> None:
    r = httpx.post(f"http://{hp}/api/control", json=body)
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert [d["field"] for d in detail] == [field], detail
    d = detail[0]
    assert d["allowed"] and field in d["msg"]
    if field in body:
        assert d["got"] == body[field]  # the value found, not the whole body


# ------------------------------------------------------------------ one client's queue


def test_events_go_out_in_order_with_the_frames_and_are_never_dropped() -> None:
    import asyncio

    from server.service.loop import ClientQueue

    async def make() -> ClientQueue:
        return ClientQueue(3, asyncio.get_running_loop())

    q = asyncio.run(make())
    q.push("f1")
    q.push_event("e1")
    for f in ("f2", "f3", "f4", "f5"):  # f1, f2 pushed out of the full frame queue
        q.push(f)
    q.push_event("e2")
    q.push_event("e3")
    q.push("f6")
    hello, msgs, dropped = q.take_all()
    assert hello is None and dropped == 3
    assert msgs == [("event", "e1"), ("data", "f4"), ("data", "f5"), ("event", "e2"),
                    ("event", "e3"), ("data", "f6")]  # fmt: skip
    assert q.take_all() == (None, [], 0)
    q.push_event("e4")
    q.push_hello("H")  # the pipeline changed: old frames go, events stay
    q.push("g1")
    assert q.take_all() == ("H", [("event", "e4"), ("data", "g1")], 0)
