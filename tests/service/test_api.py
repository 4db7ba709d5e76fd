"""REST API through the real app on a real uvicorn server: every 4xx path with its message."""

from __future__ import annotations

import re
import time
from collections.abc import Iterator

import httpx
import pytest
from _live import OPERATOR, VIEWER, serve
from _wait import poll
from pydantic import ValidationError

from server.errors import CutwatchError
from server.service.app import create_app
from server.service.http_errors import error
from server.service.schemas import ErrorBody
from server.service.settings import Settings


@pytest.fixture(scope="module")
def api() -> Iterator[httpx.Client]:
    with (
        serve(scenario="default", upload_max_mb=1) as hp,
        httpx.Client(base_url=f"http://{hp}", timeout=10) as client,
    ):
        yield client


@pytest.fixture(scope="module")
def locked() -> Iterator[httpx.Client]:
    """A second server, with CUTWATCH_TOKEN set."""
    with (
        serve(scenario="default", token=OPERATOR) as hp,
        httpx.Client(base_url=f"http://{hp}", timeout=10) as c,
    ):
        yield c


def sim_t(api: httpx.Client) -> float:
    return float(api.get("/api/health").json()["sim_t"])


def test_health_reports_loop(api: httpx.Client) -> None:
    deadline = time.monotonic() + 20
    while sim_t(api) < 1.5 and time.monotonic() < deadline:
        time.sleep(0.1)
    h = api.get("/api/health").json()
    assert h["status"] == "ok"
    assert h["viser_port"] == 8080
    assert h["sim_t"] >= 1.5
    # the rate itself is a benchmark (cutwatch bench live), not a test: here only its field
    assert h["realtime_factor"] >= 0.0
    assert h["lag_ms"] >= 0.0 and h["lag_p99_ms"] >= 0.0


def test_scenarios_and_params(api: httpx.Client) -> None:
    sc = api.get("/api/scenarios").json()
    assert sc["current"] == "default" and "default" in sc["scenarios"]
    params = api.get("/api/params").json()
    rpm = params["spindle_rpm"]
    assert rpm["type"] == "number" and rpm["min"] < rpm["value"] < rpm["max"]
    assert params["weight_on"]["type"] == "bool"


def test_patch_changes_value(api: httpx.Client) -> None:
    r = api.patch("/api/params", json={"spindle_rpm": 2400})
    assert r.status_code == 200
    assert r.json()["spindle_rpm"]["value"] == 2400
    assert api.get("/api/params").json()["spindle_rpm"]["value"] == 2400


@pytest.mark.parametrize(
    ("body", "field", "message"),
    [
        (
            {"spindle_rpm": 1e9},
            "spindle_rpm",
            r"spindle_rpm: expected a number in \[600, 6000\] rpm, got 1000000000.0",
        ),
        ({"spindle_rpm": "fast"}, "spindle_rpm", r"expected a number in .* got 'fast'"),
        ({"spindle_rpm": True}, "spindle_rpm", r"expected a number in .* got True"),
        ({"weight_on": 1}, "weight_on", r"weight_on: expected true or false, got 1"),
        ({"bogus": 1}, "bogus", r"unknown parameter 'bogus'; expected one of spindle_rpm"),
        ({}, "body", r"no field given"),
    ],
)
def test_patch_rejects_with_field_range_and_value(
    api: httpx.Client, body: dict[str, object], field: str, message: str
) -> None:
    r = api.patch("/api/params", json=body)
    assert r.status_code == 422
    (err,) = r.json()["detail"]
    assert err["field"] == field
    assert err["allowed"]
    assert re.search(message, err["msg"]), err["msg"]


def test_patch_is_all_or_nothing(api: httpx.Client) -> None:
    before = api.get("/api/params").json()
    r = api.patch(
        "/api/params", json={"weight_on": not before["weight_on"]["value"], "spindle_rpm": -5}
    )
    assert r.status_code == 422
    assert [e["field"] for e in r.json()["detail"]] == ["spindle_rpm"]
    assert api.get("/api/params").json() == before
    t0 = sim_t(api)
    poll(lambda: sim_t(api) > t0, timeout=10)  # the loop kept running (slow under load)


def test_patch_non_finite_number_is_422_not_500(api: httpx.Client) -> None:
    r = api.patch(
        "/api/params", content=b'{"spindle_rpm": NaN}', headers={"content-type": "application/json"}
    )
    assert r.status_code == 422
    assert r.json()["detail"][0]["got"] == "nan"


@pytest.mark.parametrize("content", [b"[1, 2]", b"not json", b'"text"', b"Infinity", b"[NaN]"])
def test_patch_body_not_an_object(api: httpx.Client, content: bytes) -> None:
    r = api.patch("/api/params", content=content, headers={"content-type": "application/json"})
    assert r.status_code == 422
    assert r.json()["detail"][0]["field"] == "body"


def test_body_size_limited(api: httpx.Client) -> None:
    big = b'{"spindle_rpm": 1500, "pad": "' + b"x" * 20000 + b'"}'
    r = api.patch("/api/params", content=big, headers={"content-type": "application/json"})
    assert r.status_code == 413
    (err,) = r.json()["detail"]
    assert err["msg"] == "request body larger than 16384 bytes"
    assert err["field"] == "body" and err["got"] == len(big)

    def chunks() -> Iterator[bytes]:  # no Content-Length: counted as it streams
        yield b'{"pad": "'
        for _ in range(40):
            yield b"x" * 1000
        yield b'"}'

    r = api.patch("/api/params", content=chunks(), headers={"content-type": "application/json"})
    assert r.status_code == 413
    assert r.json()["detail"][0]["msg"] == "request body larger than 16384 bytes"


@pytest.mark.parametrize(
    ("body", "message"),
    [
        (
            {"action": "jump"},
            r"Input should be 'pause', 'resume', 'reset', 'speed', 'scenario', 'inject' or"
            r" 'relearn'",
        ),
        ({"action": "speed"}, r"value: expected a value \(required with action 'speed'\), got"),
        ({"action": "speed", "value": 5000}, r"value: expected a speed in \[0, 1000\], got 5000$"),
        ({"action": "pause", "extra": 1}, r"Extra inputs are not permitted"),
        ({}, r"Field required"),
        (
            {"action": "scenario", "scenario": "mars"},
            r"scenario: expected one of default, .*"
            r"got 'mars'",
        ),
        ({"action": "scenario"}, r"scenario: expected a value \(required with action 'scenario'"),
    ],
)
def test_control_rejects(api: httpx.Client, body: dict[str, object], message: str) -> None:
    r = api.post("/api/control", json=body)
    assert r.status_code == 422
    assert re.search(message, r.json()["detail"][0]["msg"]), r.json()


def test_control_pause_resume_reset_speed(api: httpx.Client) -> None:
    # judged by the loop's schedule, not by how much it computes in a fixed sleep (a
    # loaded box may not step in 0.3 s, nor reach 4x; the rate is cutwatch bench's)
    assert api.post("/api/control", json={"action": "pause"}).json()["paused"] is True
    t0 = sim_t(api)
    time.sleep(0.3)
    assert sim_t(api) == t0  # paused: no block runs after the answer
    assert api.post("/api/control", json={"action": "resume"}).json()["paused"] is False
    poll(lambda: sim_t(api) > t0, 20)
    # reset: t from 0 on the wall clock's schedule, so never ahead of the wall time since
    # (plus one block: a block found due just before the reset may run just after it)
    block_s = Settings().block_ms * 1e-3
    before = time.monotonic()
    api.post("/api/control", json={"action": "reset"})
    t_reset = sim_t(api)
    assert t_reset <= time.monotonic() - before + block_s + 1e-9, t_reset
    # speed 4 from a pause (t fixed, the schedule anchored at the answer): never more than
    # 4x the wall time since, and sooner or later ahead of the wall clock, which 1x is not
    assert api.post("/api/control", json={"action": "pause"}).json()["paused"] is True
    t1 = sim_t(api)
    before = time.monotonic()
    r = api.post("/api/control", json={"action": "speed", "value": 4})
    assert r.json()["speed"] == 4.0 and r.json()["paused"] is False

    def ahead() -> bool:
        ran = sim_t(api) - t1
        wall = time.monotonic() - before
        assert ran <= 4.0 * wall, (ran, wall)
        return ran > wall

    poll(ahead, 30)
    assert api.post("/api/control", json={"action": "speed", "value": 0}).json()["paused"]
    api.post("/api/control", json={"action": "speed", "value": 1})


def test_scenario_switch(api: httpx.Client) -> None:
    r = api.post("/api/control", json={"action": "scenario", "scenario": "seed001-spindle"})
    assert r.status_code == 200 and r.json()["scenario"] == "seed001-spindle"
    assert api.get("/api/scenarios").json()["current"] == "seed001-spindle"
    # its script steps the spindle once at 11 s: the periodic steps' knob is not offered
    params = api.get("/api/params").json()
    assert "spindle_changes" not in params and params["spindle_rpm"]["parts"] == ["simulator"]
    r = api.post("/api/control", json={"action": "scenario", "scenario": "default"})
    assert api.get("/api/health").json()["scenario"] == "default"


def test_snapshot_and_metrics(api: httpx.Client) -> None:
    snap = api.get("/api/snapshot").json()
    assert snap["pipeline"]["scenario"] == "default"
    assert "spindle_rpm" in snap["pipeline"]["knobs"]
    assert snap["health"]["sim_t"] >= 0
    m = api.get("/metrics")
    assert m.headers["content-type"].startswith("text/plain")
    values = {
        line.split()[0]: float(line.split()[1])
        for line in m.text.splitlines()
        if line and not line.startswith("#")
    }
    for name in (
        "cutwatch_loop_lag_seconds",
        "cutwatch_realtime_factor",
        "cutwatch_ws_clients",
        "cutwatch_ws_dropped_frames_total",
    ):
        assert name in values
    assert values["cutwatch_blocks_total"] > 0


def test_accuracy_in_snapshot_and_metrics(api: httpx.Client) -> None:
    from server.pipeline.live_pipeline import FORCE_ESTIMATES

    deadline = time.monotonic() + 20
    while api.get("/api/snapshot").json()["pipeline"]["accuracy"]["span"][0] < 1.0:
        assert time.monotonic() < deadline, "1 s of simulation not reached"
        time.sleep(0.2)
    api.post("/api/control", json={"action": "pause"})
    try:
        time.sleep(0.2)
        acc = api.get("/api/snapshot").json()["pipeline"]["accuracy"]
        text = api.get("/metrics").text
    finally:
        api.post("/api/control", json={"action": "resume"})
    assert acc["mode"] == "truth" and acc["windows"] == [1.0, 10.0]
    assert list(acc["rms"]) == list(acc["rms_q"]) == list(FORCE_ESTIMATES)
    assert acc["span"][0] == pytest.approx(1.0)
    got = {
        m[0]: float(m[1])
        for m in re.findall(r"^cutwatch_force_error_rms\{(.*)\} (\S+)$", text, re.MULTILINE)
    }
    assert "# TYPE cutwatch_force_error_rms gauge" in text
    for est in FORCE_ESTIMATES:
        for j, w in enumerate(("1s", "10s")):
            for table, against in ((acc["rms"], "truth"), (acc["rms_q"], "q_truth")):
                v = table[est][j]
                assert 0.0 < v < 50.0, (est, w, v)  # finite, non-zero errors in N m
                key = f'estimate="{est}",window="{w}",against="{against}"'
                assert got[key] == pytest.approx(v, rel=1e-5)
    assert got['estimate="q_filtered_truth",window="1s",against="truth"'] == pytest.approx(
        acc["floor"][0], rel=1e-5
    )


def test_openapi_lists_every_endpoint(api: httpx.Client) -> None:
    paths = api.get("/openapi.json").json()["paths"]
    for p in (
        "/api/health",
        "/api/scenarios",
        "/api/params",
        "/api/control",
        "/api/snapshot",
        "/api/machine",
        "/metrics",
        "/api/events",
        "/api/events/{event_id}/ack",
        "/api/tool-life",
    ):
        assert p in paths
    assert "patch" in paths["/api/params"]
    assert api.get("/docs").status_code == 200


def test_unknown_route_404(api: httpx.Client) -> None:
    assert api.get("/api/nothing").status_code == 404


def test_token_required_for_reads_and_changes_when_set() -> None:
    with (
        serve(scenario="default", token=OPERATOR, view_token=VIEWER) as hp,
        httpx.Client(base_url=f"http://{hp}") as c,
    ):
        assert c.get("/api/health").status_code == 200  # the one open read
        r = c.get("/api/params")
        assert r.status_code == 401
        (err,) = r.json()["detail"]
        assert err["field"] == "authorization" and r.headers["www-authenticate"] == "Bearer"
        r = c.patch("/api/params", json={"spindle_rpm": 2000})
        assert r.status_code == 401
        r = c.post(
            "/api/control", json={"action": "pause"}, headers={"Authorization": "Bearer wrong"}
        )
        assert r.status_code == 401
        assert "wrong" not in r.text  # the token given is never echoed
        view = {"Authorization": f"Bearer {VIEWER}"}
        assert c.get("/api/params", headers=view).status_code == 200
        r = c.patch("/api/params", json={"spindle_rpm": 2000}, headers=view)
        assert r.status_code == 403 and r.json()["detail"][0]["field"] == "role"
        r = c.patch(
            "/api/params",
            json={"spindle_rpm": 2000},
            headers={"Authorization": f"Bearer {OPERATOR}"},
        )
        assert r.status_code == 200


def test_refuses_public_bind_without_token() -> None:
    with pytest.raises(CutwatchError, match=r"binding to '0.0.0.0' \(not loopback\) requires"):
        create_app(Settings(host="0.0.0.0"))
    create_app(Settings(host="0.0.0.0", token=OPERATOR))  # with a token it builds


def test_unknown_scenario_refused() -> None:
    with pytest.raises(ValidationError, match=r"expected one of default, seed000-weight"):
        Settings(scenario="nope")


JSON_CT = {"content-type": "application/json"}
# (case, method, path, request keywords, status, the field named by the first entry)
ERROR_CASES = [
    ("bad field", "PATCH", "/api/params", {"json": {"spindle_rpm": "fast"}}, 422, "spindle_rpm"),
    ("unknown field", "PATCH", "/api/params", {"json": {"bogus": 1}}, 422, "bogus"),
    ("out of range", "PATCH", "/api/params", {"json": {"spindle_rpm": 1e9}}, 422, "spindle_rpm"),
    ("no field", "PATCH", "/api/params", {"json": {}}, 422, "body"),
    ("not an object", "PATCH", "/api/params", {"content": b"[NaN]", "headers": JSON_CT}, 422,
     "body"),
    ("not JSON", "PATCH", "/api/params", {"content": b"{", "headers": JSON_CT}, 422, "body"),
    ("bad literal", "POST", "/api/control", {"json": {"action": "jump"}}, 422, "action"),
    ("missing field", "POST", "/api/control", {"json": {}}, 422, "action"),
    ("extra field", "POST", "/api/control", {"json": {"action": "pause", "x": 1}}, 422, "x"),
    ("speed out of range", "POST", "/api/control", {"json": {"action": "speed", "value": 5000}},
     422, "value"),
    ("ParameterError", "POST", "/api/observer-effects",
     {"json": {"observer_effects": [{"name": "gremlin", "coef": []}]}}, 422, "name"),
    ("CutwatchError", "POST", "/api/replay", {"json": {"path": "/nonexistent/x.csv"}}, 422,
     "path"),
    ("wrong token", "PATCH", "/api/params",
     {"json": {"spindle_rpm": 2000}, "headers": {"Authorization": "Bearer wrong"}}, 401,
     "authorization"),
    ("no token", "POST", "/api/control", {"json": {"action": "pause"}}, 401, "authorization"),
    ("unknown route", "GET", "/api/nothing", {}, 404, "path"),
    ("wrong method", "DELETE", "/api/health", {}, 405, "method"),
    ("wrong method (static)", "POST", "/index.html", {}, 405, "method"),
    ("oversized body", "PATCH", "/api/params",
     {"content": b"x" * 20000, "headers": JSON_CT}, 413, "body"),
    ("unknown report", "GET", "/residual/nope/", {}, 404, "name"),
    ("unknown report.json", "GET", "/residual/nope/report.json", {}, 404, "name"),
    ("unsafe report name", "GET", "/residual/.hidden/", {}, 404, "name"),
    ("record: no token", "POST", "/api/record", {"json": {"action": "start"}}, 401,
     "authorization"),
    ("upload: no token", "POST", "/api/uploads?name=x.csv", {"content": b"t"}, 401,
     "authorization"),
    ("analysis: no token", "POST", "/api/analyses", {"json": {"log": "x"}}, 401,
     "authorization"),
    ("not recording", "POST", "/api/record", {"json": {"action": "stop"}}, 409, "action"),
    ("unknown recording", "GET", "/api/records/nope.csv", {}, 404, "name"),
    ("unknown log", "POST", "/api/analyses", {"json": {"log": "nope"}}, 422, "name"),
    ("unknown job", "GET", "/api/analyses/nope", {}, 404, "job_id"),
    ("upload name", "POST", "/api/uploads?name=../x.csv", {"content": b"t"}, 422, "name"),
    ("oversized upload", "POST", "/api/uploads?name=x.csv",
     {"content": b"x" * 2_000_001}, 413, "body"),
]  # fmt: skip


@pytest.mark.parametrize(
    ("method", "path", "kw", "status", "field"),
    [c[1:] for c in ERROR_CASES],
    ids=[c[0] for c in ERROR_CASES],
)
def test_every_4xx_has_the_one_body_shape(
    api: httpx.Client,
    locked: httpx.Client,
    method: str,
    path: str,
    kw: dict[str, object],
    status: int,
    field: str,
) -> None:
    client = locked if status == 401 else api
    r = client.request(method, path, **kw)
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == "application/json"
    body = r.json()
    assert list(body) == ["detail"]
    assert isinstance(body["detail"], list) and body["detail"]
    for e in body["detail"]:
        assert set(e) == {"field", "allowed", "got", "msg"}, e
        assert isinstance(e["field"], str) and e["field"]
        assert isinstance(e["allowed"], str) and e["allowed"]
        assert isinstance(e["msg"], str) and e["msg"]
    ErrorBody.model_validate(body)
    assert body["detail"][0]["field"] == field
    if status == 405:
        assert body["detail"][0]["got"] == method
        allow = "GET" if path.startswith("/api/") else "GET, HEAD"  # a route, a static file
        assert r.headers["allow"] == allow and body["detail"][0]["allowed"] == f"one of {allow}"
    if status == 401:
        assert r.headers["www-authenticate"] == "Bearer"
        assert "wrong" not in r.text


def test_openapi_documents_every_response(api: httpx.Client) -> None:
    spec = api.get("/openapi.json").json()
    schemas = spec["components"]["schemas"]
    error_ref = {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorBody"}}}
    ops = [(p, m, op) for p, ms in spec["paths"].items() for m, op in ms.items()]
    # 13 paths before the data routes; /api/params has GET and PATCH, effects GET/POST/DELETE;
    # + record, records (list, CSV, sidecar), uploads (POST, GET), analyses (POST, GET, GET id)
    # + login, logout, session; + the history: events (GET), ack (POST), tool-life (GET)
    # + the machine (GET /api/machine); + the axes' model (GET, POST, DELETE /api/axis-model)
    # + a measured flank wear entered at a tool change (POST /api/tool-life/vb)
    assert len(ops) == 34
    assert ("/api/tool-life/vb", "post") in {(p, m) for p, m, _ in ops}
    for p, m, op in ops:
        where = f"{m.upper()} {p}"
        ok = [c for c in op["responses"] if c.startswith("2")]
        assert ok, where
        for c in ok:
            content = op["responses"][c]["content"]
            assert content, where
            for media, entry in content.items():
                schema = entry.get("schema")
                assert schema, (where, media)  # not missing, not {}
                if "$ref" in schema:
                    target = schemas[schema["$ref"].rsplit("/", 1)[-1]]
                    assert target.get("properties") or target.get("additionalProperties"), where
        errors = {c: r for c, r in op["responses"].items() if c.startswith("4")}
        assert "4XX" in errors, where
        for c, r in errors.items():
            assert r["content"] == error_ref, (where, c)
        assert {"400", "401", "403"} <= set(errors), where  # Host, credentials, role/Origin
        if "requestBody" in op:
            assert {"413", "422"} <= set(errors), where
            media = "application/octet-stream" if p == "/api/uploads" else "application/json"
            assert op["requestBody"]["content"][media]["schema"], where
    assert set(schemas["ErrorItem"]["properties"]) == {"field", "allowed", "got", "msg"}
    assert "HTTPValidationError" not in schemas  # FastAPI's own 422 shape is not offered


def test_error_entry_got_is_json() -> None:
    import numpy as np

    assert error("x", "a number", np.float64(2.5), "m")["got"] == 2.5  # not "np.float64(2.5)"
    assert error("x", "a number", np.int64(3), "m")["got"] == 3
    # a client's NaN is echoed as "nan", not null (null would read as "you sent null")
    assert error("x", "a number", float("nan"), "m")["got"] == "nan"
    assert error("x", "a number", None, "m")["got"] is None
    assert error("x", "a list", np.zeros(2), "m")["got"] == "array([0., 0.])"
