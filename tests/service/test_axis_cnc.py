"""Issue 30, items 5 and 7b: a real CNC's 10 Hz export (../shared/data/cnc-mill/
experiment_01.csv as one machine: X, Y, Z and the spindle, with the program line, its
description docs/machines/cnc-mill.json) sent by ``cutwatch feed`` through a real
Mosquitto into the service. The parts that run and those that cannot, with their
reasons, match the table in docs/live-axis.md; the dashboard (a real Chromium) shows the
machine ``degraded`` with its parts and their reasons."""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from _broker import broker, need_mosquitto
from _browser import chromium_page
from _live import serve

from server.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
CSV = next(
    (p / "shared" / "data" / "cnc-mill" / "experiment_01.csv" for p in ROOT.parents
     if (p / "shared" / "data" / "cnc-mill" / "experiment_01.csv").exists()),
    None,
)  # fmt: skip
pytestmark = [pytest.mark.skipif(CSV is None, reason="cnc-mill data not present"), pytest.mark.slow]
DOC = ROOT / "docs" / "live-axis.md"


@pytest.fixture(scope="module")
def fed() -> Iterator[tuple[str, dict[str, Any], dict[str, Any]]]:
    """The service with the whole record estimated: its address, health and snapshot."""
    need_mosquitto()
    with broker() as bp:
        url = f"mqtt://127.0.0.1:{bp}"
        with serve(source="mqtt", mqtt_broker=url, mqtt_machine="mill-1", mqtt_buffer_s=300) as hp:
            argv = ["feed", str(CSV), "--meta", str(ROOT / "docs" / "machines" / "cnc-mill.json"),
                    "--broker", url, "--machine", "mill-1", "--speed", "0", "--quiet"]  # fmt: skip
            feeder = threading.Thread(target=main, args=(argv,))
            feeder.start()
            feeder.join(60)
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                h = httpx.get(f"http://{hp}/api/health").json()
                f = h.get("feed") or {}
                if f.get("samples", 0) >= 1000 and f.get("buffered_samples", 1) == 0:
                    break
                time.sleep(0.2)
            snap = httpx.get(f"http://{hp}/api/snapshot").json()["pipeline"]
            yield hp, h, snap


def doc_table() -> dict[str, tuple[bool, str]]:
    """The table of docs/live-axis.md's cnc-mill section: part -> (runs, the reason's
    start)."""
    text = DOC.read_text()
    sec = text[text.index("<!-- cnc-mill parts -->") : text.index("<!-- /cnc-mill parts -->")]
    out = {}
    for line in sec.splitlines():
        m = re.match(r"\| `(\w+)` \| (yes|no) \| (.*) \|$", line)
        if m:
            out[m.group(1)] = (m.group(2) == "yes", m.group(3).strip().strip("`"))
    return out


def test_the_parts_match_the_table_in_the_docs(fed: tuple[str, dict[str, Any], dict[str, Any]]):
    _, h, snap = fed
    got = {p["name"]: p for p in h["parts"]}
    want = doc_table()
    assert set(got) == set(want), (sorted(got), sorted(want))
    for name, (runs, reason) in want.items():
        assert got[name]["running"] == runs, got[name]
        assert got[name]["reason"].startswith(reason.rstrip(".")), (got[name], reason)
    assert h["status"] == "degraded" and h["idle"] == ""
    # per axis, nothing left out at 10 Hz: the CNC's velocity and acceleration stand in
    assert snap["axes"] == {"X": {}, "Y": {}, "Z": {}}
    latest = snap["latest"]
    for ax in ("X", "Y"):  # Fc excited from the CNC's velocity (the docs' table above)
        assert latest[f"{ax}.Fc_excited"] == 1.0 and 4.0 < latest[f"{ax}.Fc"] < 5.5


def test_the_dashboard_shows_the_machine_degraded_with_its_parts_and_reasons(
    fed: tuple[str, dict[str, Any], dict[str, Any]],
) -> None:
    hp, h, _ = fed
    with chromium_page(1280, 900) as (page, errors):
        page.goto(f"http://{hp}/")
        page.wait_for_selector("#parts tr[data-part=axes]", timeout=20000)
        for p in h["parts"]:
            row = page.locator(f"#parts tr[data-part={p['name']}]")
            assert row.get_attribute("data-running") == ("true" if p["running"] else "false")
            if not p["running"]:
                assert p["reason"][:40] in (row.text_content() or ""), p
        down = sum(not p["running"] for p in h["parts"])
        assert page.text_content("#parts-summary") == f"{down} not running"
        page.wait_for_selector("#chart-axis-X-force canvas", timeout=20000)
        out = Path("out")
        out.mkdir(exist_ok=True)
        page.screenshot(path=str(out / "cnc-mill-degraded.png"), full_page=True)
        assert errors == []
