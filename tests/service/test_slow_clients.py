"""Slow and oversized clients against ``cutwatch serve`` as a user runs it (a subprocess,
its own uvicorn): headers a byte at a time, a body declared 1,000 bytes with 1 sent, a
body trickling in, a connection that sends nothing, a 10 MiB header. Each is dropped
within its limit (2 s here, to keep the test short; 10 s by default) while ordinary
requests and a WebSocket that outlives the limits keep working.

When a drop came is judged against what cannot race: never before its limit (the clock
started before the connection was opened, so before the server's timer). Which limit
applied is read from the 408's body, which names it (``within 2 s``, ``a byte at least
every 2 s``; the default would read 10 s), not from a wall-clock upper bound that a
loaded machine's late timer could pass.

Bounded: at most 10 slow connections at once, each test under ~10 s.
"""

from __future__ import annotations

import contextlib
import json
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from _live import serve_process
from _wait import poll
from websockets.sync.client import connect

from server.service.settings import Settings

HEADER_S = 2.0
BODY_S = 2.0
MAX_HEADER = 32768
PER_CLIENT = 20
#: the server's timers run on the event loop's clock, whole milliseconds under uvloop
#: (libuv): a drop may come this much before its limit as this process measures it
CLOCK_S = 0.01
#: the default header and body limits (Settings): the configured ones differ, so the limit
#: a 408 names tells which was applied
DEFAULT_S = Settings().header_timeout_s
assert Settings().body_timeout_s == DEFAULT_S and DEFAULT_S not in (HEADER_S, BODY_S)
#: a connection still open this long was never dropped: a hang, not a late timer
GIVE_UP_S = 60.0
HEADER_NAMED = f"within {HEADER_S:g} s"
BODY_NAMED = f"a byte at least every {BODY_S:g} s"


def not_early(t: float, limit: float) -> bool:
    """Dropped after at least ``limit`` s (no upper bound: a loaded machine may run the
    server's timer late; the 408 names the limit that applied)."""
    return t >= limit - CLOCK_S


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    d = tmp_path_factory.mktemp("slow")
    limits = {
        "CUTWATCH_HEADER_TIMEOUT_S": str(HEADER_S),
        "CUTWATCH_BODY_TIMEOUT_S": str(BODY_S),
        "CUTWATCH_MAX_HEADER_BYTES": str(MAX_HEADER),
        "CUTWATCH_MAX_CONNECTIONS_PER_CLIENT": str(PER_CLIENT),
    }
    with serve_process("--scenario", "default", "--data-dir", str(d / "data"), **limits) as p:
        yield p.base.removeprefix("http://")


def open_conn(hp: str) -> socket.socket:
    host, port = hp.split(":")
    s = socket.create_connection((host, int(port)), timeout=5)
    return s


def read_until_closed(
    s: socket.socket, limit_s: float, t0: float | None = None
) -> tuple[bytes, float]:
    """Everything the server sends until it closes, and when it closed (from ``t0``,
    default now)."""
    t0 = time.monotonic() if t0 is None else t0
    out = b""
    s.settimeout(0.2)
    while time.monotonic() - t0 < limit_s:
        try:
            chunk = s.recv(65536)
        except TimeoutError:
            continue
        except ConnectionResetError:
            break
        if not chunk:
            break
        out += chunk
    else:
        raise AssertionError(f"still open after {limit_s} s; got {out[:200]!r}")
    return out, time.monotonic() - t0


def status_and_body(raw: bytes) -> tuple[int, dict]:
    head, _, body = raw.partition(b"\r\n\r\n")
    return int(head.split(b" ", 2)[1]), json.loads(body)


def test_headers_a_byte_at_a_time_are_dropped_in_time(server: str) -> None:
    """10 connections trickling a request's headers (a byte every 0.1 s at most: the
    600-byte header would take 60 s, so no late timer lets one complete): each answered
    408 naming the header limit, and closed."""
    request = f"GET /api/health HTTP/1.1\r\nHost: {server}\r\nX-Slow: {'a' * 600}\r\n\r\n"
    t0 = time.monotonic()  # before the connections: before the server's timers start
    conns = [open_conn(server) for _ in range(10)]
    closed_at: list[float] = []
    answers: list[bytes] = []
    lock = threading.Lock()

    def trickle(s: socket.socket) -> None:
        got = b""
        s.settimeout(0.1)
        for ch in request.encode():
            try:
                s.send(bytes([ch]))
            except OSError:
                break
            try:
                data = s.recv(4096)
                got += data
                if not data:
                    break
            except TimeoutError:
                continue
            except OSError:
                break
        with lock:
            closed_at.append(time.monotonic() - t0)
            answers.append(got)

    threads = [threading.Thread(target=trickle, args=(c,)) for c in conns]
    for th in threads:
        th.start()
    for th in threads:
        th.join(GIVE_UP_S * 2)
    for c in conns:
        c.close()
    print(f"byte-a-time headers: 10 connections closed after {sorted(closed_at)} s")
    assert len(closed_at) == 10
    assert all(not_early(t, HEADER_S) for t in closed_at), closed_at
    for a in answers:
        status, body = status_and_body(a)
        assert status == 408 and body["detail"][0]["field"] == "headers"
        assert body["detail"][0]["allowed"] == HEADER_NAMED, body
    # the server serves on, and counts them
    assert httpx.get(f"http://{server}/api/health", timeout=5).status_code == 200
    metrics = httpx.get(f"http://{server}/metrics", timeout=5).text
    n = next(
        ln
        for ln in metrics.splitlines()
        if ln.startswith("cutwatch_http_dropped_header_timeout_total ")
    )
    assert float(n.split()[-1]) >= 10


def test_a_connection_that_sends_nothing_is_dropped(server: str) -> None:
    t0 = time.monotonic()
    s = open_conn(server)
    raw, t = read_until_closed(s, GIVE_UP_S, t0)
    s.close()
    print(f"silent connection closed after {t:.2f} s")
    assert not_early(t, HEADER_S), t
    status, body = status_and_body(raw)
    assert status == 408 and body["detail"][0]["field"] == "headers"
    assert body["detail"][0]["allowed"] == HEADER_NAMED, body


@pytest.mark.parametrize("path", ["/api/control", "/api/nowhere"])
def test_a_body_declared_1000_bytes_with_1_sent_is_dropped(server: str, path: str) -> None:
    """Whether the app waits for the body (a JSON route) or answers without it (404)."""
    s = open_conn(server)
    t0 = time.monotonic()  # before the headers are sent: before the body's timer starts
    s.sendall(
        f"POST {path} HTTP/1.1\r\nHost: {server}\r\nContent-Type: application/json\r\n"
        "Content-Length: 1000\r\n\r\n{".encode()
    )
    raw, t = read_until_closed(s, GIVE_UP_S, t0)
    s.close()
    print(f"body 1 of 1000 bytes on {path}: closed after {t:.2f} s")
    assert not_early(t, BODY_S), t
    if path == "/api/control":  # the app was still waiting: the answer is ours
        assert raw.startswith(b"HTTP/1.1 408"), raw[:200]
    at = raw.find(b"HTTP/1.1 408")  # a 404 answered before the body may precede ours
    if at >= 0 or path == "/api/control":
        status, body = status_and_body(raw[at:])
        assert status == 408 and body["detail"][0]["field"] == "body"
        assert body["detail"][0]["got"] == 1
        assert body["detail"][0]["allowed"] == BODY_NAMED, body


def test_a_trickling_body_is_dropped_by_its_rate(server: str) -> None:
    """A byte every 0.5 s never leaves the body silent for 2 s, but it is far below the
    1024 bytes/s accepted past the first 2 s."""
    s = open_conn(server)
    t0 = time.monotonic()  # before the headers are sent: before the body's timer starts
    s.sendall(
        f"POST /api/control HTTP/1.1\r\nHost: {server}\r\nContent-Type: application/json\r\n"
        "Content-Length: 1000\r\n\r\n".encode()
    )
    s.settimeout(0.5)
    raw = b""
    while time.monotonic() - t0 < GIVE_UP_S:
        try:
            s.send(b" ")
            chunk = s.recv(4096)
        except TimeoutError:
            continue
        except OSError:
            break
        raw += chunk
        if not chunk:
            break
    t = time.monotonic() - t0
    s.close()
    print(f"trickling body: closed after {t:.2f} s")
    assert not_early(t, BODY_S), t
    status, body = status_and_body(raw)
    assert status == 408 and "bytes/s" in body["detail"][0]["msg"]
    assert body["detail"][0]["allowed"] == BODY_NAMED, body


def test_connections_from_one_address_are_bounded(tmp_path: Path) -> None:
    """20 silent connections are held; the 21st from the same address is answered 503 at
    once; once they are gone, requests are served again. On a server of its own whose
    header limit (120 s) outlasts any pause of a loaded machine between opening the 20
    and the 21st: at the module's 2 s the first could be dropped before the last opened,
    and the 21st would then be held, not refused."""
    held_s = "120"
    with serve_process(
        "--scenario", "default", "--data-dir", str(tmp_path / "data"),
        CUTWATCH_HEADER_TIMEOUT_S=held_s, CUTWATCH_MAX_CONNECTIONS_PER_CLIENT=str(PER_CLIENT),
    ) as p:  # fmt: skip
        hp = p.base.removeprefix("http://")
        held = [open_conn(hp) for _ in range(PER_CLIENT)]
        try:
            extra = open_conn(hp)
            # a 503 is answered as the connection is made; a held 21st would wait 120 s
            raw, t = read_until_closed(extra, 60)
            extra.close()
            print(f"connection {PER_CLIENT + 1} from one address: 503 after {t:.3f} s")
            status, body = status_and_body(raw)
            assert status == 503 and body["detail"][0]["field"] == "connections"
        finally:
            for c in held:
                c.close()
        poll(lambda: httpx.get(f"{p.base}/api/health", timeout=5).status_code == 200, 30)


def test_a_10_mib_header_is_refused_before_it_is_read(server: str) -> None:
    s = open_conn(server)
    s.sendall(f"GET /api/health HTTP/1.1\r\nHost: {server}\r\nX-Big: ".encode())
    sent = 0
    chunk = b"a" * 65536
    t0 = time.monotonic()
    with contextlib.suppress(OSError):
        while sent < 10 * 2**20:
            sent += s.send(chunk)
    raw, _ = read_until_closed(s, 10)
    t = time.monotonic() - t0
    s.close()
    print(f"10 MiB header: refused after {sent} bytes sent, {t:.2f} s")
    status, body = status_and_body(raw)
    assert status == 431 and body["detail"][0]["field"] == "headers"
    # the server stopped reading near the limit: the rest never left the client's buffers
    assert sent < 10 * 2**20


def test_a_header_over_the_limit_in_one_piece_is_refused(server: str) -> None:
    r = httpx.get(f"http://{server}/api/health", headers={"X-Big": "a" * (MAX_HEADER + 100)})
    assert (
        r.status_code == 431 and r.json()["detail"][0]["allowed"] == f"at most {MAX_HEADER} bytes"
    )
    r = httpx.get(f"http://{server}/api/health", headers={"X-Fine": "a" * (MAX_HEADER // 2)})
    assert r.status_code == 200


def test_an_invalid_request_gets_the_error_shape(server: str) -> None:
    for raw in (
        f"POST /api/control HTTP/1.1\r\nHost: {server}\r\nContent-Length: abc\r\n\r\n",
        f"GET /api/health HTTP/1.1\r\nHost: {server}\r\nBad Header\r\n\r\n",
        f"BREW /api/health HTTP/1.1\r\nHost: {server}\r\n\r\n",  # an unknown method
    ):
        s = open_conn(server)
        s.sendall(raw.encode())
        got, _ = read_until_closed(s, 5)
        s.close()
        status, body = status_and_body(got)
        assert status == 400 and body["detail"][0]["field"] == "request"


def test_ordinary_clients_keep_working(server: str) -> None:
    """Kept-alive requests with pauses, a JSON body in pieces, and a WebSocket open for
    longer than both limits."""
    with httpx.Client(base_url=f"http://{server}", timeout=5) as c:
        for _ in range(3):
            assert c.get("/api/health").status_code == 200
            time.sleep(1.0)  # under uvicorn's 5 s keep-alive, past nothing of ours
    s = open_conn(server)
    body = b'{"action": "pause"}'
    s.sendall(
        f"POST /api/control HTTP/1.1\r\nHost: {server}\r\nContent-Type: application/json\r\n"
        f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n".encode()
    )
    for i in range(0, len(body), 5):  # a slow but live sender: a piece every 0.3 s
        time.sleep(0.3)
        s.sendall(body[i : i + 5])
    raw, _ = read_until_closed(s, 10)
    s.close()
    assert raw.startswith(b"HTTP/1.1 200"), raw[:200]
    with connect(f"ws://{server}/ws") as ws:
        assert json.loads(ws.recv(timeout=5))["type"] == "hello"
        t0 = time.monotonic()
        pong = None
        while time.monotonic() - t0 < HEADER_S + BODY_S + 5:
            if pong is None and time.monotonic() - t0 > HEADER_S + BODY_S + 0.5:
                pong = ws.ping()
            if pong is not None and pong.is_set():
                break  # still open past both limits: the limits end at the upgrade
            with contextlib.suppress(TimeoutError):
                ws.recv(timeout=0.2)  # the stream's frames, read so that the pong gets in
        assert pong is not None and pong.is_set()
