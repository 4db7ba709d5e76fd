"""The machining centre's CNC trace as a measured log: written with its machine
description and read back by the log reader as the same machine (the recorded traces a
plant bench replays, issue 32)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from machine.centre import signals
from machine.centre.sim import MachiningCentre
from machine.centre.trace import CncTrace, TraceParams
from server.records.measured_log import load_log, write_log


def test_a_trace_written_as_a_log_reads_back_as_the_machine(tmp_path: Path) -> None:
    m = MachiningCentre()
    st = m.initial_state(seed=1)
    trace = CncTrace(TraceParams(500.0, "mean"), m.sample_time)
    ts = trace.initial_state()
    parts = []
    for _ in range(6):
        st, rec = m.step(st, 5000)
        ts, tr = trace.export(ts, rec)
        parts.append(signals.columns(tr))
    cols = {c: np.concatenate([p[c] for p in parts]) for c in parts[0]}
    side = {**signals.description_dict(m.params, 500.0), "program": m.program.name}
    path = tmp_path / "centre.csv"
    write_log(path, cols, side)
    log = load_log(path)
    d = log.description
    assert d is not None and d.axis_names == ("X", "Y", "Z")
    assert d.axis("X").kind == "two_inertia" and d.axis("Y").kind == "rigid"
    assert d.spindle is not None and set(d.spindle.signals) == {
        "speed", "speed_cmd", "current", "power",
    }  # fmt: skip
    assert log.sample_time == pytest.approx(0.002, rel=1e-12)
    for c in ("X_q_l", "Z_i_m", "S_power", "tool", "line"):
        assert np.array_equal(log.columns[c], cols[c]), c
    assert log.sidecar["program"] == "O2001"
