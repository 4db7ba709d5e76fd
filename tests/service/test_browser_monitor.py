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

pytestmark = [*MARKS, pytest.mark.slow]

MACHINE = "mill-7"
#: the marker colour of an event waiting for an acknowledgement (web/monitor.js)
MARKER_RGB = (224, 0, 0)
#: how long the monitor may teach before it watches (simulated parts at the service's speed)
TEACH_TIMEOUT_S = 240.0

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
        # the fleet page subscribes before the service publishes
        with (
            serve_fleet(parse_broker_url(url), stale_after=10.0) as fleet_hp,
            serve_process(
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
            ) as sp,  # fmt: skip
            chromium_page(1280, 900) as (page, errors),
        ):
            base = sp.base
            log_in(page, base, OPERATOR)
            page.wait_for_selector("#conn[data-state=up]", timeout=15000)
            # the monitor teaches on the first good parts, then watches
            wait_for(lambda: strip_state(page) == "watching", timeout=TEACH_TIMEOUT_S)
            assert page.inner_text("#strip-tool").startswith("T")
            assert "%" in page.inner_text("#strip-wear")

            r = operator_post(base, "/api/control", {"action": "inject", "kind": "breakage"})
            assert r.status_code == 200, r.text

            # the status strip: alarm, with the breakage's words
            wait_for(lambda: strip_state(page) == "alarm", timeout=30)
            assert page.inner_text("#strip-state") == "ALARM"
            assert "tool breakage" in page.inner_text("#strip-message")
            # the timeline: the breakage's row, waiting, newest first
            row = page.locator("#timeline-rows tr").first
            row.wait_for(timeout=10000)
            assert row.get_attribute("data-kind") == "breakage"
            assert "waiting" in (row.get_attribute("class") or "")
            ev_id = row.get_attribute("data-id")
            assert ev_id
            cells = row.locator("td").all_inner_texts()
            assert cells[1] == "tool breakage" and cells[6] == "feed hold"
            assert cells[2] == page.inner_text("#strip-tool")  # the tool in the spindle
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
            viewer = page.context.browser.new_context(viewport={"width": 1280, "height": 900})
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
            fleet = page.context.new_page()
            fleet.goto(f"http://{fleet_hp}/")
            mrow = fleet.locator(f"tr[data-machine='{MACHINE}']")
            fleet.wait_for_selector(f"tr[data-machine='{MACHINE}'].alarm", timeout=15000)
            fleet.wait_for_selector(
                f"tr[data-machine='{MACHINE}'] td.event[data-kind=breakage]", timeout=15000
            )
            assert mrow.locator(".monitor").inner_text().lower() == "alarm"
            assert "tool breakage" in mrow.locator("td.event").inner_text()
            assert mrow.locator("a").get_attribute("href")  # the dashboard link stays
            fleet.screenshot(path=str(out / "fleet-alarm.png"), full_page=True)

            # acknowledged on the dashboard: the strip leaves alarm, the row says who
            page.click(f"#timeline-rows tr[data-id='{ev_id}'] button.ack")
            wait_for(lambda: strip_state(page) != "alarm", timeout=15)
            acked = page.locator(f"#timeline-rows tr[data-id='{ev_id}']")
            wait_for(lambda: "acked" in (acked.get_attribute("class") or ""))
            assert acked.locator("td").nth(7).inner_text().startswith("yes")
            kept = httpx.get(
                f"{base}/api/events",
                params={"acked": "true"},
                headers={"Authorization": f"Bearer {VIEWER}"},
            ).json()
            assert ev_id in [e["id"] for e in kept["items"] if e["acked"]]
            assert errors == []
