"""Estimates out: built from the pipeline's channels, published through a real broker."""

from __future__ import annotations

import math
import queue
import threading
import time
from functools import partial

import numpy as np
import paho.mqtt.client as mqtt
from _broker import broker, returns, silent_broker
from _wait import poll

from server.pipeline.broker import parse_broker_url
from server.pipeline.estimates_out import EstimatesPublisher
from server.pipeline.live_pipeline import LivePipeline
from server.records.drive_wire import decode_estimates


def test_the_message_carries_estimates_not_truth() -> None:
    p = LivePipeline("default", seed=0)
    pub = EstimatesPublisher(parse_broker_url("mqtt://127.0.0.1:1"), "m1", rate_hz=5)
    for _ in range(40):
        out = p.step(125)
        pub.observe(out)
    body = pub.build(time.time(), p.channels(), p.t, "simulator")
    f = np.asarray(out["f_adaptive"])
    assert math.isfinite(body["force"]["level"]) and body["force"]["level"] > 0
    assert body["force"]["f_adaptive"] == f[-1]
    assert "J_L_adaptive" in body["params"] and "J_L_true" not in body["params"]
    assert not any(k.endswith("_true") for g in ("force", "params", "harmonics") for k in body[g])
    assert set(body["wear"]) == {"tool", "VB_mm", "VB_limit_mm", "remaining_life_min"}
    # the level is the period's rms; the next period starts afresh
    assert math.isnan(pub.build(time.time(), p.channels(), p.t, "simulator")["force"]["level"])


def test_published_at_the_set_rate_through_a_broker() -> None:
    p = LivePipeline("default", seed=0)
    with broker() as port:
        got: queue.Queue[bytes] = queue.Queue()
        sub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        sub.on_message = lambda _c, _u, m: got.put(bytes(m.payload))
        subscribed = threading.Event()
        sub.on_subscribe = lambda *_a: subscribed.set()
        sub.connect("127.0.0.1", port)
        sub.subscribe("cutwatch/m1/estimates")
        sub.loop_start()
        pub = EstimatesPublisher(parse_broker_url(f"mqtt://127.0.0.1:{port}"), "m1", rate_hz=10)
        pub.start()
        try:
            # the subscription is in place before the first message (qos 0: not kept)
            assert subscribed.wait(30), "the subscription was not acknowledged"
            poll(lambda: pub.connected, 30, 0.05)
            # the rate is the publisher's schedule on the clock it is handed, so the test
            # hands it 1 s of 10 ms ticks: a loaded box that takes longer to step the
            # pipeline does not change the count (it did when the ticks were the wall's)
            now0 = time.time()
            sent = 0
            for k in range(100):
                pub.observe(p.step(125))
                now = now0 + 0.01 * k
                if pub.due(now):
                    sent += pub.publish(pub.build(now, p.channels(), p.t, "simulator"), now)
            poll(lambda: got.qsize() >= sent, 30, 0.05)  # each one through the broker
        finally:
            pub.stop()
            sub.loop_stop()
            sub.disconnect()
    msgs = [decode_estimates(got.get_nowait()) for _ in range(got.qsize())]
    assert 9 <= sent <= 11 and len(msgs) == sent
    assert msgs[-1]["machine"] == "m1" and msgs[-1]["source"] == "simulator"


def test_no_broker_never_blocks_or_raises() -> None:
    # judged where a wait could never end, not by a clock (a loaded box can stall any
    # call 200 ms): no broker (refused), and one that takes the connection and never
    # answers, where a publish that waited on the network would not return
    with silent_broker() as hung:
        for port in (1, hung):
            pub = EstimatesPublisher(parse_broker_url(f"mqtt://127.0.0.1:{port}"), "m1", rate_hz=10)
            pub.start()
            try:
                sent = returns(partial(pub.publish, {"x": 1}, time.time()))
                assert sent == [False] and not pub.health()["connected"]
            finally:
                pub.stop()


def test_the_monitor_state_travels_when_its_channels_are_streamed() -> None:
    pub = EstimatesPublisher(parse_broker_url("mqtt://127.0.0.1:1"), "m1", rate_hz=5)
    p = LivePipeline("default", seed=0)
    pub.observe(p.step(125))
    plain = pub.build(time.time(), p.channels(), p.t, "simulator")
    if "mon_state" not in {c.name for c in p.channels()}:
        assert "monitor" not in plain  # no process monitor: nothing claimed
    # the process monitor's channels, as the pipeline streams them (0 teaching, 1
    # watching, 2 alarm): the latest sample of the block decides
    for states, want in (([0.0, 0.0], "teaching"), ([0.0, 1.0], "watching"), ([1, 2], "alarm")):
        pub.observe({"t": [0.0, 1e-3], "mon_state": states, "mon_tool": [3, 3],
                     "mon_line": [110, 120]})  # fmt: skip
        body = pub.build(time.time(), p.channels(), p.t, "simulator")
        assert body["monitor"] == {"state": want, "tool": 3, "line": 120}
    # the service's status strip, when given, is what travels (it knows the acknowledgements)
    # (issue 28: with its one tool's wear, the tool named in the wear section and alarms)
    status = {"state": "watching", "tool": 4, "program": "O1", "line": 30, "part": 2,
              "wear_share": 0.5, "life_left_min": 9.0, "unacked": 0, "wear_tool": 2,
              "wear_of": "the stage's turning tool", "wear_limit_mm": 0.3,
              "wear_alarm_share": 0.9}  # fmt: skip
    body = pub.build(time.time(), p.channels(), p.t, "simulator", monitor=status)
    assert body["monitor"] == status
    assert body["wear"]["tool"] == 2
    pub.observe({"t": [0.0], "vb_est": [0.28], "vb_limit": [0.3], "life_left": [1.0]})
    body = pub.build(time.time(), p.channels(), p.t, "simulator", monitor=status)
    assert body["alarms"] == [
        "tool 2: flank wear 0.280 mm, 93 % of its limit 0.300 mm (alarm at 90 %): change the tool",
        "tool 2: remaining tool life 1.0 min",
    ]
