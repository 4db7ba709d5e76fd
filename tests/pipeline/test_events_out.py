"""The monitor's events and feed-hold commands on a real Mosquitto: topics, QoS 1, the wire
shapes, the command before its event, nothing for an alarm but the event; a broker that
is not there costs the caller nothing."""

from __future__ import annotations

import json
import queue
import time
from functools import partial

import paho.mqtt.client as mqtt
from _broker import broker, free_port, returns, silent_broker
from _wait import poll

from server.pipeline.broker import parse_broker_url
from server.pipeline.events_out import COMMAND_SCHEMA, EventsPublisher
from server.records.monitor_events import MonitorEvent


def _subscriber(port: int, topic: str) -> tuple[mqtt.Client, queue.Queue[mqtt.MQTTMessage]]:
    got: queue.Queue[mqtt.MQTTMessage] = queue.Queue()
    sub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    sub.on_message = lambda _c, _u, m: got.put(m)
    subscribed = queue.Queue[int]()
    sub.on_subscribe = lambda _c, _u, mid, _rc, _p: subscribed.put(mid)
    sub.connect("127.0.0.1", port)
    sub.loop_start()
    sub.subscribe(topic, qos=1)
    subscribed.get(timeout=5)
    return sub, got


def test_a_feed_hold_sends_its_command_then_its_event_and_an_alarm_only_its_event() -> None:
    with broker() as port:
        sub, got = _subscriber(port, "cutwatch/m1/#")
        pub = EventsPublisher(parse_broker_url(f"mqtt://127.0.0.1:{port}"), "m1")
        pub.start()
        try:
            poll(lambda: pub.connected, 10, 0.02)
            brk = MonitorEvent("breakage", "feed_hold", 12.5, tool=3, program="P1", line=40,
                               part=7, value=0.8, limit=0.3, unit="1", machine="m1")  # fmt: skip
            wear = MonitorEvent("wear_limit", "alarm", 13.0, value=0.28, limit=0.27, unit="mm")
            pub.publish([brk, wear])
            msgs = [got.get(timeout=5) for _ in range(3)]
            time.sleep(0.3)  # nothing else comes (no command for the alarm)
            assert got.empty()
        finally:
            pub.stop()
            sub.loop_stop()
            sub.disconnect()
    assert [m.topic for m in msgs] == [
        "cutwatch/m1/command",
        "cutwatch/m1/events",
        "cutwatch/m1/events",
    ]
    assert all(m.qos == 1 and not m.retain for m in msgs)
    cmd = json.loads(msgs[0].payload)
    assert cmd["schema"] == COMMAND_SCHEMA and cmd["version"] == 1
    assert cmd["command"] == "feed_hold" and cmd["event_id"] == brk.id
    assert cmd["machine"] == "m1" and cmd["t"] == 12.5 and abs(cmd["wall"] - time.time()) < 30
    first = json.loads(msgs[1].payload)
    assert first["schema"] == "cutwatch.event" and first["version"] == 1
    assert MonitorEvent.from_dict(first) == brk  # the whole event, identities and all
    assert MonitorEvent.from_dict(json.loads(msgs[2].payload)) == wear
    h = pub.health()
    assert (h["events"], h["commands"], h["refused"]) == (2, 1, 0)


def test_without_a_broker_publishing_neither_blocks_nor_raises() -> None:
    # "never blocks" judged where a wait could never end, not by a clock (a loaded box
    # can stall any call 200 ms): no broker at all (refused), and a broker that takes the
    # connection and never answers; a publish that waited on the network (its connection,
    # an acknowledgement) would not return from the second
    with silent_broker() as hung:
        for port in (free_port(), hung):
            pub = EventsPublisher(parse_broker_url(f"mqtt://127.0.0.1:{port}"), "m1")
            pub.start()
            try:
                evs = [MonitorEvent("collision", "feed_hold", float(i)) for i in range(50)]
                assert returns(partial(pub.publish, evs)) == [None], f"publish waits on port {port}"
                h = pub.health()
            finally:
                pub.stop(timeout=0.1)
            assert h["connected"] is False
            # kept by paho for when the broker comes (QoS 1), counted as handed over
            assert (h["events"], h["commands"], h["refused"]) == (50, 50, 0)
