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
    assert "| 500 Hz |" in text and "| missing_tool | spindle |" in text
    assert "| spindle | machine | " in text


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


def test_until_earlier_than_now_is_tomorrow() -> None:
    import datetime as dt

    now = dt.datetime(2026, 12, 7, 22, 21, 30, tzinfo=dt.UTC)
    assert cp.stop_time("06:00", now) == dt.datetime(2026, 12, 8, 6, 0, tzinfo=dt.UTC)
    assert cp.stop_time("23:05", now) == dt.datetime(2026, 12, 7, 23, 5, tzinfo=dt.UTC)
    # this very minute is already past (seconds dropped): the next day's
    assert cp.stop_time("22:21", now) == dt.datetime(2026, 12, 8, 22, 21, tzinfo=dt.UTC)
    for bad in ("6", "25:00", "06:60", "ab:cd"):
        with pytest.raises(ValueError, match="--until"):
            cp.stop_time(bad, now)


def test_until_in_the_past_is_refused_before_any_case_runs_wrongly(tmp_path) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(SystemExit):
        cp.main(["--quick", "--out", str(tmp_path / "x.jsonl"), "--until", "7:99"])
    assert not (tmp_path / "x.jsonl").exists()


def test_a_quick_file_does_not_stand_for_a_full_runs_cases() -> None:
    quick = cp.cases(1, 0.01, 1, 1000)
    full = cp.cases(2, 0.5, 1, 1000)
    rows = [cp.case_fields(c) for c in quick]  # what the quick run wrote (less the results)
    left = cp.remaining(full, rows)
    # the event cases are the same size in both (teach-in and one part): done; the
    # event-free case of seed 1000 was 0.01 h, not 0.5 h: to run, as is seed 1001
    assert [(c.kind, c.seed, c.hours) for c in left] == [("none", 1000, 0.5), ("none", 1001, 0.5)]
    assert cp.remaining(quick, rows) == []
    # a row from before the hours were recorded matches nothing
    old = [{"kind": c.kind, "seed": c.seed} for c in full]
    assert cp.remaining(full, old) == full
