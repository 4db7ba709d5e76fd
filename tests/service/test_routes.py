"""The routes in process: the real app, ``Live`` overridden by a real loop that is not run.

``create_app`` builds the real app (routers, error handlers, body limit); FastAPI's
``dependency_overrides`` hands every route a real :class:`LiveLoop` whose thread is never
started, and httpx drives the app through its ASGI transport, without a server or a
socket. The pipeline is stepped by hand, so what a route answers can be compared with the
loop's own state exactly.
The routes through a real uvicorn server, with the loop running on its clock, are
``test_api.py``.
"""

from __future__ import annotations

import asyncio
import json
import tempfile
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
from fastapi import FastAPI
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from server.service.app import create_app
from server.service.deps import live_loop
from server.service.hub import Hub
from server.service.loop import LiveLoop
from server.service.settings import Settings

JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=10,
)
# bodies aimed at the real knobs as well as arbitrary JSON
KNOB_BODIES = JSON | st.dictionaries(
    st.sampled_from(["spindle_rpm", "weight_on", "Spindle_rpm", ""]),
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
    max_size=3,
)
CONTROL_BODIES = JSON | st.fixed_dictionaries(
    {"action": st.sampled_from(["speed", "pause", "resume", "x"])},
    optional={"value": st.none() | st.floats() | st.integers() | st.text(max_size=3)},
)
JSON_CT = {"content-type": "application/json"}


class InProcess:
    """A blocking client of an ASGI app: httpx's ASGI transport on a private event loop.

    (Starlette's ``TestClient`` warns that its httpx use is deprecated; this is the same
    request path without it.) The app's lifespan is not run.
    """

    def __init__(self, app: FastAPI) -> None:
        self._loop = asyncio.new_event_loop()
        transport = httpx.ASGITransport(app=app)
        # a loopback Host: the app's Host allow-list answers only those on a loopback bind
        self._client = httpx.AsyncClient(transport=transport, base_url="http://127.0.0.1")

    def request(self, method: str, url: str, **kw: Any) -> httpx.Response:
        return self._loop.run_until_complete(self._client.request(method, url, **kw))

    def get(self, url: str, **kw: Any) -> httpx.Response:
        return self.request("GET", url, **kw)

    def post(self, url: str, **kw: Any) -> httpx.Response:
        return self.request("POST", url, **kw)

    def patch(self, url: str, **kw: Any) -> httpx.Response:
        return self.request("PATCH", url, **kw)

    def close(self) -> None:
        self._loop.run_until_complete(self._client.aclose())
        self._loop.close()


@pytest.fixture(scope="module")
def routed() -> Iterator[tuple[InProcess, LiveLoop]]:
    """The app and the loop its routes see (one per module: the tests leave it running)."""
    with tempfile.TemporaryDirectory(prefix="cutwatch-data-") as tmp:
        s = Settings(scenario="default", viser=False, data_dir=tmp)
        app = create_app(s)
        loop = LiveLoop(s, Hub(4))
        app.dependency_overrides[live_loop] = lambda: loop
        client = InProcess(app)  # no lifespan, so no loop thread
        yield client, loop
        client.close()


def test_health_reads_the_loop_it_is_given(routed: tuple[InProcess, LiveLoop]) -> None:
    client, loop = routed
    loop.pipeline.step(3 * loop.block_n)
    h = client.get("/api/health").json()
    assert h["sim_t"] == loop.pipeline.t > 0.0
    assert h["scenario"] == loop.pipeline.scenario
    assert h["status"] == "error"  # the loop's thread is not running: said so
    assert h["loop_error"] is None
    snap = client.get("/api/snapshot").json()
    assert snap["pipeline"]["t"] == loop.pipeline.t
    assert snap["pipeline"]["knobs"] == loop.knob_values()


def test_patch_sets_the_pipelines_knob(routed: tuple[InProcess, LiveLoop]) -> None:
    client, loop = routed
    r = client.patch("/api/params", json={"spindle_rpm": 2400})
    assert r.status_code == 200, r.text
    assert loop.pipeline.knobs()["spindle_rpm"].value == 2400
    assert r.json()["spindle_rpm"]["value"] == 2400


def test_a_refused_patch_changes_no_knob(routed: tuple[InProcess, LiveLoop]) -> None:
    client, loop = routed
    before = loop.knob_values()
    body = {"weight_on": not before["weight_on"], "spindle_rpm": -5}
    r = client.patch("/api/params", json=body)
    assert r.status_code == 422
    assert [e["field"] for e in r.json()["detail"]] == ["spindle_rpm"]
    assert loop.knob_values() == before


def test_control_drives_the_loop(routed: tuple[InProcess, LiveLoop]) -> None:
    client, loop = routed
    r = client.post("/api/control", json={"action": "speed", "value": 4})
    assert r.status_code == 200 and (loop.speed, loop.paused) == (4.0, False)
    assert r.json() == {
        "speed": 4.0,
        "paused": False,
        "sim_t": loop.pipeline.t,
        "scenario": loop.pipeline.scenario,
    }
    client.post("/api/control", json={"action": "pause"})
    assert loop.paused
    client.post("/api/control", json={"action": "resume"})
    assert not loop.paused and loop.speed == 4.0
    loop.pipeline.step(loop.block_n)
    assert client.post("/api/control", json={"action": "reset"}).json()["sim_t"] == 0.0
    assert loop.pipeline.t == 0.0
    other = next(n for n in client.get("/api/scenarios").json()["scenarios"] if n != "default")
    r = client.post("/api/control", json={"action": "scenario", "scenario": other})
    assert r.json()["scenario"] == loop.pipeline.scenario == other
    client.post("/api/control", json={"action": "scenario", "scenario": "default"})


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(body=KNOB_BODIES)
def test_patch_any_body_is_applied_whole_or_refused_whole(
    routed: tuple[InProcess, LiveLoop], body: object
) -> None:
    client, loop = routed
    before = loop.knob_values()
    # NaN and Infinity are sent as Python writes them (not strict JSON), on purpose
    r = client.patch("/api/params", content=json.dumps(body).encode(), headers=JSON_CT)
    assert r.status_code in (200, 422), r.text
    after = loop.knob_values()
    if r.status_code == 422:
        assert after == before
        assert r.json()["detail"] and all(e["msg"] for e in r.json()["detail"])
    else:
        assert isinstance(body, dict)
        assert {k: after[k] for k in body} == {k: r.json()[k]["value"] for k in body}
        assert {k: v for k, v in after.items() if k not in body} == {
            k: v for k, v in before.items() if k not in body
        }


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(body=CONTROL_BODIES)
def test_control_any_body_is_carried_out_or_refused(
    routed: tuple[InProcess, LiveLoop], body: object
) -> None:
    client, loop = routed
    before = (loop.speed, loop.paused)
    r = client.post("/api/control", content=json.dumps(body).encode(), headers=JSON_CT)
    assert r.status_code in (200, 422), r.text
    if r.status_code == 422:
        assert (loop.speed, loop.paused) == before
    else:
        assert isinstance(body, dict)
        assert (r.json()["speed"], r.json()["paused"]) == (loop.speed, loop.paused)
        if body["action"] == "speed":
            assert loop.speed == float(body["value"])
    loop.set_speed(1.0)


#: refusals of ``POST /api/control`` (one action per model, told apart by ``action``):
#: body -> (the field named, the allowed named, the message); the same answers as the one
#: flat model with its if/elif chain gave (tests/service/test_api.py checks them over HTTP)
CONTROL_REFUSALS: list[tuple[dict[str, Any], str, str, str]] = [
    ({"action": "jump"}, "action",
     "one of 'pause', 'resume', 'reset', 'speed', 'scenario', 'inject' or 'relearn'",
     "action: Input should be 'pause', 'resume', 'reset', 'speed', 'scenario', 'inject' or"
     " 'relearn'"),
    ({}, "action", "a value (the field is required)", "action: Field required"),
    ({"action": "speed"}, "value", "a value (required with action 'speed')",
     "value: expected a value (required with action 'speed'), got None"),
    ({"action": "speed", "value": 5000}, "value", "a speed in [0, 1000]",
     "value: expected a speed in [0, 1000], got 5000"),
    ({"action": "pause", "extra": 1}, "extra", "only action",
     "extra: Extra inputs are not permitted"),
    ({"action": "scenario"}, "scenario", "a value (required with action 'scenario')",
     "scenario: expected a value (required with action 'scenario'), got None"),
    ({"action": "inject", "kind": "meteor"}, "kind",
     "one of 'breakage', 'collision' or 'missing_tool'",
     "kind: Input should be 'breakage', 'collision' or 'missing_tool'"),
    ({"action": "inject", "kind": "collision", "size": 0.5}, "size",
     "a feed multiplier in (1, 20] (kind collision)",
     "size: expected a feed multiplier in (1, 20] (kind collision), got 0.5"),
    ({"action": "inject", "kind": "breakage", "at_t": 3, "at_part": 2}, "at_t",
     "no time when at_part is given (one of them)",
     "at_t: expected no time when at_part is given (one of them), got 3.0"),
    ({"action": "inject", "kind": "breakage", "tool": 2}, "tool",
     "no tool (it belongs to action 'relearn')",
     "tool: expected no tool (it belongs to action 'relearn'), got 2"),
    ({"action": "relearn", "kind": "breakage"}, "kind",
     "no kind (it belongs to action 'inject')",
     "kind: expected no kind (it belongs to action 'inject'), got 'breakage'"),
    ({"action": "pause", "at_t": 3}, "at_t", "no at_t (it belongs to action 'inject')",
     "at_t: expected no at_t (it belongs to action 'inject'), got 3"),
    ({"action": 5}, "action",
     "one of 'pause', 'resume', 'reset', 'speed', 'scenario', 'inject' or 'relearn'",
     "action: Input should be 'pause', 'resume', 'reset', 'speed', 'scenario', 'inject' or"
     " 'relearn'"),
]  # fmt: skip


#: routes whose routers are given their tags later (see the test below)
_TAGGED_LATER = {"/api/health", "/api/scenarios", "/api/snapshot", "/metrics", "/api/events",
                 "/api/events/{event_id}/ack", "/api/tool-life"}  # fmt: skip


@pytest.mark.parametrize(("body", "field", "allowed", "msg"), CONTROL_REFUSALS)
def test_control_refuses_each_field_by_name(
    routed: tuple[InProcess, LiveLoop], body: dict[str, Any], field: str, allowed: str, msg: str
) -> None:
    client, loop = routed
    before = (loop.speed, loop.paused, loop.pipeline.t)
    r = client.post("/api/control", json=body)
    assert r.status_code == 422, r.text
    (d,) = r.json()["detail"]
    assert (d["field"], d["allowed"], d["msg"]) == (field, allowed, msg)
    assert d["got"] == body.get(field, None if field != "at_t" else 3.0)
    assert (loop.speed, loop.paused, loop.pipeline.t) == before


def test_control_inject_and_relearn_reach_the_monitor(routed: tuple[InProcess, LiveLoop]) -> None:
    client, _ = routed
    r = client.post("/api/control", json={"action": "inject", "kind": "collision", "at_part": 3})
    assert r.status_code == 200, r.text
    assert r.json()["scheduled"]["kind"] == "collision" and r.json()["scheduled"]["at_part"] == 3
    assert "relearned" not in r.json()
    r = client.post("/api/control", json={"action": "relearn", "tool": 1})
    assert r.status_code == 200 and r.json()["relearned"]["tool"] == 1
    assert "scheduled" not in r.json()


def test_the_openapi_document_tells_the_actions_apart_and_tags_every_route(
    routed: tuple[InProcess, LiveLoop],
) -> None:
    client, _ = routed
    doc = client.get("/openapi.json").json()
    body = doc["paths"]["/api/control"]["post"]["requestBody"]["content"]["application/json"]
    schema = body["schema"]
    assert schema["discriminator"]["propertyName"] == "action"
    assert sorted(schema["discriminator"]["mapping"]) == sorted(
        ["pause", "resume", "reset", "speed", "scenario", "inject", "relearn"]
    )
    untagged = [
        p for p, ms in doc["paths"].items() for m, op in ms.items() if not op.get("tags")
    ]  # fmt: skip
    # status.py and events.py get their prefix and tags once the machining centre's and
    # the turning-wear lines, which add routes to them, have landed (issue 34's note)
    assert set(untagged) <= _TAGGED_LATER, sorted(set(untagged) - _TAGGED_LATER)
    # the paths the routers' prefixes make are the paths the service always had
    for path in ("/api/params", "/api/record", "/api/records", "/api/records/{name}",
                 "/api/records/{name}/sidecar", "/api/replay", "/api/observer-effects",
                 "/api/uploads", "/api/analyses", "/api/analyses/{job_id}", "/residual",
                 "/residual/{name}/", "/residual/{name}/report.json", "/api/login",
                 "/api/logout", "/api/session"):  # fmt: skip
        assert path in doc["paths"], path
