"""``POST /api/tool-life/vb`` (issue 35 item 7 live) on a real server running the machining
centre: the strip's wear of the spindle's tool says "uncalibrated" with the prior's
interval; bad input is answered 422 naming the field, what it allows and what it got; a
VB entered at a tool change labels that life and the tool's map is calibrated from it.

A worn tool lasts tens of minutes of machine time (the simulator's lives), longer than
a test may run, so the one tool change of the last test is the part's own bookkeeping
of a change (:meth:`estimators.wear.centre.CentreWear` ends a life on two fresh
readings) entered under the loop's lock; the route, the part's label and the strip are
the real ones. Detection and calibration over whole lives are measured by
``cutwatch reproduce centre-wear``."""

from __future__ import annotations

import math
import socket
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import httpx
import pytest
import uvicorn
from _live import in_thread
from _wait import poll

from estimators.wear.centre import Life
from server.service.app import create_app
from server.service.front import uvicorn_options
from server.service.loop import LiveLoop
from server.service.settings import Settings


@contextmanager
def serve_app(**settings: Any) -> Iterator[tuple[str, LiveLoop]]:
    """The real app on a free loopback port in this process; ``host:port`` and its loop."""
    with tempfile.TemporaryDirectory(prefix="cutwatch-data-") as d, socket.socket() as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(("127.0.0.1", 0))
        port = int(sock.getsockname()[1])
        s = Settings(port=port, viser=False, data_dir=d, **settings)
        app = create_app(s)
        options = uvicorn_options(s)
        del options["workers"]
        cfg = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", **options)
        with in_thread(uvicorn.Server(cfg), sock):
            yield f"127.0.0.1:{port}", app.state.loop


@pytest.fixture(scope="module")
def centre() -> Iterator[tuple[httpx.Client, LiveLoop]]:
    with (
        serve_app(scenario="machining-centre") as (hp, loop),
        httpx.Client(base_url=f"http://{hp}", timeout=60) as api,
    ):
        r = api.post("/api/control", json={"action": "speed", "value": 1000})
        assert r.status_code == 200, r.text

        def status() -> dict[str, Any]:
            return dict(api.get("/api/snapshot").json()["status"] or {})

        # four parts: every cut block taught, then read; the strip speaks of T2 at last
        poll(lambda: status().get("wear_lo_share") is not None
             and loop.pipeline.part("centre_wear").st.est.tools.get(2) is not None
             and loop.pipeline.part("centre_wear")._taught(2), 240, 0.5)  # fmt: skip
        yield api, loop


def test_the_strip_says_uncalibrated_with_the_priors_interval(centre: tuple) -> None:
    api, _ = centre
    st = api.get("/api/snapshot").json()["status"]
    assert st["wear_calibrated"] is False
    assert st["wear_tool"] == st["tool"] > 0 and st["wear_limit_mm"] == pytest.approx(0.3)
    assert 0.0 <= st["wear_lo_share"] <= st["wear_share"] <= st["wear_hi_share"]
    assert math.isfinite(st["wear_hi_share"]) and st["wear_hi_share"] > st["wear_lo_share"]


@pytest.mark.parametrize(
    ("body", "field", "words"),
    [
        ({"tool": 2, "vb_mm": -0.1}, "vb_mm", "greater than 0"),
        ({"tool": 2, "vb_mm": 3.0}, "vb_mm", "less than or equal to 0.9"),
        ({"tool": 0, "vb_mm": 0.3}, "tool", "greater than or equal to 1"),
        ({"tool": 2}, "vb_mm", "required"),
        ({"tool": 2, "vb_mm": 0.3, "x": 1}, "x", "not permitted"),
        # no tool change of T2 seen yet: nothing to label
        ({"tool": 2, "vb_mm": 0.3}, "tool", "a tool with a tool change not yet labelled"),
    ],
)
def test_bad_input_is_named(centre: tuple, body: dict, field: str, words: str) -> None:
    api, _ = centre
    r = api.post("/api/tool-life/vb", json=body)
    assert r.status_code == 422, r.text
    d = r.json()["detail"]
    assert any(e["field"].endswith(field) for e in d), d
    assert words in r.text, r.text


def test_a_vb_entered_at_a_change_calibrates_the_tools_map(centre: tuple) -> None:
    api, loop = centre
    part = loop.pipeline.part("centre_wear")
    with loop.lock:
        st = part.st.est
        assert any(k[0] == 2 and part.wear._is_cut(b) for k, b in st.blocks.items())
        # every block of T2 (all seen in the parts so far; one may finish its teaching
        # before the label arrives)
        keys = [k for k in st.blocks if k[0] == 2]
        # the part's own record of a change of T2: its blocks read +30 % at the end
        end = float(loop.pipeline.source.t)
        st.lives.append(Life(2, 1, 0.0, end, 100.0, 0.25e-3, {k: 0.3 for k in keys}))
        part.st.changes.append({"tool": 2, "index": 1, "start_t": 0.0, "end_t": end,
                                "wear_at_change_mm": 0.25, "cause": "wear_limit"})  # fmt: skip
    # the change is kept in the tool-life record, with no measured VB yet
    lives = poll(lambda: api.get("/api/tool-life", params={"tool": 2}).json()["items"], 60, 0.2)
    assert lives[0]["index"] == 1 and lives[0]["wear_measured_mm"] is None
    r = api.post("/api/tool-life/vb", json={"tool": 2, "vb_mm": 0.28})
    assert r.status_code == 200, r.text
    got = r.json()
    assert (got["tool"], got["index"], got["vb_mm"], got["calibrated"]) == (2, 1, 0.28, True)
    assert got["recorded"] is True
    rec = api.get("/api/tool-life", params={"tool": 2}).json()["items"][0]
    assert rec["wear_measured_mm"] == 0.28 and rec["wear_at_change_mm"] == 0.25
    assert got["vb_est_mm"] == pytest.approx(0.25)
    # the gain of each block is that life's: 0.3 / (0.28 mm - the taught VB)
    a = 0.3 / (0.28e-3 - part.wear.params.vb_taught)
    for k in keys:
        assert part.wear.gain(part.st.est, k)[0] == pytest.approx(a)
    assert part.wear.calibrated(part.st.est, 2)
    # the strip says calibrated while T2 is in the spindle
    poll(lambda: (s := api.get("/api/snapshot").json()["status"])["wear_tool"] == 2
         and s["wear_calibrated"] is True, 120, 0.2)  # fmt: skip
    # that life is labelled: a second entry finds nothing to label
    r = api.post("/api/tool-life/vb", json={"tool": 2, "vb_mm": 0.28})
    assert r.status_code == 422 and "tool" in r.text


def test_a_machine_without_the_wear_part_names_it() -> None:
    with (
        serve_app(scenario="default") as (hp, _),  # the seeds' stage: no spindle
        httpx.Client(base_url=f"http://{hp}", timeout=60) as api,
    ):
        r = api.post("/api/tool-life/vb", json={"tool": 1, "vb_mm": 0.3})
        assert r.status_code == 422, r.text
        assert "centre_wear" in r.text and r.json()["detail"][0]["field"] == "tool"
