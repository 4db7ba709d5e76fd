"""Issue 27: the doors a probe found open, each closed in every process that has it.

One module-wide plant on loopback: a real Mosquitto, ``cutwatch serve`` (with viser, for
its WebSocket relay), a plant's worker (``create_worker_app`` on a real uvicorn, its data
directory holding a checkpoint it must refuse) and a real ``cutwatch fleet`` process, all
three with the service's two tokens. Each test is one finding of the issue:

1. the fleet page had no access control, no Host allow-list, no Origin check, no headers;
2. the fleet took a row's machine and its link from the message's body;
3. the worker answered its checkpoints' absolute paths;
4. a request with two ``Host`` headers passed when the first was allowed;
5. a JSON body in UTF-16 was parsed (and paused the loop);
6. the Origin check ignored the scheme;
7. the npm tree (``package.json``, ``node_modules/``) was served;
8. a client leaving a WebSocket was logged as an ERROR with two tracebacks (it was the
   dashboard's ``/viser`` relay, whose close after the browser had gone raised); a
   refused upgrade was an ERROR line too (uvicorn's websockets-sansio).
"""

from __future__ import annotations

import json
import logging
import socket
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import paho.mqtt.client as mqtt
import pytest
from _broker import broker, free_port
from _live import OPERATOR, VIEWER, fleet_process, serve, serve_asgi
from _wait import poll
from pydantic import SecretStr
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from server.pipeline.broker import parse_broker_url
from server.pipeline.worker import Worker, WorkerConfig
from server.records.drive_wire import encode_estimates, encode_meta
from server.service.settings import Settings
from server.service.worker_app import create_worker_app

VIEW = {"Authorization": f"Bearer {VIEWER}"}
OP = {"Authorization": f"Bearer {OPERATOR}"}
META = {
    "kind": "two_inertia",
    "sample_time": 4e-4,
    "units": {"effort": "N m", "position": "rad"},
    "nominal": {"J_M": 2.8e-4, "J_L": 2.8e-4, "K": 900.0, "K_t": 0.571, "B_M": 2e-3,
                "B_L": 2e-3, "F_CM": 0.15, "F_CL": 0.15},
}  # fmt: skip


@dataclass
class Plant:
    service: str  # host:port of each
    fleet: str
    worker: str
    broker: int
    data: Path  # the worker's data directory
    fleet_log: Callable[[], str]  # what the fleet process has written


def shaped(r: httpx.Response) -> dict[str, Any]:
    """The refusal's one entry, checked to be the service's one error shape."""
    assert r.status_code < 500, r.text
    body = r.json()
    assert set(body) == {"detail"} and len(body["detail"]) == 1, body
    item: dict[str, Any] = body["detail"][0]
    assert set(item) == {"field", "allowed", "got", "msg"}, item
    return item


def publisher(port: int) -> mqtt.Client:
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    c.connect("127.0.0.1", port)
    c.loop_start()
    return c


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plant]:
    data = tmp_path_factory.mktemp("worker-data")
    (data / "state").mkdir()
    (data / "state" / "mine.npz").write_bytes(b"not a checkpoint")  # refused, named
    tokens = {"token": SecretStr(OPERATOR), "view_token": SecretStr(VIEWER)}
    with broker() as bp:
        url = f"mqtt://127.0.0.1:{bp}"
        pub = publisher(bp)
        pub.publish("cutwatch/mine/meta", encode_meta(META), qos=1, retain=True).wait_for_publish()
        pub.loop_stop()
        pub.disconnect()
        w = Worker(
            parse_broker_url(url),
            WorkerConfig(machines=frozenset({"mine"}), data_dir=data, checkpoint_s=60),
        )
        settings = Settings(**tokens)  # type: ignore[arg-type]
        with (
            serve(scenario="default", token=OPERATOR, view_token=VIEWER,
                  data_dir=tmp_path_factory.mktemp("svc"), viser=True,
                  viser_port=free_port()) as svc,
            serve_asgi(create_worker_app(w, settings), settings) as wk,
            fleet_process("--broker", url, "--stale-after", "30",
                          CUTWATCH_TOKEN=OPERATOR, CUTWATCH_VIEW_TOKEN=VIEWER) as fl,
        ):  # fmt: skip
            yield Plant(svc, fl.host, wk, bp, data, fl.output)


def raw_get(hp: str, path: str, *headers: str) -> tuple[int, bytes]:
    """``GET path`` with exactly these header lines (httpx would merge two Hosts)."""
    host, port = hp.split(":")
    lines = [f"GET {path} HTTP/1.1", *headers, "Connection: close", "", ""]
    with socket.create_connection((host, int(port)), timeout=10) as s:
        s.sendall("\r\n".join(lines).encode())
        got = b""
        while chunk := s.recv(65536):
            got += chunk
    head, _, body = got.partition(b"\r\n\r\n")
    return int(head.split()[1]), body


# ------------------------------------------------------------------ 1. the fleet's doors
def test_the_fleet_page_has_the_services_access_model(plant: Plant) -> None:
    base = f"http://{plant.fleet}"
    for path in ("/", "/fleet.js", "/api/fleet", "/metrics", "/openapi.json", "/docs"):
        r = httpx.get(base + path, timeout=10)
        assert r.status_code == 401, (path, r.status_code)
        assert shaped(r)["field"] == "authorization"
        assert httpx.get(base + path, headers=VIEW, timeout=10).status_code == 200, path
    page = httpx.get(base + "/", headers={"accept": "text/html"}, timeout=10)
    assert page.status_code == 303 and page.headers["location"] == "/login"
    for path in ("/login", "/login.js", "/style.css", "/api/health"):  # public
        assert httpx.get(base + path, timeout=10).status_code == 200, path
    with pytest.raises(InvalidStatus) as exc:
        connect(f"ws://{plant.fleet}/ws", open_timeout=10)
    assert exc.value.response.status_code == 401
    with pytest.raises(InvalidStatus) as exc:  # a viewer's credential, another site's page
        connect(f"ws://{plant.fleet}/ws", additional_headers={**VIEW,
                "Origin": "http://evil.example"}, open_timeout=10)  # fmt: skip
    assert exc.value.response.status_code == 403
    own = {**VIEW, "Origin": base}
    with connect(f"ws://{plant.fleet}/ws", additional_headers=own, open_timeout=10) as ws:
        assert "rows" in json.loads(ws.recv(timeout=10))
    # DNS rebinding: another name for this address
    r = httpx.get(base + "/api/fleet", headers={**VIEW, "Host": "rebind.attacker.example"})
    assert r.status_code == 400 and shaped(r)["field"] == "host"
    for path in ("/", "/api/fleet", "/login"):
        h = httpx.get(base + path, headers=VIEW, timeout=10).headers
        assert h["x-frame-options"] == "DENY" and h["x-content-type-options"] == "nosniff"
        assert "frame-ancestors 'none'" in h["content-security-policy"]


# ------------------------------------------------------------------ 2. the fleet's trust
def test_a_fleet_row_is_its_topics_machine_and_never_a_scripts_link(plant: Plant) -> None:
    base = f"http://{plant.fleet}"
    malformed0 = _metric(base, "cutwatch_fleet_malformed_total")
    pub = publisher(plant.broker)
    try:
        forged = {"wall": time.time(), "dashboard": "javascript:alert(document.domain)"}
        # mill-9's topic, a body that says mill-7 (the probe's message)
        body = json.loads(encode_estimates("mill-7", forged))
        pub.publish("cutwatch/mill-9/estimates", json.dumps(body).encode())
        ev = {"schema": "cutwatch.event", "version": 1, "id": "e1", "kind": "breakage",
              "action": "feed_hold", "t": 1.0, "tool": 1, "program": "", "line": 0,
              "part": -1, "value": None, "limit": None, "unit": "", "message": "forged",
              "machine": "mill-7"}  # fmt: skip
        pub.publish("cutwatch/mill-9/events", json.dumps(ev).encode(), qos=1)
        # a machine's own message whose link is a script
        pub.publish("cutwatch/mill-8/estimates", encode_estimates("mill-8", forged))
        pub.publish("cutwatch/mill-9/estimates", encode_estimates("mill-9", {"wall": 1.0}))
        rows = poll(lambda: _rows_with(base, {"mill-8", "mill-9"}), 15)
    finally:
        pub.loop_stop()
        pub.disconnect()
    names = {r["machine"] for r in rows}
    assert "mill-7" not in names, rows
    assert all(r["dashboard"] is None for r in rows), rows
    assert next(r for r in rows if r["machine"] == "mill-9")["event"] is None
    poll(lambda: _metric(base, "cutwatch_fleet_malformed_total") >= malformed0 + 2, 10)


def _rows_with(base: str, names: set[str]) -> list[dict[str, Any]] | None:
    rows: list[dict[str, Any]] = httpx.get(base + "/api/fleet", headers=VIEW).json()
    return rows if names <= {r["machine"] for r in rows} else None


def _metric(base: str, name: str) -> float:
    text = httpx.get(base + "/metrics", headers=VIEW, timeout=10).text
    return float(next(ln.split()[1] for ln in text.splitlines() if ln.startswith(name + " ")))


# ------------------------------------------------------------------ 3. server paths
def test_no_worker_answer_carries_a_server_path(plant: Plant) -> None:
    base = f"http://{plant.worker}"

    def built() -> list[dict[str, Any]] | None:
        ms: list[dict[str, Any]] = httpx.get(base + "/api/machines", headers=VIEW).json()
        return ms if ms and ms[0]["checkpoint"] else None

    machines = poll(built, 60)
    cp = machines[0]["checkpoint"]
    assert cp["file"] == "state/mine.npz" and not cp["resumed"] and cp["refused"], cp
    roots = {str(plant.data), str(plant.data.resolve()), str(Path.cwd())}
    for path in ("/api/health", "/api/machines", "/api/machines/mine", "/m/mine/",
                 "/metrics", "/api/machines/nope", "/nothing", "/openapi.json"):  # fmt: skip
        text = httpx.get(base + path, headers=VIEW, timeout=10).text
        assert not [r for r in roots if r in text], (path, text[:2000])


# ------------------------------------------------------------------ 4. two Host headers
def test_a_repeated_host_header_is_refused_in_every_process(plant: Plant) -> None:
    auth = f"Authorization: Bearer {VIEWER}"
    for hp, path in ((plant.service, "/api/params"), (plant.fleet, "/api/fleet"),
                     (plant.worker, "/api/machines")):  # fmt: skip
        status, _ = raw_get(hp, path, f"Host: {hp}", auth)
        assert status == 200, (hp, path)
        for second in ("evil.example", hp):
            status, body = raw_get(hp, path, f"Host: {hp}", f"Host: {second}", auth)
            assert status == 400, (hp, path, second, status)
            item = json.loads(body)["detail"][0]
            assert item["field"] == "host" and "one Host header" in item["allowed"], item


# ------------------------------------------------------------------ 5. charsets
def test_a_json_body_in_another_charset_is_refused_naming_it(plant: Plant) -> None:
    base = f"http://{plant.service}"
    pause = '{"action": "pause"}'
    cases = [
        (pause.encode("utf-16"), "application/json", "utf-16le"),
        (pause.encode("utf-16-be"), "application/json", "utf-16be"),
        (pause.encode("utf-32"), "application/json", "utf-32le"),
        (pause.encode("utf-16"), "application/json; charset=utf-16", "utf-16"),
        (pause.encode(), "application/json; charset=iso-8859-1", "iso-8859-1"),
        (pause.encode(), 'text/plain; charset="Shift_JIS"', "shift_jis"),
    ]
    for body, ctype, found in cases:
        r = httpx.post(base + "/api/control", content=body,
                       headers={**OP, "content-type": ctype}, timeout=10)  # fmt: skip
        assert r.status_code == 415, (ctype, r.status_code, r.text)
        item = shaped(r)
        assert item["field"] == "charset" and str(item["got"]).lower() == found, item
        assert "utf-8" in item["allowed"].lower() and found in item["msg"].lower(), item
    assert httpx.get(base + "/api/health", timeout=10).json()["paused"] is False
    for ctype in ("application/json", "application/json; charset=UTF-8",
                  'application/json; charset="utf-8"'):  # fmt: skip
        r = httpx.post(base + "/api/control", content=b'{"action": "resume"}',
                       headers={**OP, "content-type": ctype}, timeout=10)  # fmt: skip
        assert r.status_code == 200, (ctype, r.text)


# ------------------------------------------------------------------ 6. Origin's scheme
def test_the_origin_check_compares_scheme_host_and_port(plant: Plant) -> None:
    base = f"http://{plant.service}"
    port = plant.service.split(":")[1]
    for origin in (f"https://{plant.service}", "http://127.0.0.1", f"http://127.0.0.1:{port}0",
                   f"ws://{plant.service}"):  # fmt: skip
        r = httpx.post(base + "/api/control", json={"action": "resume"},
                       headers={**OP, "Origin": origin}, timeout=10)  # fmt: skip
        assert r.status_code == 403 and shaped(r)["field"] == "origin", (origin, r.text)
        with pytest.raises(InvalidStatus) as exc:
            connect(f"ws://{plant.service}/ws", additional_headers={**VIEW, "Origin": origin},
                    open_timeout=10)  # fmt: skip
        assert exc.value.response.status_code == 403, origin
    for origin in (base, f"HTTP://127.0.0.1:{port}", f"http://localhost:{port}"):
        host = origin.split("//")[1].lower()
        r = httpx.post(base + "/api/control", json={"action": "resume"},
                       headers={**OP, "Origin": origin, "Host": host}, timeout=10)  # fmt: skip
        assert r.status_code == 200, (origin, r.text)


# ------------------------------------------------------------------ 7. the npm tree
def test_only_the_pages_own_files_are_served(plant: Plant) -> None:
    npm = ("/package.json", "/package-lock.json", "/node_modules/uplot/package.json",
           "/node_modules/uplot/dist/uPlot.iife.min.js", "/node_modules/.package-lock.json",
           "/vendor/uplot/uPlot.esm.js", "/vendor/uplot/uPlot.d.ts", "/vendor/uplot/")  # fmt: skip
    others = {plant.service: ("/fleet.html", "/fleet.js", "/machine.html", "/machine.js"),
              plant.fleet: ("/index.html", "/app.js", "/machine.js", "/fleet.html"),
              plant.worker: ("/", "/index.html", "/fleet.js", "/machine.html")}  # fmt: skip
    for hp, theirs in others.items():
        for path in npm + theirs:
            r = httpx.get(f"http://{hp}{path}", headers=VIEW, timeout=10)
            assert r.status_code == 404, (hp, path, r.status_code)
            assert shaped(r)["field"] == "path"
    own = ("/", "/index.html", "/app.js", "/charts.js", "/loop.js", "/panels.js", "/monitor.js",
           "/protocol.js", "/schema.js", "/style.css", "/login", "/login.js",
           "/vendor/uplot/uPlot.iife.min.js", "/vendor/uplot/uPlot.min.css")  # fmt: skip
    for path in own:
        r = httpx.get(f"http://{plant.service}{path}", headers=VIEW, timeout=10)
        assert r.status_code == 200 and r.content, (path, r.status_code)


# ------------------------------------------------------------------ 8. a normal close
class _Records(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@pytest.fixture
def server_log() -> Iterator[_Records]:
    """What the servers in this process log (uvicorn's and cutwatch's loggers)."""
    h = _Records()
    names = ("uvicorn.error", "cutwatch")
    levels = {n: logging.getLogger(n).level for n in names}
    for n in names:
        logging.getLogger(n).addHandler(h)
    logging.getLogger("cutwatch.ws").setLevel(logging.DEBUG)
    try:
        yield h
    finally:
        for n in names:
            logging.getLogger(n).removeHandler(h)
            logging.getLogger(n).setLevel(levels[n])
        logging.getLogger("cutwatch.ws").setLevel(logging.NOTSET)


def test_a_client_leaving_a_websocket_is_logged_at_debug(
    plant: Plant, server_log: _Records
) -> None:
    import viser

    sub = [f"viser-v{viser.__version__}"]
    # the service's viser relay last: its leave is what the poll below waits for, so the
    # other endpoints' closes come before it
    for hp, path, kw in ((plant.fleet, "/ws", {}), (plant.service, "/ws", {}),
                         (plant.service, "/viser", {"subprotocols": sub})):  # fmt: skip
        for abrupt in (False, True):
            # generous deadlines for the first message (10 s ran out once at load 14-19)
            ws = connect(f"ws://{hp}{path}", additional_headers=VIEW, open_timeout=30, **kw)
            ws.recv(timeout=30)
            if abrupt:  # the browser's process killed: no close frame
                ws.socket.shutdown(socket.SHUT_RDWR)
                ws.socket.close()
            else:
                ws.close()
        with pytest.raises(InvalidStatus):  # a refusal is an answer, not an error either
            connect(f"ws://{hp}{path}", open_timeout=10, **kw)
    # the servers notice and end the connections: until the service has logged the viser
    # relay's clients leaving, both of them (the abrupt one was the last close made; was a
    # fixed 1.5 s, short for a loaded box)
    poll(lambda: sum("/viser" in r.getMessage() for r in server_log.records
                     if r.name == "cutwatch.ws") >= 2, 30)  # fmt: skip
    bad = [f"{r.name} {r.levelname}: {r.getMessage()}" for r in server_log.records
           if r.levelno >= logging.ERROR]  # fmt: skip
    assert not bad, bad
    left = [r for r in server_log.records if r.name == "cutwatch.ws"]
    assert left and all(r.levelno == logging.DEBUG for r in left), left
    assert any("/viser" in r.getMessage() for r in left)
    fleet = plant.fleet_log()  # the fleet process's own log
    assert "Traceback" not in fleet and "ERROR" not in fleet, fleet[-3000:]
