"""The fleet's trust in its messages (issue 27, finding 2), in process: a row is its
topic's machine, every message is checked by its model, and a row's link comes from the
fleet's own configuration (``Links``), never from a message alone."""

from __future__ import annotations

import json

import pytest

from server.errors import CutwatchError
from server.records.drive_wire import encode_estimates
from server.service.fleet import FleetState, Links

ORIGINS = ("http://worker-0.plant:8200", "https://mill-7.shop.test")


def test_a_row_link_is_the_template_or_an_allowed_origin() -> None:
    tpl = Links.parse("http://plant.lan/m/{machine}/", ())
    assert tpl.link("mill-1", "javascript:alert(1)") == "http://plant.lan/m/mill-1/"
    links = Links.parse(None, ORIGINS)
    ok = "http://worker-0.plant:8200/m/mill-1/"
    assert links.link("mill-1", ok) == ok
    assert links.link("mill-1", "https://mill-7.shop.test:443/") == "https://mill-7.shop.test:443/"
    for bad in ("javascript:alert(document.domain)", "JavaScript://worker-0.plant:8200/%0aalert(1)",
                "https://worker-0.plant:8200/m/", "http://worker-0.plant:8201/m/",
                "http://evil@worker-0.plant:8200/", "http://evil.example/", "data:text/html,x",
                "//worker-0.plant:8200/m/", "http://worker-0.plant:8200/m/\n", None):  # fmt: skip
        assert links.link("mill-1", bad) is None, bad
    assert Links().link("mill-1", ok) is None  # nothing configured: no link


def test_bad_link_options_are_named() -> None:
    with pytest.raises(CutwatchError, match=r"--machine-url: expected .*\{machine\}.*got"):
        Links.parse("http://plant.lan/m/", ())
    with pytest.raises(CutwatchError, match="--machine-url"):
        Links.parse("javascript:{machine}", ())
    for bad in ("ftp://a.b", "http://a.b/path", "a.b:80", "http://u@a.b"):
        with pytest.raises(CutwatchError, match=rf"--dashboard-origin: expected .*got '{bad}'"):
            Links.parse(None, [bad])


def test_a_row_is_its_topics_machine_and_its_message_is_checked() -> None:
    s = FleetState(30.0, Links.parse(None, ORIGINS))
    good = {"wall": 1.0, "force": {"level": 3}, "alarms": [],
            "dashboard": "http://worker-0.plant:8200/m/mill-1/"}  # fmt: skip
    assert s.update("cutwatch/mill-1/estimates", encode_estimates("mill-1", good)) == "mill-1"
    refused = [
        ("cutwatch/mill-9/estimates", encode_estimates("mill-7", good)),  # another machine
        ("cutwatch/mill-2/estimates", encode_estimates("mill-2", {"force": {"level": "12"}})),
        ("cutwatch/mill-2/estimates", encode_estimates("mill-2", {"alarms": "worn"})),
        ("cutwatch/mill-2/estimates", encode_estimates("mill-2", {"dashboard": 7})),
        ("cutwatch/a b/estimates", encode_estimates("a b", good)),  # not a machine name
        ("cutwatch/mill-2/x/estimates", encode_estimates("mill-2", good)),
        ("cutwatch/mill-2/estimates", b'{"schema": "cutwatch.estimates", "version": 2}'),
        ("cutwatch/mill-2/estimates", b"[]"),
    ]
    for topic, payload in refused:
        assert s.update(topic, payload) is None, payload
    assert s.malformed == len(refused)
    rows = s.rows()
    assert [r.machine for r in rows] == ["mill-1"]
    assert rows[0].force == 3.0 and rows[0].dashboard == good["dashboard"]
    ev = {"schema": "cutwatch.event", "version": 1, "id": "e1", "kind": "breakage",
          "action": "feed_hold", "t": 1.0, "tool": 1, "program": "", "line": 0, "part": -1,
          "value": None, "limit": None, "unit": "", "message": "m",
          "machine": "mill-7"}  # fmt: skip
    assert s.event("cutwatch/mill-1/events", json.dumps(ev).encode()) is None
    assert s.event("cutwatch/mill-1/events", json.dumps({**ev, "machine": "mill-1"}).encode())
    assert s.event("cutwatch/mill-3/events", json.dumps({**ev, "machine": ""}).encode())
    assert [r.machine for r in s.rows()] == ["mill-1", "mill-3"]
    assert s.rows()[0].event is not None and s.malformed == len(refused) + 1


def test_nothing_waiting_clears_only_events_taken_the_grace_before_it() -> None:
    # the acknowledgement rule on the fleet's own clock, given: an estimate saying nothing
    # waits (monitor.unacked 0) was maybe built before an event raised just ahead of it,
    # so it clears only the events taken ACK_GRACE_S before it or earlier (through a real
    # broker, test_fleet judges the clearing a grace later; "just after" is judged here,
    # where a loaded box's pause cannot move the times)
    from server.records.monitor_events import DEFAULT_ACTIONS, MonitorEvent
    from server.service.fleet import ACK_GRACE_S

    s = FleetState(30.0)
    ev = MonitorEvent(kind="breakage", action=DEFAULT_ACTIONS["breakage"], t=12.5, tool=3,
                      machine="mill-4", message="breakage on T3")  # fmt: skip
    quiet = encode_estimates("mill-4", {"wall": 1.0, "force": {"level": 3}, "alarms": [],
                             "monitor": {"state": "watching", "unacked": 0}})  # fmt: skip
    t0 = 1000.0
    assert s.event("cutwatch/mill-4/events", json.dumps(ev.to_wire()).encode(), now=t0)
    for dt in (0.0, 0.5 * ACK_GRACE_S, ACK_GRACE_S - 1e-6):  # arriving just after: waits
        assert s.update("cutwatch/mill-4/estimates", quiet, now=t0 + dt) == "mill-4"
        row = s.row("mill-4", now=t0 + dt)
        assert row.monitor == "alarm" and row.event is not None and row.event.id == ev.id, dt
    assert s.update("cutwatch/mill-4/estimates", quiet, now=t0 + ACK_GRACE_S) == "mill-4"
    row = s.row("mill-4", now=t0 + ACK_GRACE_S)
    assert row.monitor == "watching" and row.event is None and row.unacked == 0


def test_a_fleet_off_loopback_needs_a_token(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from server.cli.main import main

    for var in ("CUTWATCH_TOKEN", "CUTWATCH_VIEW_TOKEN"):
        monkeypatch.delenv(var, raising=False)
    args = ["fleet", "--broker", "mqtt://127.0.0.1:1", "--host", "0.0.0.0", "--port", "9"]
    assert main(args) == 2
    assert "requires a bearer token: set CUTWATCH_TOKEN" in capsys.readouterr().err
    monkeypatch.setenv("CUTWATCH_TOKEN", "short")
    assert main(args) == 2
    assert "CUTWATCH_TOKEN" in capsys.readouterr().err
    assert main([*args[:3], "--dashboard-origin", "ftp://x"]) == 2
    assert "--dashboard-origin: expected http(s)://host[:port]" in capsys.readouterr().err
