"""The tools the pipeline changes at the flank-wear limit, as the history records them."""

from __future__ import annotations

import numpy as np

from server.pipeline.live_pipeline import LivePipeline
from server.pipeline.wear_passes import VB_LIMIT


def test_each_tool_change_gives_the_worn_tools_life() -> None:
    p = LivePipeline()
    p.set_knob("wear_rate", 5.0)  # 5 min of wear per second: a tool lasts a few seconds
    changes: list[dict[str, object]] = []
    while len(changes) < 2 and p.t < 40.0:
        p.step(125)
        changes += p.take_tool_changes()
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
        est = c["wear_at_change_mm"]
        # the monitor's estimate after the tool's last pass (it lags at this wear rate)
        assert isinstance(est, float) and np.isfinite(est) and est > 0.0
        start = end
