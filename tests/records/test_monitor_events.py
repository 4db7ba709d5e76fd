"""The monitor's event record: round trips, refusals by name, the bounded outbox."""

from __future__ import annotations

import json
import math

import pytest

from server.records.monitor_events import EventOutbox, MonitorEvent


def test_wire_round_trip_keeps_every_field_and_nan() -> None:
    ev = MonitorEvent("breakage", "feed_hold", 12.5, tool=3, program="O1001", line=40, part=7,
                      value=0.8, unit="1", message="tooth broken")  # fmt: skip
    back = MonitorEvent.from_dict(json.loads(json.dumps(ev.to_wire())))
    assert back.id == ev.id and back.line == 40 and back.value == 0.8
    assert math.isnan(back.limit)
    assert ev.to_wire()["limit"] is None


def test_refusals_name_the_field() -> None:
    with pytest.raises(ValueError, match="kind"):
        MonitorEvent("crash", "alarm", 0.0)
    with pytest.raises(ValueError, match="action"):
        MonitorEvent("collision", "stop", 0.0)
    with pytest.raises(ValueError, match="color"):
        MonitorEvent.from_dict({"kind": "collision", "action": "alarm", "t": 1.0, "color": "red"})
    with pytest.raises(ValueError, match="version"):
        MonitorEvent.from_dict({"version": 99, "kind": "collision", "action": "alarm", "t": 1.0})


def test_outbox_is_bounded_and_counts_what_it_drops() -> None:
    box = EventOutbox(maxlen=3)
    for i in range(5):
        box.put(MonitorEvent("collision", "alarm", float(i)))
    taken = box.take()
    assert [e.t for e in taken] == [2.0, 3.0, 4.0] and box.dropped == 2 and len(box) == 0
