"""The CNC's identities of a broker feed reach the parts (issue 32 item 3): the drive
header's segments (tool, line, override) as the description's identity columns, as a
log or the simulated centre gives them, so the spindle part's monitor keys its blocks."""

from __future__ import annotations

from typing import Any

import numpy as np

from server.pipeline.broker import parse_broker_url
from server.pipeline.centre_feed import CentreFeed, CentreFeedParams
from server.pipeline.drive_feed import DriveFeed
from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.mqtt_source import MqttSource
from server.records.drive_wire import decode_drive


def test_identities_of_the_drive_header_are_columns_of_the_block() -> None:
    feed_sim = CentreFeed(0, 3, CentreFeedParams(rate_hz=500.0, block_ms=100.0))
    blocks = [feed_sim.next_block(i) for i in range(40)]  # 4 s: past the tool change
    feed = DriveFeed(parse_broker_url("mqtt://127.0.0.1:1"), "vmc", max_samples=10_000)
    feed.push_meta(feed_sim.meta)
    for b in blocks:
        feed.push(b)
    src = MqttSource(feed)
    got = [src.step(50) for _ in range(40)]
    line = np.concatenate([g.columns["line"] for g in got])
    tool = np.concatenate([g.columns["tool"] for g in got])
    sent = [decode_drive(b).identities() or {} for b in blocks]
    np.testing.assert_array_equal(line, np.concatenate([s["line"] for s in sent]))
    np.testing.assert_array_equal(tool, np.concatenate([s["tool"] for s in sent]))
    assert len(set(line.tolist())) > 3 and tool[-1] == 1


def test_the_spindle_monitor_over_a_broker_feed_teaches_per_block() -> None:
    feed_sim = CentreFeed(0, 3, CentreFeedParams(rate_hz=500.0, block_ms=100.0))
    feed = DriveFeed(parse_broker_url("mqtt://127.0.0.1:1"), "vmc", max_samples=100_000)
    feed.push_meta(feed_sim.meta)
    for i in range(100):  # 10 s
        feed.push(feed_sim.next_block(i))
    p = LivePipeline(source=MqttSource(feed))
    for _ in range(100):
        p.step(50)
    part: Any = p.part("spindle")
    st = part.st.monitor
    lines = st["key_line"][st["key_tool"] >= 0]
    # one segment per G-code line met (not one "line 0" for everything)
    assert len(set(lines.tolist())) > 3 and 0 not in set(lines[1:].tolist())
