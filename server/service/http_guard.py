"""Slow and oversized clients dropped at the HTTP layer, before the app runs.

uvicorn (0.54, its httptools protocol) waits for a request's headers and body as long as
the client likes and takes headers of any size: 10 connections sending their headers a
byte at a time were held 70 s, a body declared 1,000 bytes with 1 sent 45 s, and a
10 MiB header was read whole (issue 20). :func:`guarded_protocol` makes uvicorn's
protocol class with these limits (``uvicorn.Config(http=...)``), for ``cutwatch serve``
and so for the image, whose entry point it is:

- ``header_timeout``: from the connection's start (and from the first byte of each later
  request on a kept-alive connection) the request line and headers must be complete
  within this many seconds, however they trickle in; then 408 and the connection closed.
- ``body_timeout``: while a body is due, the connection is closed when no byte of it came
  for this many seconds (nginx's ``client_body_timeout``), or when, past that time, it came
  slower than ``body_min_rate`` bytes/s on average (a trickle of one byte every few
  seconds is as much a hold as silence).
- ``max_header_bytes``: a request line and headers larger than this are answered 431 and
  the connection closed; at most this much plus one read (256 KiB) is ever buffered.
- ``max_per_client``: at most this many HTTP connections open at once from one address;
  one more is answered 503 and closed at once (a WebSocket leaves the count when it is
  upgraded: the stream's own limits hold it).

Idle kept-alive connections are closed by uvicorn after ``timeout_keep_alive`` (5 s).
:class:`WebSocketProtocol` is uvicorn's websockets-sansio implementation with a refused
upgrade not logged as an error (see there). Once
the headers and body are in, the request is the app's: nothing here limits how long the
app or a WebSocket (after its upgrade) takes. The answers of this layer carry the
service's one error body (``server.service.http_errors``), as does httptools' own 400 for
a request it cannot parse.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any, ClassVar

from uvicorn.protocols.http.httptools_impl import STATUS_LINE, HttpToolsProtocol
from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol

from server.service.http_errors import ErrorEntry, error

#: connections dropped by each limit since the process started
DROPPED: dict[str, int] = {
    "header_timeout": 0, "body_timeout": 0, "header_size": 0, "per_client": 0
}  # fmt: skip


class _Refused(Exception):
    """Raised inside a parser callback to stop parsing; the answer is already chosen."""


class GuardedHttpToolsProtocol(HttpToolsProtocol):
    """uvicorn's httptools protocol with header and body timeouts and a header-size limit
    (the class attributes; :func:`guarded_protocol` makes a subclass with the settings)."""

    header_timeout: float = 10.0
    body_timeout: float = 10.0
    body_min_rate: float = 1024.0
    max_header_bytes: int = 32768
    max_per_client: int = 64
    #: open HTTP connections per client address (one dict per class: per server)
    open_per_client: ClassVar[dict[str, int]] = {}

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._timer: asyncio.TimerHandle | None = None
        self._phase = "idle"  # "headers" | "body" | "app"
        self._header_bytes = 0
        self._body_bytes = 0
        self._body_last = 0.0  # when its last byte came
        self._rate_start = 0.0  # the average rate is measured from here ...
        self._rate_bytes = 0  # ... and from this count on
        self._answer: tuple[int, str, ErrorEntry] | None = None
        self._addr = "?"
        self._counted = False  # in open_per_client

    # --- timers
    def _arm(self, delay: float, callback: Any) -> None:
        self._disarm()
        self._timer = self.loop.call_later(delay, callback)

    def _disarm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _start_headers(self) -> None:
        self._phase = "headers"
        self._header_bytes = 0
        self._arm(self.header_timeout, self._headers_late)

    def _headers_late(self) -> None:
        self._timer = None
        if self._phase != "headers" or self.transport.is_closing():
            return
        if self.flow.read_paused:  # a pipelined request waits for ours to be answered
            self._arm(self.header_timeout, self._headers_late)
            return
        DROPPED["header_timeout"] += 1
        msg = f"request headers not complete within {self.header_timeout:g} s"
        self._refuse(408, msg, error("headers", f"within {self.header_timeout:g} s", "", msg))

    def _body_check(self) -> None:
        self._timer = None
        if self._phase != "body" or self.transport.is_closing():
            return
        now = self.loop.time()  # the timers' own clock (uvloop's is cached per iteration)
        if self.flow.read_paused:  # the app has not taken what came: the wait is ours
            self._body_last = self._rate_start = now
            self._rate_bytes = self._body_bytes
        elapsed = now - self._rate_start
        if now - self._body_last >= self.body_timeout:
            msg = f"no byte of the request body for {self.body_timeout:g} s"
        elif elapsed >= self.body_timeout and (
            self._body_bytes - self._rate_bytes < self.body_min_rate * elapsed
        ):
            got = self._body_bytes - self._rate_bytes
            msg = (
                f"request body slower than {self.body_min_rate:g} bytes/s "
                f"({got} bytes in {elapsed:.1f} s)"
            )
        else:  # look again when the silence would be too long, and at least every second
            nxt = min(self._body_last + self.body_timeout, now + 1.0)
            self._timer = self.loop.call_later(max(0.05, nxt - now), self._body_check)
            return
        DROPPED["body_timeout"] += 1
        allowed = f"a byte at least every {self.body_timeout:g} s"
        self._refuse(408, msg, error("body", allowed, self._body_bytes, msg))

    def _refuse(self, status: int, msg: str, entry: ErrorEntry) -> None:
        """Answer ``status`` with the service's error body and close the connection."""
        self._disarm()
        self._phase = "closed"
        self.logger.warning("%s: %s", self.client[0] if self.client else "?", msg)
        c = self.cycle
        if c is not None and c.response_started and not c.response_complete:
            self.transport.close()  # a response is under way: only hang up
            return
        body = json.dumps({"detail": [entry]}).encode()
        head = [STATUS_LINE[status]]
        for name, value in self.server_state.default_headers:
            head += [name, b": ", value, b"\r\n"]
        head += [
            b"content-type: application/json\r\n",
            b"content-length: " + str(len(body)).encode() + b"\r\n",
            b"connection: close\r\n\r\n",
            body,
        ]
        self.transport.write(b"".join(head))
        self.transport.close()

    # --- the protocol's events
    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._addr = self.client[0] if self.client else "?"
        held = self.open_per_client.get(self._addr, 0)
        self._counted = True
        self.open_per_client[self._addr] = held + 1
        if held >= self.max_per_client:
            DROPPED["per_client"] += 1
            msg = f"more than {self.max_per_client} open connections from {self._addr}"
            self._refuse(503, msg, error("connections", f"at most {self.max_per_client}",
                                         held + 1, msg))  # fmt: skip
            return
        self._start_headers()  # a connection that sends nothing is dropped in time too

    def _uncount(self) -> None:
        if self._counted:
            self._counted = False
            n = self.open_per_client.get(self._addr, 1) - 1
            if n > 0:
                self.open_per_client[self._addr] = n
            else:
                self.open_per_client.pop(self._addr, None)

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        self._phase = "closed"
        self._uncount()
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self._phase == "closed":
            return
        if self._phase == "headers":
            self._header_bytes += len(data)
        self._answer = None
        super().data_received(data)
        if self._answer is not None:
            self._refuse(*self._answer)
        elif self._phase == "headers" and self._header_bytes > self.max_header_bytes:
            self._too_large(self._header_bytes)

    def _too_large(self, size: int) -> None:
        DROPPED["header_size"] += 1
        msg = f"request line and headers larger than {self.max_header_bytes} bytes"
        entry = error("headers", f"at most {self.max_header_bytes} bytes", size, msg)
        self._refuse(431, msg, entry)

    def send_400_response(self, msg: str) -> None:
        if self._answer is not None or self._phase == "closed":
            return  # a limit of ours stopped the parser; its answer goes out instead
        text = "a request that is not valid HTTP/1.1 (request line, headers or framing)"
        self._refuse(400, text, error("request", "HTTP/1.1", "", text))

    def handle_websocket_upgrade(self) -> None:
        self._disarm()  # the WebSocket protocol takes the connection from here
        self._phase = "app"
        self._uncount()
        super().handle_websocket_upgrade()

    # --- parser callbacks
    def on_message_begin(self) -> None:
        super().on_message_begin()
        if self._phase != "headers":  # a later request on a kept-alive connection
            self._start_headers()

    def on_headers_complete(self) -> None:
        size = len(self.url) + sum(len(n) + len(v) + 4 for n, v in self.headers) + 16
        if size > self.max_header_bytes:
            DROPPED["header_size"] += 1
            msg = f"request line and headers larger than {self.max_header_bytes} bytes"
            entry = error("headers", f"at most {self.max_header_bytes} bytes", size, msg)
            self._answer = (431, msg, entry)
            raise _Refused(msg)
        self._disarm()
        self._phase = "body"
        self._body_last = self._rate_start = self.loop.time()
        self._body_bytes = self._rate_bytes = 0
        super().on_headers_complete()
        if self._phase == "body":  # not yet complete: the body is due
            self._timer = self.loop.call_later(self.body_timeout, self._body_check)

    def on_body(self, body: bytes) -> None:
        self._body_bytes += len(body)
        self._body_last = self.loop.time()
        super().on_body(body)

    def on_message_complete(self) -> None:
        if self._phase == "body":
            self._disarm()
            self._phase = "app"
        super().on_message_complete()


def guarded_protocol(
    *,
    header_timeout: float,
    body_timeout: float,
    body_min_rate: float,
    max_header_bytes: int,
    max_per_client: int = GuardedHttpToolsProtocol.max_per_client,
) -> type[GuardedHttpToolsProtocol]:
    """A :class:`GuardedHttpToolsProtocol` subclass with these limits (for
    ``uvicorn.Config(http=...)``)."""
    return type(
        "CutwatchHttpProtocol",
        (GuardedHttpToolsProtocol,),
        {
            "header_timeout": float(header_timeout),
            "body_timeout": float(body_timeout),
            "body_min_rate": float(body_min_rate),
            "max_header_bytes": int(max_header_bytes),
            "max_per_client": int(max_per_client),
            "open_per_client": {},
        },
    )


class WebSocketProtocol(WebSocketsSansIOProtocol):
    """uvicorn's websockets-sansio WebSocket protocol, counting the handshake as done once
    a denial response has been sent.

    A refused upgrade (the Guard's 401/403 with the error body, sent through ASGI's
    ``websocket.http.response`` extension) leaves uvicorn 0.54's ``handshake_complete``
    false, so every refusal is also logged at ERROR as "ASGI callable returned without
    completing handshake" (uvicorn's wsproto implementation marks it done; the same fix
    is proposed upstream, Kludex/uvicorn pull request 3138). A refusal is an answer, not
    an error of the process.
    """

    async def send(self, message: Any) -> None:
        await super().send(message)
        if message["type"] == "websocket.http.response.body" and not message.get("more_body"):
            self.handshake_complete = True
