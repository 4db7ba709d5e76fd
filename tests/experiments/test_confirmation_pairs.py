"""`python -m server.experiments.confirmation_pairs --quick`: the paired comparison's contract.

One short event-free case and one event of each kind on the machining centre, each
watched at 5 kHz, 1 kHz and 500 Hz by the monitor on the rule in samples (``before``)
and on the physical rule (``after``): the same simulation reaches both, so a difference
is the rule's. The full run's size and numbers are in docs/monitoring.md.
"""

from __future__ import annotations

import json
from typing import Any

import pytest

from common.event_kinds import ProcessEventKind
from server.experiments import confirmation_pairs as cp


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[dict[str, Any]], str]:
    out = tmp_path_factory.mktemp("pairs") / "pairs.jsonl"
    assert cp.main(["--quick", "--out", str(out), "--workers", "2"]) == 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    return rows, cp.summary(rows)


def test_every_case_is_watched_on_both_rules_at_every_rate(quick) -> None:  # type: ignore[no-untyped-def]
    rows, text = quick
    assert sorted(r["kind"] for r in rows) == sorted(["none", *map(str, ProcessEventKind)])
    for r in rows:
        for rate in cp.RATES:
            assert set(r[f"{rate:g}"]) == set(cp.VARIANTS)
    free = next(r for r in rows if r["kind"] == "none")
    assert free["watched_h"] >= 0.01
    assert "500 Hz before -> after" in text and "| missing_tool | spindle |" in text


def test_a_lost_tool_is_confirmed_over_30_ms_after_and_one_revolution_before(quick) -> None:  # type: ignore[no-untyped-def]
    rows, _ = quick
    (r,) = [r for r in rows if r["kind"] == ProcessEventKind.MISSING_TOOL]
    checked = 0
    for rate in cp.RATES:
        for sig in cp.SETS:
            b, a = (r[f"{rate:g}"][v][sig] for v in cp.VARIANTS)
            if not (a["detected"] and b["detected"]):
                continue
            checked += 1
            # the same event: the later rule alarms no earlier, and 30 ms after at least
            assert a["delay_samples"] >= b["delay_samples"]
            assert a["delay_s"] >= 0.030 - 1.0 / rate
    assert checked >= 3


def test_a_collision_is_confirmed_alike_on_both_rules(quick) -> None:  # type: ignore[no-untyped-def]
    # 0.4 ms and at least 2 samples is 2 samples at every rate: the rule did not change it
    rows, _ = quick
    (r,) = [r for r in rows if r["kind"] == ProcessEventKind.COLLISION]
    for rate in cp.RATES:
        for sig in cp.SETS:
            b, a = (r[f"{rate:g}"][v][sig] for v in cp.VARIANTS)
            assert a["detected"] == b["detected"]
            assert a.get("delay_samples") == b.get("delay_samples")
