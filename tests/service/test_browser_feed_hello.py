"""A live feed's rate is not claimed before its meta (issue 30): the first ``hello`` of
a service on a broker whose machine has said nothing yet gives ``sample_time`` null (not
the simulator's 0.4 ms); the dashboard, in a real Chromium, shows the stream without a
script error; the meta brings a new hello with the feed's rate, and the page draws the
machine's parts from it. A real Mosquitto, the real app, real WebSocket traffic."""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np
import paho.mqtt.client as mqtt
from _broker import broker, need_mosquitto
from _browser import MARKS, chromium_page, wait_for
from _live import serve
from websockets.sync.client import connect

from machine.rigid_axis import RigidAxisParams, simulate_rigid_axis
from server.records.drive_wire import encode_drive, encode_meta

pytestmark = MARKS

TS = 1e-3  # the feed's rate: 1 kHz


def next_hello(ws: Any, timeout: float = 20.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = json.loads(ws.recv(timeout=timeout))
        if msg["type"] == "hello":
            return msg  # type: ignore[no-any-return]
    raise AssertionError(f"no hello within {timeout} s")


def publish_machine(port: int) -> None:
    """The machine's meta (retained) and 2 s of a rigid axis at 1 kHz, in 50 ms blocks."""
    x = simulate_rigid_axis(RigidAxisParams(sample_time=TS), 2.0, np.random.default_rng(3))
    sig = {"q_m": "X_pos", "tau_m": "X_force"}
    meta = {"sample_time": TS, "axes": {"X": {"kind": "rigid", "signals": sig,
            "units": {"position": "m", "effort": "N"}}}}  # fmt: skip
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    c.connect("127.0.0.1", port)
    c.loop_start()
    try:
        c.publish("cutwatch/m1/meta", encode_meta(meta), qos=1, retain=True).wait_for_publish(10)
        for seq, a in enumerate(range(0, len(x["q_m"]), 50)):
            cols = {"X_pos": x["q_m"][a : a + 50], "X_force": x["tau_m"][a : a + 50]}
            body = encode_drive(seq, a * TS, TS, cols, {"X_pos": "m", "X_force": "N"},
                                {"X_pos": "<f8", "X_force": "<f8"})  # fmt: skip
            c.publish("cutwatch/m1/drive", body, qos=1).wait_for_publish(10)
    finally:
        c.loop_stop()
        c.disconnect()


def test_no_rate_is_claimed_before_the_meta_and_the_page_copes() -> None:
    need_mosquitto()
    with (
        broker() as bp,
        serve(source="mqtt", mqtt_broker=f"mqtt://127.0.0.1:{bp}", mqtt_machine="m1") as hp,
    ):
        with connect(f"ws://{hp}/ws") as ws, chromium_page() as (page, errors):
            first = next_hello(ws)
            assert first["sample_time"] is None, first["sample_time"]  # not 0.0004
            page.goto(f"http://{hp}/")
            page.wait_for_selector("#conn[data-state=up]", timeout=20000)
            assert page.text_content("#error") == "" and errors == []
            publish_machine(bp)
            again = next_hello(ws)
            assert again["sample_time"] == TS  # the feed's rate, once it is known
            assert {c["name"] for c in again["channels"]} >= {"X.M", "X.Fc", "X.F"}
            wait_for(lambda: page.query_selector("tr[data-part=axes][data-running=true]"))
            assert page.text_content("#error") == "" and errors == []
