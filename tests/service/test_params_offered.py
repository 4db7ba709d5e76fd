"""Issue 31: the knobs are the running parts', over real HTTP and in the page.

A real server started with no scenario runs the machining centre: ``GET /api/params``
offers its monitors' two knobs (read by the spindle and axis_monitor parts), and the frames carry
those two; ``PATCH /api/params`` refuses a knob no part of the centre reads with a 422
naming the field, the knobs expected and the value found, and the parts that would read
it, changing nothing (all or nothing); switched to the stage's scenario every knob is
offered again. In headless Chromium the knobs panel builds exactly those controls, a
change through one reaches the pipeline, and the panel follows a scenario switch; the
accuracy panel lists the axes' estimates and none of the stage's observers (not run).
The centre's two knobs are an operator's (``page`` operator): they are set on the machine's
tab, the page opens on, and a value set there is the pipeline's after a reload; the stage's
scenario keeps its other knobs on the research tab.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from _browser import CHROMIUM, chromium_page, wait_for
from _live import serve
from websockets.sync.client import connect

from server.pipeline.knobs import KNOBS

CENTRE_KNOBS = {"teach_parts", "band_factor"}


@pytest.fixture(scope="module")
def hp() -> Iterator[str]:
    with serve() as hostport:  # no scenario: the machining centre
        yield hostport


@pytest.fixture
def api(hp: str) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=f"http://{hp}", timeout=10) as c:
        assert c.get("/api/scenarios").json()["current"] == "machining-centre"
        yield c


def test_the_centre_offers_its_parts_knobs(hp: str, api: httpx.Client) -> None:
    params = api.get("/api/params").json()
    assert set(params) == CENTRE_KNOBS
    for k in params.values():
        assert (
            k["parts"] == ["spindle", "axis_monitor"]
            and k["waiting"] == ""
            and k["type"] == "number"
        )
    with connect(f"ws://{hp}/ws") as ws:
        msgs: list[dict[str, Any]] = [json.loads(ws.recv(timeout=10))]
        while msgs[-1]["type"] != "data":
            assert len(msgs) < 50, [m["type"] for m in msgs]
            msgs.append(json.loads(ws.recv(timeout=10)))
    msg = msgs[-1]
    assert set(msg["knobs"]) == CENTRE_KNOBS


def test_a_knob_no_part_reads_is_refused_by_name(api: httpx.Client) -> None:
    before = api.get("/api/params").json()
    r = api.patch("/api/params", json={"band_factor": 5.0, "wear_rate": 1.5, "spindle_rpm": 2000})
    assert r.status_code == 422, r.text
    detail = {e["field"]: e for e in r.json()["detail"]}
    assert set(detail) == {"wear_rate", "spindle_rpm"}  # band_factor itself was fine
    wear = detail["wear_rate"]
    assert wear["got"] == 1.5
    assert (
        wear["allowed"] == "one of the knobs this pipeline's parts read: teach_parts, band_factor"
    )
    assert wear["msg"].startswith("wear_rate is read by the wear part, which this pipeline")
    assert "the simulated stage" in detail["spindle_rpm"]["msg"]
    assert api.get("/api/params").json() == before  # all or nothing
    # a knob of the centre's parts is taken
    r = api.patch("/api/params", json={"band_factor": 5.0})
    assert r.status_code == 200 and r.json()["band_factor"]["value"] == 5.0


def test_the_stage_scenario_offers_every_knob_again(api: httpx.Client) -> None:
    try:
        r = api.post("/api/control", json={"action": "scenario", "scenario": "default"})
        assert r.status_code == 200, r.text
        params = api.get("/api/params").json()
        assert set(params) == set(KNOBS)
        assert params["wear_rate"]["parts"] == ["wear"]
        assert params["spindle_rpm"]["parts"] == ["simulator"]
        assert api.patch("/api/params", json={"wear_rate": 1.5}).status_code == 200
    finally:
        api.post("/api/control", json={"action": "scenario", "scenario": "machining-centre"})


@pytest.mark.browser
@pytest.mark.skipif(not CHROMIUM.exists(), reason="/usr/bin/chromium is not installed")
def test_the_knobs_panel_follows_the_running_parts(hp: str) -> None:
    base = f"http://{hp}"

    def knob_ids(page: Any) -> set[str]:
        ids = page.eval_on_selector_all("form.knobs [id^=knob-]", "els => els.map(e => e.id)")
        return {i.removeprefix("knob-") for i in ids}

    with chromium_page(1280, 900) as (page, errors):
        page.goto(f"{base}/#research")
        # built (on the machine's tab: an operator's knob, hidden while research shows)
        page.wait_for_selector("#knob-teach_parts", state="attached", timeout=30000)
        assert knob_ids(page) == CENTRE_KNOBS
        # the accuracy panel: the running parts' estimates (the axes'), not the stage's
        page.wait_for_selector("#accuracy tr[data-key='X.F']", timeout=30000)
        assert page.locator("#accuracy tr[data-key=f_fixed]").count() == 0
        title = page.get_attribute("label[for=knob-band_factor]", "title") or ""
        assert "read by the spindle part" in title
        # a change through the page's control reaches the pipeline
        page.locator("#knob-band_factor").evaluate(
            "el => { el.value = 7; el.dispatchEvent(new Event('change')); }"
        )
        wait_for(lambda: httpx.get(f"{base}/api/params").json()["band_factor"]["value"] == 7.0)
        # switched to the stage's scenario from the page: its knobs appear
        try:
            page.select_option("#scenario", "default")
            wait_for(lambda: "wear_rate" in knob_ids(page), 30)
            assert knob_ids(page) == set(KNOBS)
            title = page.get_attribute("label[for=knob-spindle_rpm]", "title") or ""
            assert "read by the simulated stage" in title
        finally:
            httpx.post(
                f"{base}/api/control",
                json={"action": "scenario", "scenario": "machining-centre"},
                timeout=30,
            )
        wait_for(lambda: knob_ids(page) == CENTRE_KNOBS, 30)
        assert errors == []


@pytest.mark.browser
@pytest.mark.skipif(not CHROMIUM.exists(), reason="/usr/bin/chromium is not installed")
def test_the_operators_knobs_are_on_the_machines_tab(hp: str, api: httpx.Client) -> None:
    base = f"http://{hp}"
    params = api.get("/api/params").json()
    assert {n for n, k in params.items() if k["page"] == "operator"} == CENTRE_KNOBS

    def ids(form: str, page: Any) -> set[str]:
        got = page.eval_on_selector_all(f"#{form} [id^=knob-]", "els => els.map(e => e.id)")
        return {i.removeprefix("knob-") for i in got}

    with chromium_page(1280, 900) as (page, errors):
        page.goto(f"{base}/")  # the default page: the machine's
        page.wait_for_selector("#knobs-operator #knob-teach_parts", timeout=30000)
        assert page.get_attribute("body", "data-page") == "operator"
        assert ids("knobs-operator", page) == CENTRE_KNOBS and ids("knobs", page) == set()
        for name in CENTRE_KNOBS:
            assert page.is_visible(f"#knob-{name}")
        assert page.is_hidden("#knobs")  # the research form: on the other tab
        # a change on the machine's tab: the same PATCH, the pipeline's value
        new = 3.0 if params["teach_parts"]["value"] != 3.0 else 4.0
        page.locator("#knob-teach_parts").evaluate(
            f"el => {{ el.value = {new}; el.dispatchEvent(new Event('change')); }}"
        )
        wait_for(lambda: api.get("/api/params").json()["teach_parts"]["value"] == new)
        page.reload()
        page.wait_for_selector("#knobs-operator #knob-teach_parts", timeout=30000)
        assert float(page.input_value("#knob-teach_parts")) == new
        assert page.inner_text("label[for=knob-teach_parts] + input + output").startswith(
            f"{new:.2f}"
        )
        # the stage's scenario: the teach-in's two on the machine's tab, the rest on research
        try:
            assert (
                api.post(
                    "/api/control", json={"action": "scenario", "scenario": "default"}
                ).status_code
                == 200
            )
            page.reload()
            wait_for(lambda: "wear_rate" in ids("knobs", page), 30)
            assert ids("knobs", page) == set(KNOBS) - CENTRE_KNOBS
            assert ids("knobs-operator", page) == CENTRE_KNOBS
            assert page.is_hidden("#knob-wear_rate")
            page.click("#tab-research")
            assert page.is_visible("#knob-wear_rate") and page.is_visible("#knob-weight_on")
            assert page.is_hidden("#knob-teach_parts")
        finally:
            api.post("/api/control", json={"action": "scenario", "scenario": "machining-centre"})
        assert errors == []
