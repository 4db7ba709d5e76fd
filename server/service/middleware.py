"""ASGI middleware of the service."""

from __future__ import annotations

import json
import logging
from collections.abc import MutableMapping, Sequence
from typing import Any

from starlette.requests import HTTPConnection
from starlette.types import ASGIApp, Receive, Scope, Send
from starlette.websockets import WebSocketDisconnect

from server.service import auth
from server.service.http_errors import ErrorEntry, error

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


#: the names of UTF-8 a Content-Type's charset may give
UTF8 = frozenset({"utf-8", "utf8"})
#: byte-order marks, longest first (UTF-32LE's begins with UTF-16LE's)
_BOMS = (
    (b"\xff\xfe\x00\x00", "UTF-32LE"), (b"\x00\x00\xfe\xff", "UTF-32BE"),
    (b"\xff\xfe", "UTF-16LE"), (b"\xfe\xff", "UTF-16BE"),
)  # fmt: skip


def charset_of(content_type: str) -> str | None:
    """The ``charset`` parameter of a Content-Type (lower case, unquoted), if any."""
    for param in content_type.split(";")[1:]:
        name, _, value = param.partition("=")
        if name.strip().lower() == "charset":
            return value.strip().strip('"').strip().lower()
    return None


def json_type(content_type: str) -> bool:
    """A body FastAPI reads as JSON: no Content-Type, ``application/json`` or
    ``application/*+json``."""
    kind = content_type.split(";")[0].strip().lower()
    return not kind or kind == "application/json" or (
        kind.startswith("application/") and kind.endswith("+json")
    )  # fmt: skip


def sniff_encoding(head: bytes) -> str | None:
    """The UTF-16 or UTF-32 a JSON text's first bytes show (a byte-order mark, or the NUL
    pattern of RFC 4627 section 3: a JSON text begins with an ASCII character); None
    for UTF-8 (with or without its byte-order mark, which RFC 8259 lets a parser
    ignore)."""
    for bom, name in _BOMS:
        if head.startswith(bom):
            return name
    if len(head) >= 4 and head[1:4] == b"\0\0\0":
        return "UTF-32LE"
    if len(head) >= 4 and head[:3] == b"\0\0\0":
        return "UTF-32BE"
    if len(head) >= 2 and (head[0] == 0) != (head[1] == 0):
        return "UTF-16BE" if head[0] == 0 else "UTF-16LE"
    return None


class Utf8Bodies:
    """ASGI middleware: request bodies in UTF-8 only (JSON between systems is UTF-8, RFC
    8259 section 8.1; Python's ``json.loads`` would otherwise read UTF-16 and UTF-32).

    A Content-Type whose ``charset`` is not UTF-8, and a JSON body (what FastAPI parses
    as JSON: :func:`json_type`) whose first bytes are UTF-16 or UTF-32
    (:func:`sniff_encoding`), are answered 415 in the service's one error body, naming
    the charset found. ``raw``: paths whose bodies are files kept as bytes (uploads),
    not checked.
    """

    def __init__(self, app: ASGIApp, raw: frozenset[str] = frozenset()) -> None:
        self.app = app
        self.raw = raw

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope.get("path", "") in self.raw:
            await self.app(scope, receive, send)
            return
        headers = {k.lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        ctype = headers.get(b"content-type", "")
        declared = charset_of(ctype)
        if declared is not None and declared not in UTF8:
            await _refuse_charset(send, declared, f"the Content-Type says charset={declared}")
            return
        has_body = headers.get(b"content-length", "0").strip() != "0" or (
            b"transfer-encoding" in headers
        )  # fmt: skip
        if not (has_body and json_type(ctype)):
            await self.app(scope, receive, send)
            return
        held, head = await _peek(receive, 4)
        found = sniff_encoding(head)
        if found is not None:
            await _refuse_charset(send, found, f"the body's first bytes are {found}")
            return

        async def replay() -> Message:
            return held.pop(0) if held else await receive()

        await self.app(scope, replay, send)


async def _peek(receive: Receive, n: int) -> tuple[list[Message], bytes]:
    """The messages read until ``n`` bytes of the body (or all of it) came, and them."""
    held: list[Message] = []
    head = b""
    while len(head) < n:
        msg = await receive()
        held.append(msg)
        if msg["type"] != "http.request":
            break
        head += msg.get("body", b"")
        if not msg.get("more_body", False):
            break
    return held, head[:n]


async def _refuse_charset(send: Send, found: str, how: str) -> None:
    allowed = "UTF-8 (JSON between systems is UTF-8: RFC 8259, section 8.1)"
    msg = f"request body in {found} refused ({how}); send it in UTF-8"
    await send_json(send, 415, error("charset", allowed, found, msg))


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
    """ASGI middleware: a repeated Host header refused, the Host allow-list, the Origin
    check of state-changing requests and WebSocket upgrades, the role check
    (:func:`server.service.auth.check`) of every request but the public paths, the
    security headers, and one audit log line per state-changing request (role, method,
    route, status, the body sent).

    A browser asking for a page without a session is sent to ``/login`` (303); every
    other refusal has the service's one error body. A WebSocket client that leaves (its
    close, or its connection gone) ends the route with ``WebSocketDisconnect`` where the
    route does not catch it: that is logged at debug (``cutwatch.ws``), not as an error.
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
        role, refusal = _decide(conn, ws, need)
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
        if ws:
            await _websocket(self.app, conn, scope, receive, send)
        elif need != "operator":
            await self.app(scope, receive, _with_headers(send))
        else:
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


def _decide(
    conn: HTTPConnection, ws: bool, need: auth.Role
) -> tuple[str | None, tuple[int, ErrorEntry] | None]:
    """The caller's role (None when not checked: a public path) and the refusal, if any."""
    if auth.host_repeated(conn):
        return None, (400, auth.refusal_repeated_host(conn))
    if not auth.host_allowed(conn):
        return None, (400, auth.refusal_host(conn))
    if (ws or need == "operator") and not auth.same_origin(conn):
        return None, (403, auth.refusal_origin(conn))
    if conn.scope.get("path", "") in auth.PUBLIC:
        return None, None
    role, status, item = auth.check(conn, need)
    return role, None if item is None else (status, item)


ws_log = logging.getLogger("cutwatch.ws")


async def _websocket(
    app: ASGIApp, conn: HTTPConnection, scope: Scope, receive: Receive, send: Send
) -> None:
    """Run a WebSocket route; a client that has left is a debug line, not an error."""
    try:
        await app(scope, receive, send)
    except WebSocketDisconnect as exc:
        who = f"{conn.client.host}:{conn.client.port}" if conn.client else "?"
        ws_log.debug("%s %s: the client left (code %s)", who, ascii(conn.url.path), exc.code)


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
    item: ErrorEntry | None,
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


async def _deny_ws(scope: Scope, send: Send, status: int, item: ErrorEntry) -> None:
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
