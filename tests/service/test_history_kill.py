"""The kept history survives a killed service: a real ``cutwatch serve`` on a data directory
records events and tool lives, an event is acknowledged over REST, the process is killed
(SIGKILL, then SIGTERM) and started again on the same directory: every event, tool life
and acknowledgement the service had answered with is there, and the snapshot shows the
latest events again.

The events are the service's own: a tooth breakage injected into the simulated part
program (``POST /api/control`` inject) and found by the process monitor (a feed hold), the
tool-life monitor's ``wear_limit`` and ``life_short`` alarms on the default scenario's
wearing tool, and the tool lives of its changes at the flank-wear limit.
"""

from __future__ import annotations

import json
import signal
import time
import urllib.request
from pathlib import Path
from typing import Any

import pytest
from _live import ServeProcess, serve_process

pytestmark = pytest.mark.slow

#: simulated seconds per wall second (the first wear alarm comes at ~60 s of simulated time)
SPEED = "50"


def _get(sp: ServeProcess, path: str) -> Any:
    with urllib.request.urlopen(sp.base + path, timeout=10) as r:
        return json.loads(r.read())


def _send(sp: ServeProcess, method: str, path: str, body: Any = None) -> dict[str, Any]:
    data = json.dumps(body).encode() if body is not None else b""
    req = urllib.request.Request(
        sp.base + path,
        data=data,
        method=method,
        headers={"Content-Type": "application/json"} if data else {},
    )
    with urllib.request.urlopen(req, timeout=10) as r:
        out: dict[str, Any] = json.loads(r.read())
    return out


def _ack(sp: ServeProcess, event_id: str, by: str | None = None) -> dict[str, Any]:
    return _send(sp, "POST", f"/api/events/{event_id}/ack", {"by": by} if by else None)


def _breakage(sp: ServeProcess, timeout: float = 300.0) -> dict[str, Any]:
    """Teach one part, inject a tooth breakage into a part the monitor watches (the
    middle of its first cut); the event kept."""
    _send(sp, "PATCH", "/api/params", {"teach_parts": 1})
    deadline = time.monotonic() + timeout
    while (st := _get(sp, "/api/snapshot")["status"])["state"] != "watching":
        assert time.monotonic() < deadline, f"the monitor does not watch: {st}"
        time.sleep(0.3)
    part = int(st["part"]) + 1
    _send(sp, "POST", "/api/control", {"action": "inject", "kind": "breakage", "at_part": part})
    while time.monotonic() < deadline:
        found = _get(sp, "/api/events?kind=breakage")["items"]
        if found:
            assert found[0]["action"] == "feed_hold" and found[0]["part"] == part
            return dict(found[0])
        time.sleep(0.3)
    snap = _get(sp, "/api/snapshot")
    raise AssertionError(f"the breakage injected into part {part} was not kept: {snap['status']}")


def _wait_for(sp: ServeProcess, events: int, lives: int, timeout: float = 240.0) -> None:
    """Until the history holds ``events`` events and ``lives`` tool lives more than now."""
    e0 = _get(sp, "/api/events?limit=1")["total"]
    l0 = _get(sp, "/api/tool-life?limit=1")["total"]
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        e = _get(sp, "/api/events?limit=1")["total"]
        lv = _get(sp, "/api/tool-life?limit=1")["total"]
        if e >= e0 + events and lv >= l0 + lives:
            return
        time.sleep(0.5)
    raise AssertionError(f"the service kept {e - e0} events and {lv - l0} tool lives in time")


def _everything(sp: ServeProcess) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    events = _get(sp, "/api/events?limit=1000")
    lives = _get(sp, "/api/tool-life?limit=1000")
    assert events["total"] == len(events["items"]) and lives["total"] == len(lives["items"])
    return {e["id"]: e for e in events["items"]}, lives["items"]


def _key(life: dict[str, Any]) -> tuple[Any, ...]:
    return (life["index"], life["start_t"], life["end_t"], life["end_wall"])


def _check_kept(
    sp: ServeProcess, seen: dict[str, Any], lives: list[dict[str, Any]]
) -> dict[str, Any]:
    """Every event (with its acknowledgement) and tool life the service answered with
    before it was stopped is there after the restart, unchanged."""
    now, now_lives = _everything(sp)
    missing = sorted(set(seen) - set(now))
    assert missing == [], f"events lost: {missing}"
    for eid, ev in seen.items():
        assert now[eid] == ev, f"event {eid} changed over the restart"
    assert {_key(x) for x in lives} <= {_key(x) for x in now_lives}, "tool lives lost"
    # the restarted service shows the latest events again (the in-memory list reloaded),
    # and an alarm not acknowledged before the restart still holds the status at alarm
    snap = _get(sp, "/api/snapshot")
    shown = {e["id"]: e for e in snap["events"]}
    newest = sorted(seen.values(), key=lambda e: e["received_wall"])[-5:]
    for ev in newest:
        assert ev["id"] in shown, "a kept event is not in the snapshot after the restart"
        assert shown[ev["id"]]["acked"] == ev["acked"]
    open_alarms = [e for e in seen.values() if not e["acked"] and e["action"] != "notice"]
    assert open_alarms, "the test expects an alarm left unacknowledged"
    assert snap["status"]["state"] == "alarm"
    assert snap["status"]["unacked"] >= sum(not e["acked"] for e in seen.values())
    return now


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_events_acks_and_tool_lives_survive_a_killed_service(
    tmp_path: Path, sig: signal.Signals
) -> None:
    data = str(tmp_path / "data")
    args = ("--scenario", "default", "--data-dir", data, "--speed", SPEED)
    with serve_process(*args) as sp:
        broken = _breakage(sp)
        acked = _ack(sp, broken["id"])
        assert acked["acked"] is True and acked["acked_by"] == "operator"
        _wait_for(sp, events=2, lives=1)  # wear alarms and a tool change after the ack
        seen, lives = _everything(sp)
        assert seen[broken["id"]]["acked_wall"] == acked["acked_wall"]
        assert {"breakage", "wear_limit"} <= {e["kind"] for e in seen.values()}
        code = sp.stop(sig)
        # uvicorn shuts down on SIGTERM, then raises the signal again: -15 either way
        assert code == -sig, sp.stderr[-2000:]
    assert (Path(data) / "history" / "cutwatch.sqlite").is_file()
    with serve_process(*args) as sp:
        now = _check_kept(sp, seen, lives)
        # the restarted service goes on recording into the same history, and an event
        # acknowledged after the restart is kept over the next stop as well
        _wait_for(sp, events=1, lives=0)
        later, _ = _everything(sp)
        fresh = max(later.values(), key=lambda e: e["received_wall"])
        assert fresh["id"] not in now
        again = _ack(sp, fresh["id"], by="night shift")
        assert again["acked_by"] == "night shift"
        assert _ack(sp, broken["id"], by="someone else") == now[broken["id"]]  # idempotent
        seen, lives = _everything(sp)
        sp.stop(sig)
    with serve_process(*args) as sp:
        _check_kept(sp, seen, lives)
