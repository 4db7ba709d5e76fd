"""Issue 31 phase 2: the machining centre on the dashboard, in headless Chromium.

A real ``cutwatch serve --scenario machining-centre`` (a child process, its data area in
a temporary directory): the page shows the one machine: the strip with the CNC's tool
(a T-number) and program O2001, the spindle's power chart and the axes' process-force
charts (X, Y, Z); the stage's observers are listed as not running, with the reason. The
monitor on the spindle's cutting power teaches one part per block (``teach_parts`` 1),
then watches; the events it has raised by then are acknowledged (one part's teach-in
leaves a false alarm, docs/machining-centre.md), a breakage is injected into the next
part's first cut (``POST /api/control``), and the page shows it: the strip in alarm with
the event's words, a red marker on the spindle's chart at the event's time. Screenshot:
``out/centre-dashboard.png`` (docs/img keeps a copy).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
import pytest
from _browser import MARKS, chromium_page, wait_for
from _live import serve_process

pytestmark = [*MARKS, pytest.mark.slow]

#: simulated seconds until the monitor watches: one part (32 s) taught, at 5x on a busy box
WATCH_TIMEOUT_S = 150.0
#: the injected part's first cut comes within two parts (64 s) of simulated time
EVENT_TIMEOUT_S = 120.0


def get(base: str, path: str, **params: Any) -> Any:
    r = httpx.get(f"{base}{path}", params=params, timeout=30)
    assert r.status_code == 200, r.text
    return r.json()


def post(base: str, path: str, body: dict[str, Any] | None = None) -> Any:
    r = httpx.post(f"{base}{path}", json=body, timeout=30)
    assert r.status_code == 200, r.text
    return r.json()


def test_the_one_machine_and_a_breakage_on_its_spindle(tmp_path: Path) -> None:
    out = Path("out")
    out.mkdir(exist_ok=True)
    with (
        serve_process("--scenario", "machining-centre", "--data-dir", str(tmp_path / "d")) as sp,
        chromium_page(1280, 1100) as (page, errors),
    ):
        base = sp.base
        r = httpx.patch(f"{base}/api/params", json={"teach_parts": 1}, timeout=30)
        assert r.status_code == 200, r.text
        page.goto(f"{base}/")
        page.wait_for_selector("#conn[data-state=up]", timeout=30000)
        post(base, "/api/control", {"action": "speed", "value": 5})

        # the one machine: its axes and spindle, the stage's observers saying why not
        m = get(base, "/api/machine")
        assert [a["name"] for a in m["axes"]] == ["X", "Y", "Z"] and m["spindle"]
        parts = {p["name"]: p for p in m["parts"]}
        assert not parts["stage"]["running"] and parts["stage"]["reason"]
        page.wait_for_selector("#chart-spindle", timeout=30000)
        for a in "XYZ":
            assert page.locator(f"#chart-axis-{a}-force").count() == 1
        wait_for(lambda: page.inner_text("#strip-where").startswith("program O2001"), 60)
        # the tool: none in the spindle (a dash) until the program's first tool change
        # (and again, for a block, while one is made), then a T-number
        wait_for(lambda: page.inner_text("#strip-tool").startswith("T"), 60)
        assert not page.is_visible("#strip-weargroup")  # no wear model on the centre yet

        # taught (watching, or in alarm already); what it raised so far acknowledged
        def state() -> str:
            return str(page.get_attribute("#strip", "data-state"))

        wait_for(lambda: state() in ("watching", "alarm"), timeout=WATCH_TIMEOUT_S)

        def acknowledged() -> bool:
            for ev in get(base, "/api/events", acked="false")["items"]:
                post(base, f"/api/events/{ev['id']}/ack")
            return state() == "watching"

        wait_for(acknowledged, timeout=30)
        scheduled = post(base, "/api/control", {"action": "inject", "kind": "breakage"})
        line = scheduled["scheduled"]["line"]

        def raised() -> list[dict[str, Any]]:
            items = get(base, "/api/events", acked="false")["items"]
            return [e for e in items if e["line"] == line]

        wait_for(raised, timeout=EVENT_TIMEOUT_S)
        # the strip: alarm, naming one of them in the detector's words (the injection may
        # raise more than one event at its line, and the strip shows the newest: the set
        # is read again while waiting, not frozen at the first event)
        wait_for(lambda: page.get_attribute("#strip", "data-state") == "alarm")
        wait_for(lambda: page.inner_text("#strip-message") in {e["message"] for e in raised()})
        assert "T1 at N60 (program O2001)" in page.inner_text("#strip-message")
        ev_ids = {e["id"] for e in raised()}

        # the spindle's chart: a marker at the event
        def marked() -> set[str]:
            return set((page.get_attribute("#chart-spindle", "data-marker-ids") or "").split(","))

        wait_for(lambda: ev_ids & marked())
        page.screenshot(path=str(out / "centre-dashboard.png"))
        assert errors == []
