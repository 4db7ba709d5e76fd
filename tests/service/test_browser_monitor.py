"""A breakage on the dashboard and on the fleet page, end to end, in headless Chromium.

A real ``cutwatch serve`` (a child process, tokens for the two roles, its data area in a
temporary directory) publishes on a real Mosquitto; the fleet page's app subscribes to
it. A breakage is injected through ``POST /api/control``; the dashboard must show it in
the status strip (alarm), the event timeline (a row waiting for an acknowledgement) and
on the process monitor's chart (a red marker drawn at the event's time); a viewer sees
the Acknowledge button disabled and why; the fleet page's row of the machine shows the
alarm and the breakage; the operator acknowledges it and the strip leaves alarm.
Screenshots: ``out/monitoring-alarm.png`` (the dashboard in alarm; docs/img keeps a copy)
and ``out/fleet-alarm.png``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
import pytest
from _broker import broker
from _browser import MARKS, chromium_page, log_in, wait_for
from _live import OPERATOR, VIEWER, serve_fleet, serve_process

from server.pipeline.broker import parse_broker_url
from server.service.fleet import Links

pytestmark = [*MARKS, pytest.mark.slow]

MACHINE = "mill-7"
#: the address the machine's estimates give for its dashboard (the fleet page's link)
PUBLIC_URL = "http://mill-7.shop.test:8000/"
#: the marker colour of an event waiting for an acknowledgement (web/monitor.js)
MARKER_RGB = (224, 0, 0)
#: how long the monitor may teach before it watches (simulated parts at the service's speed)
TEACH_TIMEOUT_S = 240.0
#: the part from which every block of the program has been taught (teach_parts 1)
WATCH_FROM_PART = 2
#: a part of the default program takes ~15 s of simulated time; at 1x, with a busy box
PART_TIMEOUT_S = 60.0

#: in the page: the marker pixels (exactly MARKER_RGB) in the canvas column of each marker
#: the chart says it drew, read in one go with the attributes (no redraw in between)
MARKER_PIXELS = """([sel, rgb]) => {
  const el = document.querySelector(sel);
  const c = el.querySelector('canvas');
  const xs = (el.dataset.markerPx || '').split(',').filter(Boolean).map(Number);
  const ids = (el.dataset.markerIds || '').split(',').filter(Boolean);
  const ctx = c.getContext('2d');
  const counts = xs.map((x) => {
    const d = ctx.getImageData(x, 0, 1, c.height).data;
    let n = 0;
    for (let i = 0; i < d.length; i += 4) {
      if (d[i] === rgb[0] && d[i + 1] === rgb[1] && d[i + 2] === rgb[2]) n++;
    }
    return n;
  });
  return { ids, counts, height: c.height };
}"""


#: a viewer's credentials for the REST reads
VIEW = {"Authorization": f"Bearer {VIEWER}"}


def service_part(base: str) -> int:
    """The part the service's monitor is at (its snapshot's status)."""
    return int(httpx.get(f"{base}/api/snapshot", headers=VIEW).json()["status"]["part"])


def strip_state(page: Any) -> str:
    return str(page.get_attribute("#strip", "data-state"))


def operator_post(base: str, path: str, body: dict[str, Any]) -> httpx.Response:
    return httpx.post(
        f"{base}{path}", json=body, headers={"Authorization": f"Bearer {OPERATOR}"}, timeout=10
    )


def test_a_breakage_on_the_dashboard_and_the_fleet_page(tmp_path: Path) -> None:
    out = Path("out")
    out.mkdir(exist_ok=True)
    with broker() as bp:
        url = f"mqtt://127.0.0.1:{bp}"
        # the fleet page subscribes before the service publishes; it links the
        # service's page (its origin is one the fleet is told of)
        links = Links.parse(None, [PUBLIC_URL])
        with (
            serve_fleet(parse_broker_url(url), stale_after=10.0, links=links) as fleet_hp,
            serve_process(
                "--scenario",
                "default",
                "--broker",
                url,
                "--machine",
                MACHINE,
                "--publish-hz",
                "5",
                "--data-dir",
                str(tmp_path / "data"),
                CUTWATCH_TOKEN=OPERATOR,
                CUTWATCH_VIEW_TOKEN=VIEWER,
                CUTWATCH_PUBLIC_URL=PUBLIC_URL,
            ) as sp,  # fmt: skip
            chromium_page(1280, 900) as (page, errors),
        ):
            base = sp.base
            # one good part taught per block (the default 5 takes a minute and more)
            r = httpx.patch(
                f"{base}/api/params",
                json={"teach_parts": 1},
                headers={"Authorization": f"Bearer {OPERATOR}"},
            )
            assert r.status_code == 200, r.text
            log_in(page, base, OPERATOR)
            page.wait_for_selector("#conn[data-state=up]", timeout=15000)
            # the monitor teaches on the first good part, then watches; by the third part
            # every block has been taught (a part at a feed override teaches nothing)
            wait_for(lambda: strip_state(page) == "watching", timeout=TEACH_TIMEOUT_S)
            wait_for(lambda: service_part(base) >= WATCH_FROM_PART, timeout=TEACH_TIMEOUT_S)
            assert page.inner_text("#strip-tool").startswith("T")
            assert "%" in page.inner_text("#strip-wear")

            # the breakage in the middle of the next part's first cut
            at_part = service_part(base) + 1
            r = operator_post(
                base, "/api/control", {"action": "inject", "kind": "breakage", "at_part": at_part}
            )
            assert r.status_code == 200, r.text

            # the status strip: alarm, with the breakage's words
            try:
                wait_for(lambda: strip_state(page) == "alarm", timeout=PART_TIMEOUT_S)
            except AssertionError:
                snap = httpx.get(f"{base}/api/snapshot", headers=VIEW).json()
                raise AssertionError(
                    f"no alarm on the page: inject answered {r.json()}; the service's "
                    f"status {snap.get('status')}, events {snap.get('events')}, "
                    f"t {snap['health']['sim_t']}"
                ) from None
            assert page.inner_text("#strip-state") == "ALARM"
            # the timeline: the breakage's row, waiting (a wear alarm may come beside it)
            row = page.locator("#timeline-rows tr[data-kind=breakage]")
            row.wait_for(timeout=10000)
            assert row.count() == 1
            assert "waiting" in (row.get_attribute("class") or "")
            ev_id = row.get_attribute("data-id")
            assert ev_id
            kept = httpx.get(
                f"{base}/api/events",
                params={"kind": "breakage"},
                headers=VIEW,
            ).json()
            ev = next(e for e in kept["items"] if e["id"] == ev_id)
            # the strip names the waiting feed hold in the detector's words
            assert page.inner_text("#strip-message") == ev["message"]
            assert "breakage" in ev["message"].lower()
            cells = row.locator("td").all_inner_texts()
            assert cells[0] == f"{ev['t']:.3f}" and cells[1] == "tool breakage"
            assert cells[2] == f"T{ev['tool']}" and cells[3] == str(ev["line"])
            assert cells[4] == str(ev["part"]) and cells[6] == "feed hold"
            assert cells[7] == "Acknowledge"
            assert not page.is_disabled(f"#timeline-rows tr[data-id='{ev_id}'] button.ack")
            # the chart marker: drawn at the event, red, the plot's height
            wait_for(
                lambda: ev_id in (page.get_attribute("#chart-monitor", "data-marker-ids") or "")
            )
            drawn = page.evaluate(MARKER_PIXELS, ["#chart-monitor", list(MARKER_RGB)])
            i = drawn["ids"].index(ev_id)
            assert drawn["counts"][i] > 0.5 * drawn["height"], drawn
            page.screenshot(path=str(out / "monitoring-alarm.png"))

            # a viewer sees the event and a disabled Acknowledge, and why
            viewer = page.context.browser.new_context()
            try:
                vpage = viewer.new_page()
                log_in(vpage, base, VIEWER)
                btn = vpage.locator(f"#timeline-rows tr[data-id='{ev_id}'] button.ack")
                btn.wait_for(timeout=15000)
                wait_for(lambda: btn.is_disabled())
                assert "operator role" in (btn.get_attribute("title") or "")
                assert "operator role" in vpage.inner_text("#ack-why")
                assert vpage.is_disabled("#ack-all")
            finally:
                viewer.close()

            # the fleet page: the machine's row in alarm, with the breakage
            browser = page.context.browser
            assert browser is not None
            fleet = browser.new_context(viewport={"width": 1280, "height": 500}).new_page()
            fleet.goto(f"http://{fleet_hp}/")
            mrow = fleet.locator(f"tr[data-machine='{MACHINE}']")
            fleet.wait_for_selector(f"tr[data-machine='{MACHINE}'].alarm", timeout=15000)
            fleet.wait_for_selector(
                f"tr[data-machine='{MACHINE}'] td.event[data-kind=breakage]", timeout=15000
            )
            assert mrow.locator(".monitor").inner_text().lower() == "alarm"
            assert "tool breakage" in mrow.locator("td.event").inner_text()
            assert mrow.locator("a").get_attribute("href") == PUBLIC_URL  # the link stays
            fleet.screenshot(path=str(out / "fleet-alarm.png"), full_page=True)

            # acknowledged on the dashboard: the row says who; with every other waiting
            # event (a wear alarm of the same run) acknowledged too, the strip leaves alarm
            page.click(f"#timeline-rows tr[data-id='{ev_id}'] button.ack")
            acked = page.locator(f"#timeline-rows tr[data-id='{ev_id}']")
            wait_for(lambda: "acked" in (acked.get_attribute("class") or ""))
            assert acked.locator("td").nth(7).inner_text().startswith("yes, ")
            if page.locator("#timeline-rows tr.waiting").count():
                page.click("#ack-all")
            wait_for(lambda: strip_state(page) != "alarm", timeout=15)
            assert page.locator("#timeline-rows tr.waiting").count() == 0
            # and the fleet learns it from the machine's estimates (nothing waits)
            wait_for(lambda: mrow.get_attribute("data-monitor") not in ("alarm", None), 15)
            assert mrow.locator("td.event").inner_text() == "–"
            kept = httpx.get(
                f"{base}/api/events",
                params={"acked": "true"},
                headers=VIEW,
            ).json()
            assert ev_id in [e["id"] for e in kept["items"] if e["acked"]]
            assert errors == []
