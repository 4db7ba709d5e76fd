"""The plant of machining centres (issue 32 item 3): a recorded trace replayed by one
``cutwatch feed`` for every machine, through real ``cutwatch worker`` processes, a real
Mosquitto and a real ``cutwatch fleet`` (``cutwatch bench fleet --centres``)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from server.experiments.benchmarks._plant_centres import EARLY_S, MATCH_S, record, score


def test_score_counts_each_true_event_once_per_machine() -> None:
    truth = [{"kind": "breakage", "t": 100.0, "line": 60},
             {"kind": "collision", "t": 200.0, "line": 150},
             {"kind": "missing_tool", "t": 295.0, "line": 60}]  # fmt: skip
    raised = {
        "a": [{"kind": "breakage", "t": 100.4, "line": 60},
              {"kind": "breakage", "t": 100.5, "line": 60},
              {"kind": "collision", "t": 200.1, "line": 150}],
        # a worker that joined 12 s late: its clock 12 s behind the log's
        "b": [{"kind": "collision", "t": 188.0, "line": 150},
              {"kind": "breakage", "t": 99.0, "line": 70},
              {"kind": "missing_tool", "t": 250.0, "line": 60}],
    }  # fmt: skip
    # the missing tool at 295 s is not due: the feed reached 300 s, less MATCH_S
    sc = score(truth, raised, t_end=300.0)
    assert MATCH_S == 10.0 and EARLY_S == 25.0
    assert sc["events_due"] == 4 and sc["found"] == 3
    # a: the second breakage; b: a breakage on another line, a missing tool
    assert sc["false"] == 3 and sc["detection"] == 0.75


def test_a_recorded_trace_is_a_described_centre_log_with_its_truth(tmp_path: Path) -> None:
    from server.records.measured_log import load_log

    truth = record(tmp_path / "c.csv", seconds=6.0, rate_hz=500.0)
    log = load_log(tmp_path / "c.csv")
    assert log.machine.sample_time == pytest.approx(2e-3)
    assert log.machine.axis_names == ("X", "Y", "Z") and log.machine.spindle is not None
    assert set(log.machine.identities) >= {"program", "tool", "line", "override"}
    assert log.n == pytest.approx(6.0 * 500, abs=50)
    saved = json.loads((tmp_path / "c.events.json").read_text())
    assert saved == json.loads(json.dumps(truth)) and saved["teach_parts"] == 5
    # no event in the teach-in parts (the first part of the default program is ~30 s)
    assert saved["events"] == []


@pytest.mark.skipif(shutil.which("mosquitto") is None and not Path("/usr/sbin/mosquitto").exists(),
                    reason="needs Debian's mosquitto (make system-deps)")  # fmt: skip
def test_a_small_plant_of_centres_runs_every_row_ok() -> None:
    from server.experiments.benchmarks.bench_fleet import measure

    out = measure(repeats=1, quick=True, machines=2, workers=1, seconds=10.0, centres=True)
    assert "machining centres at 500 Hz" in str(out["configuration"])
    assert out["fleet.rows"] == 2 and out["fleet.ok_at_end"] == 2
    assert out["workers.dropped_samples"] == 0
    assert float(out["latency.samples"]) > 0  # type: ignore[arg-type]
    assert 0 < float(out["latency_ms.p50"]) < 10_000  # type: ignore[arg-type]
    assert float(out["cpu_pct_one_core.workers_per_machine"]) > 0  # type: ignore[arg-type]
    # scored against the trace's truth: nothing due within a window this short (the
    # monitors teach on the first 5 parts), and no event raised while they teach
    assert out["monitor.events_due"] == 0 and out["monitor.false"] == 0
