"""The monitor's events through the real service: on /ws (event messages, frames with the
status strip, the unacknowledged ones to a new client), in /api/snapshot and /metrics, on
a real Mosquitto (the event, and the feed-hold command before a breakage's event); an
acknowledgement (``POST /api/events/{id}/ack``) announced to every client; inject and
relearn refused by name.

One run of the default scenario at the loop's top speed, taught on 2 parts: a tooth
breakage injected through ``POST /api/control`` once the monitor watches (~30 s of
simulated time), and the tool-life monitor's own wear alarm (the first tool passes 90 %
of its wear limit at ~60 s).
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

from machine.process import default_program
from server.records.monitor_events import MonitorEvent
from server.service.app import create_app
from server.service.front import uvicorn_options
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
    """What one run of the service showed: the stream, the broker's messages (arrival
    order), the answer to the injection, the loop."""

    hp: str
    loop: LiveLoop
    stream: list[dict[str, Any]] = field(default_factory=list)
    mqtt: list[mqtt.MQTTMessage] = field(default_factory=list)
    injected: dict[str, Any] = field(default_factory=dict)

    def events(self, kind: str | None = None) -> list[dict[str, Any]]:
        return [
            m["event"]
            for m in self.stream
            if m["type"] == "event" and (kind is None or m["event"]["kind"] == kind)
        ]


def _recv(ws: ClientConnection) -> dict[str, Any]:
    msg: dict[str, Any] = json.loads(ws.recv(timeout=10))
    return msg


def _drive(r: Run, ws: ClientConnection) -> None:
    """Run at top speed; inject a breakage once the monitor watches; on until the wear
    alarm and the breakage's event have come, and five frames more."""
    base = f"http://{r.hp}"
    r.stream.append(_recv(ws))  # hello
    httpx.patch(f"{base}/api/params", json={"teach_parts": 2}).raise_for_status()
    httpx.post(f"{base}/api/control", json={"action": "speed", "value": 1000})
    deadline = time.monotonic() + 120
    while not (r.events("wear_limit") and r.events("breakage")):
        assert time.monotonic() < deadline, "no breakage and wear alarm in 120 s"
        m = _recv(ws)
        r.stream.append(m)
        if not r.injected and m["type"] == "data" and m["status"]["state"] == "watching":
            body = {"action": "inject", "kind": "breakage"}
            ans = httpx.post(f"{base}/api/control", json=body)
            assert ans.status_code == 200, ans.text
            r.injected = ans.json()
    r.stream += [_recv(ws) for _ in range(5)]
    httpx.post(f"{base}/api/control", json={"action": "pause"})


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
            with serve_app(scenario="default", speed=0, mqtt_broker=url, mqtt_machine="m1") as (
                hp,
                loop,
            ):
                r = Run(hp, loop)
                health = f"http://{hp}/api/health"
                poll(lambda: httpx.get(health).json()["events_out"]["connected"], 10)
                with connect(f"ws://{hp}/ws") as ws:
                    _drive(r, ws)
                # until every event the stream told of, and a command for each feed hold,
                # is on the broker (was: as many messages as events, commands counted
                # too, then a fixed 0.2 s for the rest)
                kept = r.events()
                holds = sum(e["action"] == "feed_hold" for e in kept)
                msgs: list[mqtt.MQTTMessage] = []

                def all_in() -> bool:
                    while not got.empty():
                        msgs.append(got.get_nowait())
                    topics = [m.topic for m in msgs]
                    return (topics.count("cutwatch/m1/events") >= len(kept)
                            and topics.count("cutwatch/m1/command") >= holds)  # fmt: skip

                poll(all_in, 30, 0.05)
                r.mqtt = msgs
                yield r
        finally:
            sub.loop_stop()
            sub.disconnect()


def test_events_reach_the_stream_with_their_machine_and_identities(run: Run) -> None:
    assert run.stream[0]["type"] == "hello"
    for m in run.stream:
        if m["type"] == "event":
            EventMessage.model_validate(m)  # the typed shape
    wear = run.events("wear_limit")[0]
    assert (wear["action"], wear["unit"], wear["machine"]) == ("alarm", "mm", "m1")
    assert wear["value"] >= wear["limit"] > 0 and 50 < wear["t"] < 70
    assert wear["acked"] is False and wear["acked_by"] is None
    brk = run.events("breakage")[0]
    assert brk["action"] == "feed_hold" and brk["machine"] == "m1"
    # the CNC's identities of the block it happened in
    assert brk["tool"] >= 1 and brk["program"] and brk["line"] > 0 and brk["part"] >= 2
    assert run.injected["scheduled"]["kind"] == "breakage"
    assert brk["t"] >= run.injected["scheduled"]["now"]


def test_the_truth_of_the_injection_is_in_the_snapshot_and_the_event_follows_it(run: Run) -> None:
    snap = httpx.get(f"http://{run.hp}/api/snapshot").json()
    truths = [t for t in snap["pipeline"]["injected"] if t["kind"] == "breakage"]
    assert len(truths) == 1
    brk = run.events("breakage")[0]
    rpm = next(b.spindle_rpm for b in default_program().blocks if b.line == brk["line"])
    assert 0.0 <= brk["t"] - truths[0]["t"] <= 2 * 60.0 / rpm  # within two revolutions


def test_frames_carry_the_status_and_turn_to_alarm(run: Run) -> None:
    frames = [m for m in run.stream if m["type"] == "data"]
    assert len(frames) >= 5
    for f in frames:
        Data.model_validate(f)
        MonitorStatus.model_validate(f["status"])
    i = next(i for i, m in enumerate(run.stream) if m["type"] == "event")
    before = [m["status"] for m in run.stream[:i] if m["type"] == "data"]
    after = [m["status"] for m in run.stream[i:] if m["type"] == "data"]
    assert before and all(s["state"] != "alarm" and s["unacked"] == 0 for s in before)
    assert {s["state"] for s in before} == {"teaching", "watching"}
    assert after and all(s["state"] == "alarm" and s["unacked"] >= 1 for s in after)
    shares = [s["wear_share"] for s in before if s["wear_share"] is not None]
    assert shares and 0.3 < shares[-1] < 1.0
    assert {s["tool"] for s in before} >= {1, 2}  # the tool in the spindle, changed


def test_snapshot_and_metrics_carry_the_events(run: Run) -> None:
    snap = httpx.get(f"http://{run.hp}/api/snapshot").json()
    kept = [Event.model_validate(e) for e in snap["events"]]
    assert [e.id for e in kept] == [e["id"] for e in reversed(run.events())]  # newest first
    assert snap["status"]["state"] == "alarm" and snap["status"]["unacked"] == len(kept)
    m = httpx.get(f"http://{run.hp}/metrics").text
    for kind in ("breakage", "collision", "missing_tool", "wear_limit", "life_short"):
        n = sum(e.kind == kind for e in kept)
        assert f'cutwatch_events_total{{kind="{kind}"}} {n}' in m
    holds = sum(e.action == "feed_hold" for e in kept)
    assert holds >= 1
    assert f"cutwatch_events_unacked {len(kept)}" in m
    assert f"cutwatch_events_published_total {len(kept)}" in m
    assert f"cutwatch_commands_published_total {holds}" in m


def test_the_broker_carries_each_event_and_a_command_before_each_feed_hold(run: Run) -> None:
    assert all(m.qos == 1 and not m.retain for m in run.mqtt)
    topics = [m.topic for m in run.mqtt]
    bodies = [json.loads(m.payload) for m in run.mqtt]
    events = [MonitorEvent.from_dict(b) for t, b in zip(topics, bodies, strict=True)
              if t == "cutwatch/m1/events"]  # fmt: skip
    assert [e.id for e in events] == [e["id"] for e in run.events()]
    assert all(e.machine == "m1" for e in events)
    commands = [(i, b) for i, (t, b) in enumerate(zip(topics, bodies, strict=True))
                if t == "cutwatch/m1/command"]  # fmt: skip
    holds = [e for e in events if e.action == "feed_hold"]
    assert [b["event_id"] for _, b in commands] == [e.id for e in holds]
    for i, cmd in commands:
        assert cmd["schema"] == "cutwatch.command" and cmd["version"] == 1
        assert cmd["command"] == "feed_hold" and cmd["machine"] == "m1"
        ev = next(e for e in holds if e.id == cmd["event_id"])
        assert cmd["t"] == ev.t
        j = topics.index("cutwatch/m1/events", i)  # the next event on the broker is its own
        assert bodies[j]["id"] == ev.id
    wear = run.events("wear_limit")[0]["id"]
    assert wear not in [b["event_id"] for _, b in commands]  # an alarm: no command


def test_a_new_client_gets_the_unacknowledged_events_after_hello(run: Run) -> None:
    n = len(run.events())
    with connect(f"ws://{run.hp}/ws") as ws:
        first = [_recv(ws) for _ in range(1 + n)]
    assert first[0]["type"] == "hello"
    assert [m["event"]["id"] for m in first[1:]] == [e["id"] for e in run.events()]


def test_an_acknowledgement_is_announced_and_clears_the_alarm(run: Run) -> None:
    kept = httpx.get(f"http://{run.hp}/api/snapshot").json()["events"]
    with connect(f"ws://{run.hp}/ws") as ws:
        assert _recv(ws)["type"] == "hello"
        backlog = [_recv(ws) for _ in kept]
        assert {m["event"]["id"] for m in backlog} == {e["id"] for e in kept}
        for e in kept:  # the operator's acknowledgement (the history's route)
            r = httpx.post(f"http://{run.hp}/api/events/{e['id']}/ack")
            assert r.status_code == 200 and r.json()["acked"] is True, r.text
        acks = []
        while len(acks) < len(kept):
            m = _recv(ws)
            if m["type"] == "event":
                acks.append(m["event"])
        frame = _recv(ws)
        while frame["type"] != "data":
            frame = _recv(ws)
    assert all(a["acked"] and a["acked_by"] and a["acked_wall"] for a in acks)
    assert {a["id"] for a in acks} == {e["id"] for e in kept}
    assert frame["status"]["unacked"] == 0 and frame["status"]["state"] != "alarm"
    snap = httpx.get(f"http://{run.hp}/api/snapshot").json()
    assert all(e["acked"] for e in snap["events"]) and snap["status"]["state"] != "alarm"
    assert "cutwatch_events_unacked 0" in httpx.get(f"http://{run.hp}/metrics").text
    with connect(f"ws://{run.hp}/ws") as ws:  # nothing left to catch up on
        assert _recv(ws)["type"] == "hello" and _recv(ws)["type"] == "data"


# ------------------------------------------------------------------ inject, relearn: refused


@pytest.fixture(scope="module")
def hp() -> Iterator[str]:
    with serve(scenario="default", speed=0) as hostport:
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
        ({"action": "inject", "kind": "breakage", "size": 0.01}, "size"),  # 10 mm
        ({"action": "inject", "kind": "breakage", "at_t": 3, "at_part": 2}, "at_t"),
        ({"action": "inject", "kind": "breakage", "tool": 2}, "tool"),
        ({"action": "relearn", "tool": 0}, "tool"),
        ({"action": "relearn", "program": ""}, "program"),
        ({"action": "relearn", "program": "P" * 33}, "program"),
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

    from server.service.hub import ClientQueue

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
