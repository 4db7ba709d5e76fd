"""The dashboard's process monitor parts (web/monitor.js) and the event message's check
(web/protocol.js), run under node on events and statuses built by the server's models."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from server.records.monitor_events import DEFAULT_ACTIONS, MonitorEvent
from server.service.messages import Event, EventMessage, MonitorStatus

WEB = Path(__file__).resolve().parents[2] / "web"
NODE = shutil.which("node")
pytestmark = pytest.mark.skipif(NODE is None, reason="node is not installed")


def run_js(code: str, stdin: str) -> object:
    assert NODE is not None
    out = subprocess.run(
        [NODE, "--input-type=module", "-e", code],
        input=stdin,
        capture_output=True,
        text=True,
        timeout=30,
        cwd=WEB,
        check=False,
    )
    if out.returncode != 0:
        raise AssertionError(out.stderr)
    return json.loads(out.stdout)


def event(kind: str, t: float, **extra: object) -> dict:
    ev = MonitorEvent(
        kind=kind, action=DEFAULT_ACTIONS[kind], t=t, tool=3, program="O1001", line=120,
        part=7, value=4.25, limit=1.5, unit="N", message=f"{kind} seen", machine="m1",
    )  # fmt: skip
    return Event.model_validate({**ev.as_dict(), **extra}).model_dump()


def status(**kw: object) -> dict:
    base = dict(
        state="watching", tool=3, program="O1001", line=120, part=7, wear_share=0.456,
        life_left_min=12.34, unacked=0,
    )  # fmt: skip
    return MonitorStatus.model_validate({**base, **kw}).model_dump()


def test_the_strip_reads_the_status() -> None:
    code = (
        "import {statusView} from './monitor.js';"
        "import {readFileSync} from 'node:fs';"
        "const [a, b, ev] = JSON.parse(readFileSync(0, 'utf8'));"
        "console.log(JSON.stringify([statusView(a), statusView(b, ev), statusView(undefined)]));"
    )
    alarm = status(state="alarm", unacked=2, wear_share=1.3, life_left_min=None, tool=0)
    w, a, off = run_js(code, json.dumps([status(), alarm, event("breakage", 5.0)]))  # type: ignore[misc]
    assert (w["state"], w["label"], w["tool"], w["wear"], w["life"]) == (
        "watching", "WATCHING", "T3", "46 %", "12.3 min",
    )  # fmt: skip
    assert w["where"] == "program O1001 · line 120 · part 7" and w["message"] == ""
    assert w["unackedText"] == "nothing to acknowledge"
    # in alarm: the waiting event's words; a worn-out tool fills the bar, no more
    assert a["label"] == "ALARM" and a["message"] == "breakage seen"
    assert a["wearBar"] == 1 and a["wear"] == "130 %" and a["life"] == "–" and a["tool"] == "–"
    assert a["unackedText"] == "2 to acknowledge"
    assert off["state"] == "off" and off["label"] == "OFF"


def test_the_wear_tiles_speak_of_one_tool_and_one_limit() -> None:
    # issue 28: the wear model's own tool beside the spindle's: its own labelled group,
    # its own number, its share of one stated limit and the alarm as a share of it; the
    # wear alarm's row names the same tool and the threshold as what it is
    code = (
        "import {statusView, eventRow} from './monitor.js';"
        "import {readFileSync} from 'node:fs';"
        "const [a, b, ev] = JSON.parse(readFileSync(0, 'utf8'));"
        "console.log(JSON.stringify([statusView(a), statusView(b), eventRow(ev).cells]));"
    )
    apart = status(wear_tool=2, wear_of="the stage's turning tool", wear_share=0.913,
                   wear_limit_mm=0.3, wear_alarm_share=0.9)  # fmt: skip
    same = status(wear_tool=3, wear_of="", wear_limit_mm=0.3, wear_alarm_share=0.9)
    wear_ev = event("wear_limit", 9.0, tool=2, program="", line=0, part=-1, value=0.274,
                    limit=0.27, unit="mm")  # fmt: skip
    a, s, cells = run_js(code, json.dumps([apart, same, wear_ev]))  # type: ignore[misc]
    assert a["wearApart"] and a["wearOf"] == "tool wear · the stage's turning tool"
    assert (a["tool"], a["wearTool"], a["wear"]) == ("T3", "tool 2", "91 %")
    assert a["wearLimit"] == "of 0.300 mm · alarm at 90 %"
    # the spindle's own tool: no second number
    assert not s["wearApart"] and s["wearTool"] == "T3" and s["wearOf"] == "tool wear"
    assert cells[2:6] == ["tool 2", "–", "–", "0.274 vs alarm at 0.270 mm"]
    assert a["wearKnown"] and s["wearKnown"]


def test_no_wear_model_hides_the_wear_tiles() -> None:
    # the machining centre (no wear estimate yet): no tool, share or life for the tiles
    code = (
        "import {statusView} from './monitor.js';"
        "import {readFileSync} from 'node:fs';"
        "const [a] = JSON.parse(readFileSync(0, 'utf8'));"
        "console.log(JSON.stringify(statusView(a)));"
    )
    v = run_js(code, json.dumps([status(wear_share=None, life_left_min=None, wear_tool=0)]))
    assert isinstance(v, dict) and v["wearKnown"] is False and v["tool"] == "T3"


def test_the_timeline_is_newest_first_and_an_acknowledgement_sticks() -> None:
    code = (
        "import {mergeEvent, ordered, eventRow, markersIn, headline} from './monitor.js';"
        "import {readFileSync} from 'node:fs';"
        "const [e1, e2, e1acked] = JSON.parse(readFileSync(0, 'utf8'));"
        "const m = new Map();"
        "const changed = [mergeEvent(m, e1), mergeEvent(m, e2), mergeEvent(m, e1),"
        " mergeEvent(m, e1acked), mergeEvent(m, e1)];"
        "console.log(JSON.stringify({changed, rows: ordered(m).map(eventRow),"
        " markers: markersIn(m, 0, 10), all: markersIn(m, 0, 100),"
        " head: headline(m).id, none: headline(new Map())}));"
    )
    e1 = event("breakage", 5.0)
    e2 = event("collision", 20.0)
    e1a = {**e1, "acked": True, "acked_by": "operator", "acked_wall": 1_700_000_000.0}
    got = run_js(code, json.dumps([e1, e2, e1a]))
    assert isinstance(got, dict)
    assert got["changed"] == [True, True, False, True, False]  # a late raised copy: no undo
    rows = got["rows"]
    assert [r["kind"] for r in rows] == ["collision", "breakage"]
    assert rows[0]["waiting"] and not rows[1]["waiting"]
    assert rows[0]["cells"] == [
        "20.000", "collision / overload", "T3", "120", "7", "4.250 vs 1.500 N", "feed hold", "no",
    ]  # fmt: skip
    assert rows[1]["cells"][7] == "yes, operator 22:13:20 UTC"
    # markers: in range only; red while waiting, grey once acknowledged
    assert [(m["t"], m["color"]) for m in got["markers"]] == [(5.0, "#8a8f98")]
    assert [m["color"] for m in got["all"]] == ["#8a8f98", "#e00000"]
    assert got["head"] == e2["id"] and got["none"] is None


def test_the_strip_names_a_feed_hold_before_a_newer_alarm() -> None:
    code = (
        "import {mergeEvent, headline, eventRow} from './monitor.js';"
        "import {readFileSync} from 'node:fs';"
        "const evs = JSON.parse(readFileSync(0, 'utf8'));"
        "const m = new Map(); for (const e of evs) mergeEvent(m, e);"
        "console.log(JSON.stringify([headline(m).kind, eventRow(evs[0]).cells[5]]));"
    )
    hold = event("breakage", 5.0, unit="1")
    got = run_js(code, json.dumps([hold, event("wear_limit", 9.0), event("life_short", 9.5)]))
    assert got == ["breakage", "4.250 vs 1.500"]  # a ratio's unit "1" is not written


def test_acknowledge_is_for_operators() -> None:
    code = (
        "import {ackRefusal} from './monitor.js';"
        "console.log(JSON.stringify(['operator', 'viewer', null].map(ackRefusal)));"
    )
    op, viewer, nobody = run_js(code, "")  # type: ignore[misc]
    assert op == "" and "operator role" in viewer and "viewer" in viewer
    assert "not signed in" in nobody


def test_protocol_accepts_event_messages_and_names_what_is_missing() -> None:
    code = (
        "import {checkMessage} from './protocol.js';"
        "import {readFileSync} from 'node:fs';"
        "const out = JSON.parse(readFileSync(0, 'utf8')).map((m) => {"
        " try { return checkMessage(JSON.stringify(m)).event.kind; }"
        " catch (e) { return e.message; } });"
        "console.log(JSON.stringify(out));"
    )
    good = EventMessage(event=Event.model_validate(event("missing_tool", 1.0))).model_dump()
    bad = {"type": "event", "event": {"id": "x", "kind": "breakage"}}
    got = run_js(code, json.dumps([good, bad, {"type": "event"}]))
    assert isinstance(got, list)
    assert got[0] == "missing_tool"
    assert got[1].startswith("event lacks action, t, tool")
    assert got[2] == "event message lacks event"


def test_the_wear_tile_says_uncalibrated_with_the_priors_interval() -> None:
    # issue 35 item 7 on the centre: the wear share's 95 % interval and whether the map
    # is this machine's own; a status without them reads as before
    code = (
        "import {statusView} from './monitor.js';"
        "import {readFileSync} from 'node:fs';"
        "const [a, b] = JSON.parse(readFileSync(0, 'utf8'));"
        "console.log(JSON.stringify([statusView(a), statusView(b)]));"
    )
    unc = status(wear_tool=2, wear_of="", wear_share=0.31, wear_limit_mm=0.3,
                 wear_lo_share=0.12, wear_hi_share=0.78, wear_calibrated=False)  # fmt: skip
    cal = status(wear_tool=2, wear_of="", wear_share=0.5, wear_limit_mm=0.3,
                 wear_lo_share=0.4, wear_hi_share=0.6, wear_calibrated=True)  # fmt: skip
    u, c = run_js(code, json.dumps([unc, cal]))  # type: ignore[misc]
    assert u["wearLimit"] == "of 0.300 mm · uncalibrated, 95 %: 12–78 %"
    assert c["wearLimit"] == "of 0.300 mm · calibrated, 95 %: 40–60 %"
    assert u["wear"] == "31 %" and u["wearTool"] == "T2" and u["wearKnown"]
