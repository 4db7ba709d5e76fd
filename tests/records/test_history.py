"""The history store on a real SQLite file: migrations, filters, paging, acknowledgements,
tool lives, and what a SIGKILL leaves (every write reported committed is there)."""

from __future__ import annotations

import math
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
from alembic import command
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext

from server.records.history import HistoryStore, default_url
from server.records.history.store import (
    alembic_config,
    current_revision,
    head_revision,
    migrate,
    open_engine,
)
from server.records.history.tables import metadata
from server.records.monitor_events import MonitorEvent

ROOT = Path(__file__).resolve().parents[2]


def _store(tmp_path: Path, machine: str = "") -> HistoryStore:
    return HistoryStore(default_url(tmp_path), machine=machine)


def test_an_empty_database_is_migrated_to_the_tables_the_code_uses(tmp_path: Path) -> None:
    engine = open_engine(default_url(tmp_path))
    assert current_revision(engine) is None
    migrate(engine)
    assert current_revision(engine) == head_revision() is not None
    # the migrated schema is the tables of tables.py: nothing for autogenerate to add
    with engine.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn), metadata)
    assert diff == []
    engine.dispose()
    assert (tmp_path / "history" / "cutwatch.sqlite").is_file()


def test_migrating_again_changes_nothing_and_keeps_the_rows(tmp_path: Path) -> None:
    st = _store(tmp_path)
    ev = MonitorEvent("breakage", "feed_hold", 3.0, tool=4)
    st.add_events([ev])
    st.acknowledge(ev.id, "anna")
    st.close()
    for _ in range(2):  # a restarted service migrates at every start
        st = _store(tmp_path)
        assert current_revision(st.engine) == head_revision()
        got = st.event(ev.id)
        assert got is not None and got["acked_by"] == "anna"
        st.close()


def test_the_migrations_go_down_to_nothing_and_up_again(tmp_path: Path) -> None:
    url = default_url(tmp_path)
    st = HistoryStore(url)
    with st.engine.begin() as conn:
        command.downgrade(alembic_config(url, conn), "base")
    names = sqlite3.connect(tmp_path / "history" / "cutwatch.sqlite").execute(
        "select name from sqlite_master where type = 'table'"
    )
    assert {n for (n,) in names} <= {"alembic_version"}
    migrate(st.engine)
    st.add_events([MonitorEvent("collision", "feed_hold", 1.0)])
    assert st.events()[0] == 1
    st.close()


def test_sqlite_runs_in_wal_mode_with_a_full_sync(tmp_path: Path) -> None:
    st = _store(tmp_path)
    with st.engine.connect() as conn:
        assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
        assert conn.exec_driver_sql("PRAGMA synchronous").scalar() == 2  # FULL
    st.close()


def _events(st: HistoryStore) -> list[MonitorEvent]:
    """Seven events received at walls 100, 101, ... (kinds, tools, values varied)."""
    evs = [
        MonitorEvent("breakage", "feed_hold", 1.0, tool=1, value=3.5, limit=2.0, unit="N"),
        MonitorEvent("collision", "feed_hold", 2.0, tool=2),
        MonitorEvent("wear_limit", "alarm", 3.0, tool=1, program="P7", line=40, part=3),
        MonitorEvent("breakage", "feed_hold", 4.0, tool=2),
        MonitorEvent("missing_tool", "feed_hold", 5.0, tool=3),
        MonitorEvent("life_short", "notice", 6.0, tool=1),
        MonitorEvent("breakage", "feed_hold", 7.0, tool=1, machine="mill-2"),
    ]
    for i, ev in enumerate(evs):
        st.add_events([ev], wall=100.0 + i)
    return evs


def test_every_field_of_an_event_comes_back(tmp_path: Path) -> None:
    st = _store(tmp_path, machine="mill-1")
    evs = _events(st)
    total, items = st.events(limit=1000)
    assert total == len(evs)
    back = {d["id"]: d for d in items}
    for ev in evs:
        d = back[ev.id]
        want = ev.as_dict()
        want["machine"] = want["machine"] or "mill-1"  # stamped when it carries none
        assert {k: d[k] for k in want} == want
        assert d["acked"] is False and d["acked_by"] is None
    nan = MonitorEvent("breakage", "feed_hold", 9.0, value=math.nan)
    st.add_events([nan])
    assert st.event(nan.id)["value"] is None  # type: ignore[index]
    st.close()


def test_filters_and_pages_newest_first(tmp_path: Path) -> None:
    st = _store(tmp_path)
    evs = _events(st)
    ids = [e.id for e in evs]
    total, items = st.events()
    assert total == 7 and [d["id"] for d in items] == ids[::-1]
    total, items = st.events(kind="breakage")
    assert total == 3 and [d["id"] for d in items] == [ids[6], ids[3], ids[0]]
    total, items = st.events(tool=1)
    assert total == 4 and [d["id"] for d in items] == [ids[6], ids[5], ids[2], ids[0]]
    total, items = st.events(kind="breakage", tool=2)
    assert total == 1 and items[0]["id"] == ids[3]
    total, items = st.events(since=102.0, until=105.0)  # [since, until)
    assert total == 3 and [d["id"] for d in items] == [ids[4], ids[3], ids[2]]
    st.acknowledge(ids[1], "anna")
    st.acknowledge(ids[4], "ben")
    total, items = st.events(acked=True)
    assert total == 2 and [d["id"] for d in items] == [ids[4], ids[1]]
    assert st.events(acked=False)[0] == 5
    # pages: the total is of all pages; pages tile the list without overlap
    pages = [st.events(limit=3, offset=o) for o in (0, 3, 6, 9)]
    assert [t for t, _ in pages] == [7] * 4
    assert [d["id"] for _, p in pages for d in p] == ids[::-1]
    assert pages[3][1] == []
    with pytest.raises(ValueError, match="kind: expected one of"):
        st.events(kind="chatter")
    st.close()


def test_recent_gives_the_latest_oldest_first(tmp_path: Path) -> None:
    st = _store(tmp_path)
    ids = [e.id for e in _events(st)]
    assert [d["id"] for d in st.recent(3)] == ids[4:]
    st.acknowledge(ids[6], "anna")
    assert [d["id"] for d in st.recent(2, unacked=True)] == ids[4:6]
    st.close()


def test_an_acknowledgement_is_kept_once(tmp_path: Path) -> None:
    st = _store(tmp_path)
    ev = MonitorEvent("collision", "feed_hold", 1.0)
    st.add_events([ev])
    first = st.acknowledge(ev.id, "anna", wall=500.0)
    assert first is not None
    assert (first["acked"], first["acked_by"], first["acked_wall"]) == (True, "anna", 500.0)
    again = st.acknowledge(ev.id, "ben", wall=600.0)
    assert again == first  # idempotent: the first acknowledgement stands
    assert st.acknowledge("0" * 32, "anna") is None  # no such event
    st.add_events([ev])  # the same event again is not stored twice
    assert st.events()[0] == 1
    st.close()


def test_tool_lives_chain_their_wall_times(tmp_path: Path) -> None:
    st = _store(tmp_path, machine="mill-1")
    a = {"tool": 1, "index": 1, "start_t": 0.0, "end_t": 40.0, "cause": "wear_limit",
         "wear_at_change_mm": 0.29, "wear_true_mm": 0.301, "wear_true_share": 1.003}  # fmt: skip
    b = {"tool": 1, "index": 2, "start_t": 40.0, "end_t": 75.5, "cause": "wear_limit",
         "wear_at_change_mm": math.nan}  # fmt: skip
    c = {"tool": 5, "start_t": 90.0, "end_t": 91.0, "cause": "breakage"}
    st.add_tool_changes([a], wall=1000.0)
    st.add_tool_changes([b], wall=1035.0)
    st.add_tool_changes([c], wall=1050.0)
    total, items = st.tool_life()
    assert total == 3
    new, mid, old = items
    assert (old["start_wall"], old["end_wall"]) == (None, 1000.0)  # mounted before we knew
    assert (mid["start_wall"], mid["end_wall"]) == (1000.0, 1035.0)  # mounted at a's change
    assert new["start_wall"] is None  # 90 s is not where the last life ended
    assert old["wear_at_change_mm"] == 0.29 and old["wear_true_mm"] == 0.301
    assert old["wear_true_share"] == 1.003 and new["wear_true_share"] is None
    assert mid["wear_at_change_mm"] is None and mid["index"] == 2
    assert new["machine"] == "mill-1" and new["cause"] == "breakage" and new["index"] is None
    assert st.tool_life(tool=1)[0] == 2
    assert st.tool_life(limit=1, offset=2)[1] == [old]
    with pytest.raises(ValueError, match="cause: expected one of"):
        st.add_tool_changes([{**c, "cause": "boredom"}])
    assert st.tool_life()[0] == 3  # nothing of the refused call was written
    st.close()


_WRITER = """
import sys, time
from server.records.history import HistoryStore, default_url
from server.records.monitor_events import MonitorEvent
st = HistoryStore(default_url(sys.argv[1]))
i = 0
while True:
    ev = MonitorEvent("breakage", "feed_hold", float(i))
    st.add_events([ev])
    if i % 2:
        st.acknowledge(ev.id, "anna")
    print(ev.id, flush=True)  # after the commit: the caller was told it is stored
    i += 1
"""


def test_what_was_reported_stored_survives_a_sigkill(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, "-c", _WRITER, str(tmp_path)],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert proc.stdout is not None
    told = []
    deadline = time.monotonic() + 60
    while len(told) < 40 and time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        told.append(line.strip())
    proc.send_signal(signal.SIGKILL)  # in the middle of its next writes
    rest = proc.stdout.read().split()
    proc.stdout.close()
    proc.wait(10)
    told += rest  # every line it printed was printed after its commit
    assert len(told) >= 40, f"the writer stopped early: {proc.returncode}"
    st = _store(tmp_path)
    total, items = st.events(limit=1000)
    kept = {d["id"]: d for d in items}
    assert set(told) <= set(kept), "an event reported stored is missing"
    assert total <= len(told) + 1  # at most the one in flight when killed
    for i, eid in enumerate(told):
        if i % 2:  # its acknowledgement was committed before it was printed
            assert kept[eid]["acked_by"] == "anna"
    st.close()
