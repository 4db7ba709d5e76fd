"""The worker's runtime in this process, on a real Mosquitto: it adopts only its own
machines (from their retained meta), publishes each machine's estimates and the
monitor's events (``cutwatch/<machine>/events``, QoS 1, the machine stamped; a feed hold
also as a command), and writes every machine's checkpoint when it stops."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import paho.mqtt.client as mqtt
import pytest
from _broker import broker

from common.state_io import load_state
from server.pipeline.broker import parse_broker_url
from server.pipeline.checkpoint import KIND, VERSION
from server.pipeline.worker import Worker, WorkerConfig
from server.records.drive_wire import encode_drive, encode_meta
from server.records.monitor_events import MonitorEvent, event_id

pytestmark = pytest.mark.slow

TS = 4e-4
META = {
    "kind": "two_inertia",
    "sample_time": TS,
    "units": {"effort": "N m", "position": "rad"},
    "nominal": {"J_M": 2.8e-4, "J_L": 2.8e-4, "K": 900.0, "K_t": 0.571, "B_M": 2e-3,
                "B_L": 2e-3, "F_CM": 0.15, "F_CL": 0.15},
}  # fmt: skip


def _blocks(seq0: int, n_blocks: int, per: int = 125) -> list[bytes]:
    out = []
    for b in range(seq0, seq0 + n_blocks):
        t = (b * per + np.arange(per)) * TS
        q = np.sin(2 * np.pi * 0.5 * t)
        cols = {"tau_m": 0.1 * np.cos(2 * np.pi * 0.5 * t), "q_m": q, "q_l": q}
        units = {"effort": "N m", "position": "rad", "current": "A"}
        out.append(encode_drive(b, float(t[0]), TS, cols, units, None, wall=time.time()))
    return out


def test_the_worker_publishes_estimates_and_events_and_checkpoints(tmp_path: Path) -> None:
    got: dict[str, list[dict[str, Any]]] = {}
    lock = threading.Lock()

    def on_message(_c: object, _u: object, m: Any) -> None:
        with lock:
            got.setdefault(m.topic, []).append(json.loads(m.payload))

    with broker() as port:
        url = f"mqtt://127.0.0.1:{port}"
        sub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        sub.on_message = on_message
        sub.connect("127.0.0.1", port)
        sub.subscribe([("cutwatch/+/estimates", 0), ("cutwatch/+/events", 1),
                       ("cutwatch/+/command", 1)])  # fmt: skip
        sub.loop_start()
        pub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        pub.connect("127.0.0.1", port)
        pub.loop_start()
        for m in ("mine", "theirs"):  # retained, before the worker starts
            pub.publish(
                f"cutwatch/{m}/meta", encode_meta(META), qos=1, retain=True
            ).wait_for_publish()
        w = Worker(
            parse_broker_url(url),
            WorkerConfig(machines=frozenset({"mine"}), data_dir=tmp_path, checkpoint_s=60),
        )
        w.start()
        try:
            deadline = time.monotonic() + 60
            while "mine" not in w.runs and time.monotonic() < deadline:
                time.sleep(0.1)
            assert set(w.runs) == {"mine"}  # "theirs" is not adopted
            seq = 0
            for m in ("mine", "theirs"):
                for p in _blocks(0, 20):
                    pub.publish(f"cutwatch/{m}/drive", p)
            seq = 20
            run = w.runs["mine"]
            while (run.pipe is None or run.pipe.t < 0.99) and time.monotonic() < deadline:
                time.sleep(0.1)
            assert run.pipe is not None and run.pipe.t >= 0.99  # the 20 blocks (1 s) taken
            ev = MonitorEvent("breakage", "feed_hold", t=1.0, tool=3, message="tool broken")
            run.pipe.events.put(ev)
            for p in _blocks(seq, 4):
                pub.publish("cutwatch/mine/drive", p)
            while time.monotonic() < deadline:
                with lock:
                    if "cutwatch/mine/events" in got and "cutwatch/mine/command" in got:
                        break
                time.sleep(0.1)
        finally:
            w.stop()
            sub.loop_stop()
            pub.loop_stop()
    with lock:
        events, cmds = got.get("cutwatch/mine/events", []), got.get("cutwatch/mine/command", [])
        est = got.get("cutwatch/mine/estimates", [])
    assert est and "cutwatch/theirs/estimates" not in got
    assert len(events) == 1 and events[0]["schema"] == "cutwatch.event"
    # the runtime's stable id (the machine's name and what the event is)
    assert events[0]["machine"] == "mine" and events[0]["id"] == event_id(ev, "mine")
    assert events[0]["kind"] == "breakage" and events[0]["tool"] == 3
    # the service's command (events_out.command_body), built by the same runtime
    assert len(cmds) == 1 and 0 < time.time() - cmds[0].pop("wall") < 120
    assert cmds == [{"schema": "cutwatch.command", "version": 1, "command": "feed_hold",
                     "event_id": event_id(ev, "mine"), "machine": "mine", "t": 1.0}]  # fmt: skip
    # stop() wrote the machine's checkpoint (its period, 60 s, had not come)
    state, _ = load_state(tmp_path / "state" / "mine.npz", kind=KIND, version=VERSION)
    assert state.source == "mqtt" and state.t > 0
    assert not (tmp_path / "state" / "theirs.npz").exists()
