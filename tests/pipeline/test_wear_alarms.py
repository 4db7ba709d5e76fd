"""The tool-life monitor's alarms as events: once per tool, not every block; the live
pipeline raises them from its wear estimate (never the true wear)."""

from __future__ import annotations

import math

from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.wear_alarms import LIFE_ALARM_MIN, WEAR_ALARM_SHARE, WearAlarms
from server.pipeline.wear_passes import VB_LIMIT

IDS: dict[str, object] = {"tool": 4, "program": "P7", "line": 120, "part": 9}


def test_each_alarm_once_per_tool() -> None:
    a = WearAlarms()
    worn = WEAR_ALARM_SHARE * VB_LIMIT + 0.001
    assert a.check(1.0, 0, 0.1, VB_LIMIT, 10.0, IDS) == []
    first = a.check(2.0, 0, worn, VB_LIMIT, 10.0, IDS)
    assert [e.kind for e in first] == ["wear_limit"]
    e = first[0]
    assert (e.action, e.t, e.value, e.limit, e.unit) == (
        "alarm", 2.0, worn, WEAR_ALARM_SHARE * VB_LIMIT, "mm",
    )  # fmt: skip
    assert (e.tool, e.program, e.line, e.part) == (4, "P7", 120, 9)
    assert e.machine == ""
    share = round(100 * worn / VB_LIMIT)
    assert e.message == (
        f"tool 4: flank wear {worn:.3f} mm, {share} % of its limit {VB_LIMIT:.3f} mm "
        f"(alarm at {100 * WEAR_ALARM_SHARE:.0f} %): change the tool"
    )
    # still worn on the next blocks: nothing more for this tool
    assert a.check(3.0, 0, worn + 0.01, VB_LIMIT, 10.0, IDS) == []
    short = a.check(4.0, 0, worn, VB_LIMIT, LIFE_ALARM_MIN - 0.5, IDS)
    assert [(e.kind, e.action, e.unit) for e in short] == [("life_short", "notice", "min")]
    assert a.check(5.0, 0, worn, VB_LIMIT, 0.1, IDS) == []
    # the next tool (index 1) raises them again
    again = a.check(6.0, 1, worn, VB_LIMIT, 0.1, IDS)
    assert sorted(e.kind for e in again) == ["life_short", "wear_limit"]
    assert len({e.id for e in [*first, *short, *again]}) == 4


def test_no_estimate_no_alarm() -> None:
    assert WearAlarms().check(1.0, 0, math.nan, VB_LIMIT, math.nan, {}) == []


def test_the_live_pipeline_raises_wear_limit_once_from_its_estimate() -> None:
    # the default scenario's first tool: its estimated wear passes 90 % of the limit at
    # ~60 s (measured), the true wear reaches the limit and the tool is changed at ~64 s
    p = LivePipeline("default")
    events = []
    vb_at_event = []
    for _ in range(int(70.0 / (125 * p.sample_time))):
        p.step(125)
        got = p.take_events()
        if got and p.tool is not None:
            vb_at_event.append(p.tool.state.vb_est)
        events += got
    assert p.tools_changed == 1
    wear = [e for e in events if e.kind == "wear_limit"]
    assert len(wear) == 1, [e.message for e in events]
    e = wear[0]
    assert e.value >= WEAR_ALARM_SHARE * VB_LIMIT and e.limit == WEAR_ALARM_SHARE * VB_LIMIT
    assert e.value == vb_at_event[0]  # the estimate, not the truth
    assert 0 < e.t <= p.t
    # issue 28: the event names the wear model's own first tool, not the milling
    # machine's tool, program, line or part; the strip's wear fields name the next tool
    assert (e.tool, e.program, e.line, e.part) == (1, "", 0, -1)
    assert f"{VB_LIMIT:.3f} mm" in e.message
    st = p.monitor_status()
    assert (st["wear_tool"], st["wear_limit_mm"], st["wear_alarm_share"]) == (
        2, VB_LIMIT, WEAR_ALARM_SHARE,
    )  # fmt: skip
    assert st["wear_of"] and st["tool"] in (1, 2)
