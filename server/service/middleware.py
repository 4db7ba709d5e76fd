"""ASGI middleware of the service."""

from __future__ import annotations

import json
from collections.abc import MutableMapping
from typing import Any

from starlette.types import ASGIApp, Receive, Scope, Send

from server.service.errors import error

Message = MutableMapping[str, Any]


class BodyLimit:
    """ASGI middleware refusing request bodies larger than ``limit`` bytes (413).

    Checks ``Content-Length`` up front and counts streamed (chunked) bodies as they
    arrive. The 413 has the service's one error body (``server.service.errors``).
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
