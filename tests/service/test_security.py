"""The probes of the security review (issue 20), rerun against real servers, each with
its numbers: bad input answered in the one shape, bad uploads refused and removed, a
.mat bomb and a large upload measured on a ``cutwatch serve`` process, every read
refused without a credential, the browser's session, Host and Origin checks, bind
checks, and a recording's temporary file cleaned after a SIGKILL.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from itertools import pairwise
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from _live import OPERATOR, VIEWER, serve, serve_process
from _wait import poll
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from common.errors import ParameterError
from server.errors import CutwatchError
from server.experiments.benchmarks.bench_upload import rigid_log
from server.records.data_areas import check_name
from server.service.app import create_app
from server.service.settings import Settings, check_security, is_loopback
from server.service.upload_check import Refused, mat_expanded_size

OP = {"Authorization": f"Bearer {OPERATOR}"}
SIDECAR = {"sample_time": 0.001, "units": {"effort": "N m", "position": "rad"}, "kind": "rigid"}


def shaped(r: httpx.Response) -> list[dict[str, Any]]:
    """The refusal's entries, checked to be the one error shape."""
    assert r.status_code < 500, r.text
    body = r.json()
    assert set(body) == {"detail"} and body["detail"], body
    for item in body["detail"]:
        assert set(item) == {"field", "allowed", "got", "msg"}, item
    items: list[dict[str, Any]] = body["detail"]
    return items


# ------------------------------------------------------------------ request bodies
@pytest.fixture(scope="module")
def locked(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[httpx.Client, Path]]:
    """A server with both tokens; its data directory."""
    data = tmp_path_factory.mktemp("data")
    with (
        serve(scenario="default", token=OPERATOR, view_token=VIEWER, data_dir=data) as hp,
        httpx.Client(base_url=f"http://{hp}", timeout=60) as c,
    ):
        yield c, data


JSON_ROUTES = [("POST", "/api/control"), ("PATCH", "/api/params"), ("POST", "/api/replay"),
               ("POST", "/api/observer-effects"), ("POST", "/api/record"),
               ("POST", "/api/analyses"), ("POST", "/api/login")]  # fmt: skip
FIELDS = ["action", "value", "scenario", "name", "report", "log", "token", "spindle_rpm"]


def _probe_bodies() -> list[bytes]:
    out = []
    for f in FIELDS:
        out.append(json.dumps({f: "\ud800"}).encode())  # a lone surrogate (escaped)
        out.append(b'{"' + f.encode() + b'": ' + b"[" * 485 + b"]" * 485 + b"}")  # deep
        out.append(b'{"' + f.encode() + b'": ' + b"9" * 400 + b"}")  # a huge integer
        out.append(json.dumps({f: [1, {"a": None}]}).encode())  # a wrong type
    out += [b"[" * 5000 + b"]" * 5000, b'{"\\udfff": 1}', b"\xff\xfe{", b'"\\ud800"']
    return out


def test_bodies_that_gave_500_are_refused_in_the_shape(locked: tuple[httpx.Client, Path]) -> None:
    c, _ = locked
    sent = fivexx = 0
    for method, path in JSON_ROUTES:
        for body in _probe_bodies():
            r = c.request(
                method, path, content=body, headers={**OP, "content-type": "application/json"}
            )
            sent += 1
            fivexx += r.status_code >= 500
            assert 400 <= r.status_code < 500, (path, body[:40], r.text)
            shaped(r)
    # the knob of the issue: 1e400 written as an integer
    r = c.patch("/api/params", content=b'{"spindle_rpm": 1' + b"0" * 400 + b"}",
                headers={**OP, "content-type": "application/json"})  # fmt: skip
    (item,) = shaped(r)
    assert r.status_code == 422 and item["field"] == "spindle_rpm"
    assert item["got"] == "an integer of about 401 digits"
    print(f"probe bodies: {sent + 1} requests, {fivexx} 5xx")
    assert fivexx == 0


def test_head_of_a_missing_path_has_the_error_headers(locked: tuple[httpx.Client, Path]) -> None:
    r = locked[0].head("/nothing-here", headers=OP)
    assert r.status_code == 404 and r.headers["content-type"] == "application/json"
    assert int(r.headers["content-length"]) > 0  # the GET's body length: the shape exists
    assert shaped(locked[0].get("/nothing-here", headers=OP))[0]["field"] == "path"


# ------------------------------------------------------------------ uploads
BAD_UPLOADS = [
    ("latin.csv", b"t,tau_m,q_m\n0,1,\xe9\n0.001,1,2\n", "not UTF-8 text"),
    ("u16.json", json.dumps(SIDECAR).encode("utf-16"), "not UTF-8 text"),
    ("deep.json", b'{"units": ' + b"[" * 100000 + b"]" * 100000 + b"}", "nested too deep"),
    ("ulist.json", json.dumps({**SIDECAR, "units": ["N m", "rad"]}).encode(), "'units'"),
    ("udict.json", json.dumps({**SIDECAR, "units": {"effort": {}}}).encode(), "'units'"),
    ("tstr.json", json.dumps({**SIDECAR, "sample_time": "1ms"}).encode(), "'sample_time'"),
    ("tlist.json", json.dumps({**SIDECAR, "sample_time": [0.001]}).encode(), "'sample_time'"),
    ("tbig.json", b'{"sample_time": 1' + b"0" * 400 + b"}", "'sample_time'"),
    ("kind.json", json.dumps({**SIDECAR, "kind": 3}).encode(), "'kind'"),
    ("v73.mat", b"MATLAB 7.3 MAT-file".ljust(124, b" ") + b"\x00\x02IM" + b"\x00" * 64, "v7.3"),
    ("short.mat", b"MATLAB 5.0", "not a MATLAB .mat file"),
]


def test_bad_uploads_are_refused_named_removed_and_not_listed(
    locked: tuple[httpx.Client, Path],
) -> None:
    c, data = locked
    sent = 0
    for name, body, why in BAD_UPLOADS:
        for _ in range(2):  # replaying it gets the same answer, not a 500
            r = c.post("/api/uploads", params={"name": name}, content=body, headers=OP)
            sent += 1
            (item,) = shaped(r)
            assert r.status_code == 422, (name, r.text)
            assert why in item["msg"] and name in item["msg"], (name, item["msg"])
            assert str(data) not in item["msg"]
        assert not (data / "uploads" / name).exists()
    listed = {u["name"] for u in c.get("/api/uploads", headers=OP).json()["uploads"]}
    assert listed == set() and not any((data / ".quarantine").iterdir())
    print(f"bad uploads: {sent} requests, 0 5xx, 0 files kept")


def test_mat_headers_give_the_expanded_size(tmp_path: Path) -> None:
    import scipy.io

    cols = {"t": np.arange(5000) * 1e-3, "tau_m": np.zeros(5000), "q_m": np.ones(5000)}
    for compress in (False, True):  # v5: element headers, compressed or not
        p = tmp_path / f"v5{compress}.mat"
        scipy.io.savemat(p, {**cols, "z": np.ones(3) + 1j}, do_compression=compress)
        assert mat_expanded_size(p, 10**9) > 3 * 5000 * 8  # the three columns at least
    p = tmp_path / "v4.mat"
    scipy.io.savemat(p, cols, format="4")  # no compression: its own size
    assert mat_expanded_size(p, 10**9) == p.stat().st_size
    p = tmp_path / "zeros.mat"  # 16 MB of zeros in a few kB
    scipy.io.savemat(p, {"t": np.zeros(2_000_000)}, do_compression=True)
    assert p.stat().st_size < 100_000
    with pytest.raises(Refused, match="expand to more than 1000000 bytes"):
        mat_expanded_size(p, 10**6)


def test_a_mat_log_and_its_sidecar_are_checked_together(
    locked: tuple[httpx.Client, Path], tmp_path: Path
) -> None:
    import scipy.io

    c, data = locked
    t = np.arange(5000) * 1e-3
    p = tmp_path / "m.mat"
    scipy.io.savemat(p, {"t": t, "tau_m": np.sin(t), "q_m": np.cos(t)}, do_compression=True)
    # the log first: no units yet, refused; the sidecar, then the log: both published
    r = c.post("/api/uploads", params={"name": "m.mat"}, content=p.read_bytes(), headers=OP)
    assert r.status_code == 422 and "units not declared" in shaped(r)[0]["msg"]
    side = json.dumps(SIDECAR).encode()
    assert c.post("/api/uploads", params={"name": "m.json"}, content=side,
                  headers=OP).status_code == 200  # fmt: skip
    r = c.post("/api/uploads", params={"name": "m.mat"}, content=p.read_bytes(), headers=OP)
    assert r.status_code == 200 and r.json()["samples"] == 5000, r.text
    assert (data / "uploads" / "m.mat").is_file()


def test_a_csv_with_too_many_columns_is_refused_before_parsing(
    locked: tuple[httpx.Client, Path],
) -> None:
    header = ",".join(["t", "tau_m", "q_m"] + [f"c{i}" for i in range(100)])
    r = locked[0].post("/api/uploads", params={"name": "wide.csv"},
                       content=(header + "\n").encode(), headers=OP)  # fmt: skip
    (item,) = shaped(r)
    assert "103 columns in the header; at most 64" in item["msg"]


def test_names_are_matched_whole(locked: tuple[httpx.Client, Path]) -> None:
    assert not check_name("nl\n") and not check_name("x.csv\n") and check_name("nl")
    c, data = locked
    r = c.post("/api/analyses", json={"log": "x", "report": "nl\n"}, headers=OP)
    assert r.status_code == 422
    r = c.post("/api/uploads", params={"name": "x.csv\n"}, content=b"t", headers=OP)
    assert shaped(r)[0]["field"] == "name" and r.status_code == 422
    assert not (data / "reports" / "nl\n").exists()


def test_no_server_path_in_answers(locked: tuple[httpx.Client, Path]) -> None:
    c, data = locked
    for path in ("/residual/nope/", "/residual/nope/report.json", "/api/records/nope.csv"):
        r = c.get(path, headers=OP)
        assert r.status_code == 404 and str(data) not in r.text, r.text
    page = c.get("/residual", headers=OP).text
    assert str(data) not in page and "<h1>Residual reports</h1>" in page


# ------------------------------------------------------------------ access
def test_every_read_is_refused_without_a_credential(locked: tuple[httpx.Client, Path]) -> None:
    c, _ = locked
    spec = c.get("/openapi.json", headers=OP).json()
    gets = [p.replace("{name}", "x").replace("{job_id}", "x")
            for p, ms in spec["paths"].items() if "get" in ms]  # fmt: skip
    gets += ["/", "/index.html", "/app.js", "/loop.js", "/fleet.html", "/docs", "/openapi.json",
             "/vendor/uplot/uPlot.iife.min.js"]  # fmt: skip
    public = {"/api/health", "/api/session"}
    refused = 0
    for p in gets:
        if p in public:
            assert c.get(p).status_code == 200
            continue
        r = c.get(p)
        assert r.status_code == 401, (p, r.status_code)
        assert shaped(r)[0]["field"] == "authorization"
        assert c.get(p, headers={"Authorization": "Bearer wrong-token-wrong"}).status_code == 401
        assert c.get(p, headers={"Authorization": f"Bearer {VIEWER}"}).status_code != 401, p
        refused += 1
    # a browser asking for the page is sent to the login page
    r = c.get("/", headers={"accept": "text/html"})
    assert r.status_code == 303 and r.headers["location"] == "/login"
    assert c.get("/login").status_code == 200 and c.get("/login.js").status_code == 200
    host = str(c.base_url).removeprefix("http://").rstrip("/")
    with pytest.raises(InvalidStatus) as exc:
        connect(f"ws://{host}/ws", open_timeout=5)
    assert exc.value.response.status_code == 401
    print(f"reads without a credential: {refused} of {len(gets) - len(public)} refused (401)")
    assert refused == len(gets) - len(public)


def test_viewer_reads_and_streams_operator_changes(locked: tuple[httpx.Client, Path]) -> None:
    c, _ = locked
    view = {"Authorization": f"Bearer {VIEWER}"}
    host = str(c.base_url).removeprefix("http://").rstrip("/")
    with connect(f"ws://{host}/ws", additional_headers=view, open_timeout=5) as ws:
        assert json.loads(ws.recv(timeout=5))["type"] == "hello"
    for method, path, body in [("POST", "/api/control", {"action": "pause"}),
                               ("PATCH", "/api/params", {"spindle_rpm": 2000}),
                               ("POST", "/api/record", {"action": "start"}),
                               ("DELETE", "/api/observer-effects", None)]:  # fmt: skip
        r = c.request(method, path, json=body, headers=view)
        assert r.status_code == 403 and shaped(r)[0]["field"] == "role", (path, r.text)
    r = c.post("/api/uploads", params={"name": "v.json"}, content=b"{}", headers=view)
    assert r.status_code == 403


def test_browser_session_cookie(locked: tuple[httpx.Client, Path]) -> None:
    c, _ = locked
    base = str(c.base_url).rstrip("/")
    host = base.removeprefix("http://")
    with httpx.Client(base_url=base, timeout=60) as b:
        r = b.post("/api/login", json={"token": "not-the-token-at-all"})
        assert r.status_code == 401 and "set-cookie" not in r.headers
        r = b.post("/api/login", json={"token": VIEWER}, headers={"origin": base})
        assert r.status_code == 200 and r.json() == {"role": "viewer", "access_control": True}
        cookie = r.headers["set-cookie"].lower()
        assert "httponly" in cookie and "samesite=strict" in cookie and "path=/" in cookie
        assert VIEWER not in r.headers["set-cookie"]  # a random session id, not the token
        assert b.get("/api/params").status_code == 200  # the cookie reads
        assert b.post("/api/control", json={"action": "pause"}).status_code == 403
        sid = b.cookies["cutwatch_session"]
        hdr = {"Cookie": f"cutwatch_session={sid}"}
        with connect(f"ws://{host}/ws", additional_headers={**hdr, "Origin": base}) as ws:
            assert json.loads(ws.recv(timeout=60))["type"] == "hello"
        with pytest.raises(InvalidStatus) as exc:  # the cookie from another site's page
            connect(f"ws://{host}/ws", additional_headers={**hdr, "Origin": "http://evil.example"})
        assert exc.value.response.status_code == 403
        assert b.post("/api/logout", headers={"origin": base}).status_code == 200
        assert httpx.get(f"{base}/api/params", headers=hdr).status_code == 401  # ended


def test_audit_line_for_every_state_change(
    locked: tuple[httpx.Client, Path], caplog: pytest.LogCaptureFixture
) -> None:
    c, _ = locked
    with caplog.at_level(logging.INFO, logger="cutwatch.audit"):
        assert c.patch("/api/params", json={"spindle_rpm": 2400}, headers=OP).status_code == 200
        assert c.post("/api/control", json={"action": "pause"}).status_code == 401
        c.get("/api/params", headers=OP)  # a read: no audit line
        poll(lambda: len(caplog.records) >= 2, 60, 0.05)
    lines = [r.getMessage() for r in caplog.records if r.name == "cutwatch.audit"]
    assert len(lines) == 2, lines
    assert "role=operator PATCH '/api/params' status=200" in lines[0]
    assert "spindle_rpm" in lines[0] and "2400" in lines[0]
    assert "role=- POST '/api/control' status=401 change=" in lines[1]
    assert "refused: this request needs 'Authorization: Bearer <token>'" in lines[1]


def test_host_origin_and_headers_on_the_open_loopback_service(tmp_path: Path) -> None:
    with (
        serve(scenario="default", data_dir=tmp_path) as hp,
        httpx.Client(base_url=f"http://{hp}", timeout=60) as c,
    ):
        # DNS rebinding: another name for this address
        r = c.post("/api/control", json={"action": "pause"}, headers={"Host": "attacker.example"})
        assert r.status_code == 400 and shaped(r)[0]["field"] == "host"
        # a page elsewhere posting a "simple" request (no preflight) must not write
        evil = {"Origin": "http://attacker.example", "content-type": "text/plain"}
        r = c.post("/api/uploads", params={"name": "x.json"}, content=b"{}", headers=evil)
        assert r.status_code == 403 and shaped(r)[0]["field"] == "origin"
        assert not list((tmp_path / "uploads").glob("*"))
        r = c.post("/api/uploads", params={"name": "x.json"}, content=b"{}",
                   headers={"Sec-Fetch-Site": "cross-site"})  # fmt: skip
        assert r.status_code == 403
        with pytest.raises(InvalidStatus):
            connect(f"ws://{hp}/ws", additional_headers={"Origin": "http://attacker.example"})
        # the same origin passes
        r = c.post("/api/uploads", params={"name": "x.json"}, content=b"{}",
                   headers={"Origin": f"http://{hp}"})  # fmt: skip
        assert r.status_code == 200, r.text
        for path in ("/", "/api/health", "/nothing"):
            h = c.get(path).headers
            assert h["x-frame-options"] == "DENY" and h["x-content-type-options"] == "nosniff"
            assert "frame-ancestors 'none'" in h["content-security-policy"]


def test_bind_checks() -> None:
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert is_loopback("127.8.9.1") and is_loopback("[::1]")
    assert not is_loopback("127.0.0.1.attacker.example") and not is_loopback("0.0.0.0")
    with pytest.raises(CutwatchError, match="requires a bearer token"):
        check_security(Settings(host="127.0.0.1.attacker.example"))
    for bad, found in ((" ", "an empty or blank value"), ("", "an empty or blank value"),
                       ("short", "a value of 5 characters"),
                       (f" {OPERATOR}", "characters")):  # fmt: skip
        with pytest.raises(ParameterError, match="CUTWATCH_TOKEN") as exc:
            create_app(Settings(host="0.0.0.0", token=bad))
        assert found in str(exc.value) and (not bad.strip() or bad.strip() not in str(exc.value))
    with pytest.raises(ParameterError, match="CUTWATCH_VIEW_TOKEN"):
        check_security(Settings(view_token=VIEWER))
    with pytest.raises(ParameterError, match="other than CUTWATCH_TOKEN"):
        check_security(Settings(token=OPERATOR, view_token=OPERATOR))
    check_security(Settings(host="0.0.0.0", token=OPERATOR))


# ------------------------------------------------------------------ measured on a process
def _bomb(path: Path) -> None:
    code = (
        "import numpy as np, scipy.io, sys; "
        "scipy.io.savemat(sys.argv[1], {'t': np.zeros(int(1e8))}, do_compression=True)"
    )
    subprocess.run([sys.executable, "-c", code, str(path)], check=True)


def test_mat_bomb_does_not_reach_the_service(tmp_path: Path) -> None:
    bomb = tmp_path / "bomb.mat"
    _bomb(bomb)
    size_kb = bomb.stat().st_size / 1e3
    with serve_process(
        "--scenario", "default", "--data-dir", str(tmp_path / "data"), CUTWATCH_TOKEN=OPERATOR
    ) as svc:
        # past start-up: the loop running and the checks' forkserver up (its memory is the
        # service's children's, not in the baseline's growth)
        poll(lambda: httpx.get(f"{svc.base}/api/health", timeout=60).json()["sim_t"] > 0, 120)
        _forkserver(svc.proc.pid)
        before = svc.rss_kb()
        svc.reset_peak()
        t0 = time.monotonic()
        r = httpx.post(f"{svc.base}/api/uploads", params={"name": "bomb.mat"},
                       content=bomb.read_bytes(), headers=OP, timeout=120)  # fmt: skip
        took = time.monotonic() - t0
        peak, after = svc.rss_kb("VmHWM"), svc.rss_kb()
        lag = httpx.get(f"{svc.base}/api/health", timeout=60).json()["lag_p99_ms"]
    (item,) = shaped(r)
    assert r.status_code == 422 and "expand to more than 100000000 bytes" in item["msg"]
    assert not (tmp_path / "data" / "uploads" / "bomb.mat").exists()
    grew = (peak - before) / 1e3
    print(f"mat bomb: {size_kb:.0f} kB file, answered in {took:.2f} s; service RSS "
          f"{before / 1e3:.0f} MB before, peak {peak / 1e3:.0f} MB (+{grew:.1f} MB), "
          f"{after / 1e3:.0f} MB after; loop lag p99 {lag:.1f} ms")  # fmt: skip
    assert grew < 100.0


def _big_csv(path: Path, mb: float) -> int:
    """A valid rigid log of about ``mb`` MB (the bench's) with its sidecar; its rows."""
    n = rigid_log(path, mb)
    path.with_suffix(".json").write_text(json.dumps(SIDECAR))
    return n


def _children(pid: int) -> list[int]:
    """Every process below ``pid`` (its children, theirs, ...), from /proc."""
    out: list[int] = []
    todo = [pid]
    while todo:
        for task in Path(f"/proc/{todo.pop()}/task").glob("*/children"):
            try:
                kids = [int(k) for k in task.read_text().split()]
            except OSError:  # the process or thread has gone
                continue
            out += kids
            todo += kids
    return out


def _forkserver(pid: int) -> int:
    """The process the service forks its upload checks from (multiprocessing's
    forkserver, started by the service's start-up)."""

    def find() -> int | None:
        for c in _children(pid):
            try:
                if b"multiprocessing.forkserver" in Path(f"/proc/{c}/cmdline").read_bytes():
                    return c
            except OSError:
                continue
        return None

    found: int = poll(find, 60)
    return found


def _quarantined(data: Path, name: str) -> int:
    """Bytes of ``name`` waiting in the quarantine (0: not there)."""
    size = 0
    for p in (data / ".quarantine").glob(f"*/{name}"):
        try:
            size = max(size, p.stat().st_size)
        except OSError:  # removed between the listing and the look
            continue
    return size


def _frames_after(host: str, sim_t: float, n: int = 3, timeout: float = 120.0) -> list[Any]:
    """The next ``n`` data frames the stream sends of simulated time past ``sim_t``, as
    (seq, sim_t), on a WebSocket opened for this and read throughout (one left unread
    between phases fills its queue, stops answering the server's pings and is closed
    1011 after 20-40 s); AssertionError if they do not come within ``timeout`` s."""
    got: list[Any] = []
    deadline = time.monotonic() + timeout
    with connect(f"ws://{host}/ws", additional_headers=OP, open_timeout=timeout) as ws:
        while len(got) < n:
            left = deadline - time.monotonic()
            assert left > 0, f"the stream stopped: {got} after sim_t {sim_t}"
            msg = json.loads(ws.recv(timeout=left))
            if msg.get("type") == "data" and msg["health"]["sim_t"] > sim_t:
                got.append((msg["seq"], msg["health"]["sim_t"]))
    return got


def _rising(frames: list[Any]) -> bool:
    return all(b[0] > a[0] and b[1] > a[1] for a, b in pairwise(frames))


def test_a_large_upload_streams_to_disk_while_the_loop_runs_on(tmp_path: Path) -> None:
    # What the security review found (issue 20): the 80 MB log was taken whole and checked
    # in the service, and the loop stalled (lag p99 651 ms). Judged here by what cannot
    # race, not by a latency (the loop's lag during an upload is `cutwatch bench upload`'s):
    # 1. half the body sent and held: its bytes are on disk in the quarantine already
    #    (streamed, not gathered in memory), and the loop publishes frames (seq and sim_t
    #    rising) and /api/health answers meanwhile;
    # 2. the body complete and the check held (its forkserver stopped by SIGSTOP, so no
    #    check can start): frames and /api/health go on, and the upload waits unanswered
    #    (the check is a child process's, awaited off the service's event loop);
    # 3. released: 200 with the rows counted, listed; the service's peak RSS grew less
    #    than the file's size.
    big = tmp_path / "big.csv"
    n = _big_csv(big, 80.0)
    size = big.stat().st_size
    data = tmp_path / "data"
    half, held, release = size // 2, threading.Event(), threading.Event()

    def body() -> Iterator[bytes]:
        with big.open("rb") as fh:
            sent = 0
            while chunk := fh.read(1 << 20):
                if sent >= half and not held.is_set():
                    held.set()
                    release.wait(300)
                yield chunk
                sent += len(chunk)

    with (
        serve_process("--scenario", "default", "--data-dir", str(data), CUTWATCH_TOKEN=OPERATOR)
        as svc,
        httpx.Client(base_url=svc.base, headers=OP, timeout=120) as c,
    ):  # fmt: skip
        r = c.post(
            "/api/uploads",
            params={"name": "big.json"},
            content=big.with_suffix(".json").read_bytes(),
        )
        assert r.status_code == 200, r.text
        forkserver = _forkserver(svc.proc.pid)  # it has checked the sidecar
        before = svc.rss_kb()
        svc.reset_peak()
        result: dict[str, Any] = {}

        def send() -> None:
            with httpx.Client(headers=OP, timeout=600) as up:
                result["r"] = up.post(f"{svc.base}/api/uploads", params={"name": "big.csv"},
                                      content=body())  # fmt: skip

        th = threading.Thread(target=send)
        th.start()
        stopped = False
        try:
            assert held.wait(300), "the upload's first half was never sent"
            # 1. half in: on disk while it arrives (a body gathered in memory is not)
            poll(lambda: _quarantined(data, "big.csv") >= half // 2, 120)
            t0 = c.get("/api/health").json()["sim_t"]
            arriving = _frames_after(svc.host, t0)
            assert _rising(arriving), arriving
            os.kill(forkserver, signal.SIGSTOP)
            stopped = True
            release.set()
            # 2. the whole body on disk; its check cannot start while the forkserver stands
            poll(lambda: _quarantined(data, "big.csv") == size, 120)
            t1 = c.get("/api/health").json()["sim_t"]
            checking = _frames_after(svc.host, t1)
            assert _rising(checking) and checking[0][1] > arriving[-1][1], checking
            assert th.is_alive() and "r" not in result, "answered before its check ran"
            assert not (data / "uploads" / "big.csv").exists()
        finally:
            release.set()
            if stopped:
                os.kill(forkserver, signal.SIGCONT)
            th.join(600)
        peak = svc.rss_kb("VmHWM")
        lag = c.get("/api/health").json()["lag_p99_ms"]
        r = result["r"]
        assert r.status_code == 200, r.text
        assert r.json()["samples"] == n
        names = {u["name"] for u in c.get("/api/uploads").json()["uploads"]}
        assert "big.csv" in names  # published once checked
    grew = (peak - before) / 1e3
    print(
        f"large upload: {size / 1e6:.1f} MB, {n} rows; frames while it arrived {arriving}, "
        f"while its check was held {checking}; service RSS +{grew:.1f} MB at peak; loop "
        f"lag p99 {lag:.1f} ms over the last 600 blocks, start-up included (not judged "
        f"here: cutwatch bench upload)"
    )
    assert grew < 100.0


def test_an_upload_is_neither_listed_nor_usable_while_its_check_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the log's check is held (the real check, started only when the test says), so the
    # time between receiving the file and publishing it is as long as the test needs and
    # what a client sees in it is judged without a race
    import asyncio

    from server.service.routes import uploads

    held, release = threading.Event(), threading.Event()
    real = uploads.run_check

    async def held_check(path: Path, what: str, limits: Any) -> Any:
        if path.suffix == ".csv":
            held.set()
            await asyncio.to_thread(release.wait, 120)
        return await real(path, what, limits)

    monkeypatch.setattr(uploads, "run_check", held_check)
    log = tmp_path / "held.csv"
    n = _big_csv(log, 0.2)
    data = tmp_path / "data"
    with (
        serve(scenario="default", token=OPERATOR, data_dir=data) as hp,
        httpx.Client(base_url=f"http://{hp}", headers=OP, timeout=120) as c,
    ):
        r = c.post("/api/uploads", params={"name": "held.json"},
                   content=log.with_suffix(".json").read_bytes())  # fmt: skip
        assert r.status_code == 200, r.text
        result: dict[str, httpx.Response] = {}
        th = threading.Thread(
            target=lambda: result.setdefault(
                "r", c.post("/api/uploads", params={"name": "held.csv"}, content=log.read_bytes())
            )
        )
        th.start()
        try:
            assert held.wait(60), "the upload's check never started"
            names = {u["name"] for u in c.get("/api/uploads").json()["uploads"]}
            assert "held.csv" not in names and "held.json" in names
            a = c.post("/api/analyses", json={"log": "held", "area": "uploads"})
            assert a.status_code != 202, a.text
            assert not (data / "uploads" / "held.csv").exists()
        finally:
            release.set()
            th.join(120)
        assert result["r"].status_code == 200, result["r"].text
        assert result["r"].json()["samples"] == n
        names = {u["name"] for u in c.get("/api/uploads").json()["uploads"]}
        assert "held.csv" in names  # published once checked
        a = c.post("/api/analyses", json={"log": "held", "area": "uploads"})
        assert a.status_code == 202, a.text


def test_the_check_runs_under_its_memory_limit(tmp_path: Path) -> None:
    # a valid 40 MB log whose check needs more than 256 MB of address space: refused,
    # named, and the service is untouched
    big = tmp_path / "mid.csv"
    _big_csv(big, 20.0)
    with (
        serve(scenario="default", data_dir=tmp_path / "data", upload_check_mb=256) as hp,
        httpx.Client(base_url=f"http://{hp}", timeout=120) as c,
    ):
        assert c.post("/api/uploads", params={"name": "mid.json"},
                      content=big.with_suffix(".json").read_bytes()).status_code == 200  # fmt: skip
        r = c.post("/api/uploads", params={"name": "mid.csv"}, content=big.read_bytes())
        (item,) = shaped(r)
        assert r.status_code == 422 and "256 MB" in item["msg"], item["msg"]
        assert c.get("/api/health").json()["status"] == "ok"
    assert not (tmp_path / "data" / "uploads" / "mid.csv").exists()


def test_a_killed_recording_is_cleaned_at_the_next_start(tmp_path: Path) -> None:
    data = tmp_path / "data"
    with serve_process(
        "--scenario", "default", "--data-dir", str(data), CUTWATCH_TOKEN=OPERATOR
    ) as svc:
        r = httpx.post(f"{svc.base}/api/record", json={"action": "start", "name": "k.csv"},
                       headers=OP, timeout=60)  # fmt: skip
        assert r.status_code == 200, r.text
        tmp = poll(lambda: list((data / "recordings").glob(".k.csv.*.tmp")), 60)
        time.sleep(0.5)
        svc.stop(signal.SIGKILL)
    assert all(p.exists() for p in tmp)  # the kill left it
    with serve_process(
        "--scenario", "default", "--data-dir", str(data), CUTWATCH_TOKEN=OPERATOR
    ) as svc:
        assert not list((data / "recordings").glob(".*.tmp"))
        listed = httpx.get(f"{svc.base}/api/records", headers=OP, timeout=60).json()["records"]
        assert listed == []
        svc.stop()
    said = f"removed 1 temporary file(s) left by an interrupted run: recordings/{tmp[0].name}"
    assert said in svc.stderr, svc.stderr[-2000:]
