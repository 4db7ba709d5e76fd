"""The tools the pipeline changes at the flank-wear limit, as the history records them."""

from __future__ import annotations

import numpy as np

from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.wear_passes import VB_LIMIT


def test_each_tool_change_gives_the_worn_tools_life() -> None:
    p = LivePipeline("default")
    p.set_knob("wear_rate", 5.0)  # 5 min of wear per second: a tool lasts a few seconds
    changes: list[dict[str, object]] = []
    while len(changes) < 2 and p.t < 40.0:
        p.step(125)
        # the stage's wearing tool (its place in the run as index); not the part program's
        changes += [c for c in p.take_tool_changes() if c["index"] is not None]
    assert p.take_tool_changes() == []  # taken: gone
    assert len(changes) == p.tools_changed >= 2
    start = 0.0
    for i, c in enumerate(changes, start=1):
        assert c["cause"] == "wear_limit"
        assert c["index"] == i
        # the CNC's tool number when the part program gives one, else the place in the run
        assert isinstance(c["tool"], int) and c["tool"] > 0
        assert c["start_t"] == start  # mounted at the previous change (the first: at 0)
        end = c["end_t"]
        assert isinstance(end, float) and end > start
        true = c["wear_true_mm"]
        assert isinstance(true, float) and VB_LIMIT <= true < VB_LIMIT + 0.1
        assert c["wear_true_share"] == true / VB_LIMIT
        est = c["wear_at_change_mm"]
        # the monitor's estimate after the tool's last pass (it lags at this wear rate)
        assert isinstance(est, float) and np.isfinite(est) and est > 0.0
        start = end


def test_a_part_programs_tool_broken_and_changed_is_a_tool_life() -> None:
    p = LivePipeline("default")
    p.set_knob("teach_parts", 1.0)  # watch from the second part on
    p.set_knob("wear_rate", 0.05)  # the stage's wearing tool lasts: only the part's change
    while p.monitor_status()["state"] == "teaching":
        p.step(125)
        assert p.t < 120.0, "the teach-in did not end"
    assert p.take_tool_changes() == []
    p.inject("breakage")
    events, changes = [], []
    while not changes and p.t < 200.0:
        p.step(125)
        events += p.take_events()
        changes += p.take_tool_changes()
    broken = [e for e in events if e.kind == "breakage"]
    assert broken, "the injected breakage was not found"
    (c,) = changes  # the operator changes the broken tool before the next part
    assert c["cause"] == "breakage" and c["tool"] == broken[0].tool and c["index"] is None
    assert c["start_t"] == 0.0  # the program's first instance of that tool
    end = c["end_t"]
    assert isinstance(end, float) and broken[0].t < end <= p.t
    share = c["wear_true_share"]
    assert isinstance(share, float) and 0.0 < share < 1.0  # not worn out: broken
    assert c["wear_at_change_mm"] is None  # the part's wear has no estimate
