"""ASGI middleware of the service."""

from __future__ import annotations

import json
import logging
from collections.abc import MutableMapping, Sequence
from typing import Any

from starlette.requests import HTTPConnection
from starlette.types import ASGIApp, Receive, Scope, Send

from server.service import auth
from server.service.http_errors import error

Message = MutableMapping[str, Any]


class BodyLimit:
    """ASGI middleware refusing request bodies larger than ``limit`` bytes (413).

    Checks ``Content-Length`` up front and counts streamed (chunked) bodies as they
    arrive. The 413 has the service's one error body (``server.service.http_errors``).
    """

    def __init__(self, app: ASGIApp, limit: int, paths: dict[str, int] | None = None) -> None:
        self.app = app
        self.limit = limit
        self.paths = dict(paths or {})  # path -> its own limit (uploads)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self.paths.get(scope.get("path", ""), self.limit)
        for k, v in scope.get("headers", []):
            if k == b"content-length":
                try:
                    size: int | str = int(v)
                except ValueError:
                    size = v.decode("latin-1")[:80]
                if not isinstance(size, int) or size > limit:
                    await self._reject(send, size, limit)
                    return
        seen = 0
        rejected = False

        async def counted() -> Message:
            # past the limit: answer 413 ourselves and tell the app the client has gone
            nonlocal seen, rejected
            if rejected:
                return {"type": "http.disconnect"}
            msg = await receive()
            if msg["type"] == "http.request":
                seen += len(msg.get("body", b""))
                if seen > limit:
                    rejected = True
                    await self._reject(send, seen, limit)
                    return {"type": "http.disconnect"}
            return msg

        async def guarded_send(msg: Message) -> None:
            if not rejected:
                await send(msg)

        await self.app(scope, counted, guarded_send)

    async def _reject(self, send: Send, got: int | str, limit: int) -> None:
        # got: the declared Content-Length, or the bytes received before refusing
        msg = f"request body larger than {limit} bytes"
        item = error("body", f"at most {limit} bytes", got, msg)
        body = json.dumps({"detail": [item]}).encode()
        await send(
            {
                "type": "http.response.start",
                "status": 413,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})


#: headers added to every HTTP answer: no framing by other sites, no MIME sniffing
SECURITY_HEADERS = [
    (b"x-frame-options", b"DENY"),
    (b"content-security-policy", b"frame-ancestors 'none'; object-src 'none'; base-uri 'none'"),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"same-origin"),
]

audit_log = logging.getLogger("cutwatch.audit")

#: request bodies of these paths are not written to the audit log (a token, a file)
_NOT_LOGGED = {"/api/login": "(a token, not logged)", "/api/uploads": None}


class Guard:
    """ASGI middleware: the Host allow-list, the Origin check of state-changing
    requests and WebSocket upgrades, the role check (:func:`server.service.auth.check`)
    of every request but the public paths, the security headers, and one audit log line
    per state-changing request (role, method, route, status, the body sent).

    A browser asking for a page without a session is sent to ``/login`` (303); every
    other refusal has the service's one error body.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        conn = HTTPConnection(scope)
        ws = scope["type"] == "websocket"
        method = "GET" if ws else scope["method"]
        need = auth.needed_role(method)
        refusal: tuple[int, dict[str, Any]] | None = None
        role: str | None = None
        if not auth.host_allowed(conn):
            refusal = (400, auth.refusal_host(conn))
        elif (ws or need == "operator") and not auth.same_origin(conn):
            refusal = (403, auth.refusal_origin(conn))
        elif scope.get("path", "") not in auth.PUBLIC:
            role, status, item = auth.check(conn, need)
            if item is not None:
                refusal = (status, item)
        if refusal is not None:
            if need == "operator":
                who = auth.access_of(conn).role_of(conn)[0]  # a viewer refused: say so
                _audit(conn, method, who, refusal[0], "refused: " + refusal[1]["msg"])
            if ws:
                await _deny_ws(scope, send, *refusal)
            elif refusal[0] == 401 and _wants_page(conn):
                await send_json(send, 303, None, [(b"location", b"/login")])
            else:
                await send_json(send, refusal[0], refusal[1])
            return
        if ws or need != "operator":
            await self.app(scope, receive, _with_headers(send))
            return
        await self._audited(conn, method, role, scope, receive, send)

    async def _audited(
        self, conn: HTTPConnection, method: str, role: str | None, scope: Scope,
        receive: Receive, send: Send,
    ) -> None:  # fmt: skip
        path = scope.get("path", "")
        seen = bytearray()
        size = 0
        status = 0

        async def recv() -> Message:
            nonlocal size
            msg = await receive()
            if msg["type"] == "http.request":
                chunk = msg.get("body", b"")
                size += len(chunk)
                if len(seen) < 400:
                    seen.extend(chunk[: 400 - len(seen)])
            return msg

        inner = _with_headers(send)

        async def sent(msg: Message) -> None:
            nonlocal status
            if msg["type"] == "http.response.start":
                status = int(msg["status"])
            await inner(msg)

        try:
            await self.app(scope, recv, sent)
        finally:
            if path in _NOT_LOGGED:
                what = _NOT_LOGGED[path] or f"{size} bytes"
            else:
                what = bytes(seen).decode("utf-8", "backslashreplace")
            _audit(conn, method, role, status, what)


def _audit(conn: HTTPConnection, method: str, role: str | None, status: int, what: str) -> None:
    query = conn.url.query
    route = conn.url.path + (f"?{query}" if query else "")
    audit_log.info(
        "audit role=%s %s %s status=%s change=%s",
        role or "-",
        method,
        ascii(route[:300]),
        status or "-",
        ascii(what[:400]),  # ascii(): no newline or control character reaches the log
    )


def _wants_page(conn: HTTPConnection) -> bool:
    """A browser navigating to a page (not an API or a script fetching data)."""
    path = conn.url.path
    accept = conn.headers.get("accept", "")
    return "text/html" in accept and not path.startswith("/api/")


def _with_headers(send: Send) -> Send:
    async def wrapped(msg: Message) -> None:
        if msg["type"] == "http.response.start":
            have = {k.lower() for k, _ in msg.get("headers", [])}
            extra = [(k, v) for k, v in SECURITY_HEADERS if k not in have]
            msg["headers"] = [*msg.get("headers", []), *extra]
        await send(msg)

    return wrapped


async def send_json(
    send: Send,
    status: int,
    item: dict[str, Any] | None,
    headers: Sequence[tuple[bytes, bytes]] = (),
) -> None:
    """An answer in the service's one error body (``item``), or an empty one."""
    body = b"" if item is None else json.dumps({"detail": [item]}).encode()
    hs = [(b"content-length", str(len(body)).encode()), *headers, *SECURITY_HEADERS]
    if item is not None:
        hs.insert(0, (b"content-type", b"application/json"))
    if status == 401:
        hs.append((b"www-authenticate", b"Bearer"))
    await send({"type": "http.response.start", "status": status, "headers": hs})
    await send({"type": "http.response.body", "body": body})


async def _deny_ws(scope: Scope, send: Send, status: int, item: dict[str, Any]) -> None:
    """Refuse a WebSocket upgrade: an HTTP answer with the error body where the server
    supports it (``websocket.http.response``), otherwise a close (403 handshake)."""
    if "websocket.http.response" in scope.get("extensions", {}):
        body = json.dumps({"detail": [item]}).encode()
        await send(
            {
                "type": "websocket.http.response.start",
                "status": status,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode())],
            }
        )  # fmt: skip
        await send({"type": "websocket.http.response.body", "body": body})
    else:
        await send({"type": "websocket.close", "code": 1008})
