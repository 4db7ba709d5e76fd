"""``/viser/``: the viser 3D view through the app's origin, behind the app's session.

viser listens on 127.0.0.1 only (:data:`server.service.viser_scene.VISER_HOST`) and has
no authentication of its own. The browser loads its page from ``/viser/`` and the page
opens its WebSocket on ``/viser`` (viser's client connects to the address it was loaded
from, without the final slash); both pass the app's middleware first (Host, Origin, a
viewer's session or token: ``server.service.middleware.Guard``), and the WebSocket is
relayed here to viser's.

The relay drops any message from the browser that asks viser for a share URL
(``ShareUrlRequest``/``ShareUrlDisconnect``; viser would open a public tunnel out of the
shop network), on top of the handlers removed in viser itself
(:func:`server.service.viser_scene.disable_share`).

The page may be framed by the dashboard (same origin only): its answers carry
``X-Frame-Options: SAMEORIGIN`` and ``frame-ancestors 'self'`` instead of the app's
``DENY``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from typing import Any
from urllib.parse import quote

import websockets
from fastapi import APIRouter, HTTPException, Request, WebSocket
from fastapi.responses import RedirectResponse, Response
from starlette.websockets import WebSocketDisconnect
from websockets.asyncio.client import connect

from server.service import auth
from server.service.viser_scene import VISER_HOST

router = APIRouter()
log = logging.getLogger("cutwatch.viser")

#: the names of viser's share messages, as they appear in any msgpack encoding of them
SHARE_MESSAGES = (b"ShareUrlRequest", b"ShareUrlDisconnect")
#: largest answer taken from viser's HTTP side (its page is ~0.8 MB) [bytes]
MAX_PAGE_BYTES = 16 << 20
#: largest message relayed from viser to the browser (viser's own limit is 50 MB) [bytes]
MAX_MESSAGE_BYTES = 64 << 20
UPSTREAM_TIMEOUT_S = 10.0
#: headers of the proxied page: framed by this origin's dashboard only
FRAME_HEADERS = {
    "x-frame-options": "SAMEORIGIN",
    "content-security-policy": "frame-ancestors 'self'; object-src 'none'; base-uri 'none'",
    "cache-control": "no-store",
}


def _viser_port(app: Any) -> int:
    """The running viser's port, or a 404 when the view is off."""
    loop = getattr(app.state, "loop", None)
    scene = getattr(loop, "scene", None)
    if scene is None:
        raise HTTPException(404, "the viser 3D view is not running (started with --no-viser?)")
    port: int = scene.port
    return port


async def fetch(port: int, path: str, accept_encoding: str) -> tuple[int, dict[str, str], bytes]:
    """GET ``path`` from viser's HTTP side: status, headers (lower-case), body.

    One HTTP/1.1 request with ``Connection: close``; viser (the ``websockets`` server)
    answers with a ``Content-Length`` and closes.
    """
    reader, writer = await asyncio.wait_for(
        asyncio.open_connection(VISER_HOST, port), UPSTREAM_TIMEOUT_S
    )
    try:
        writer.write(
            f"GET {path} HTTP/1.1\r\nHost: {VISER_HOST}:{port}\r\n"
            f"Accept-Encoding: {accept_encoding}\r\nConnection: close\r\n\r\n".encode("latin-1")
        )
        await writer.drain()
        raw = await asyncio.wait_for(reader.read(MAX_PAGE_BYTES + 65536), UPSTREAM_TIMEOUT_S)
        while len(raw) <= MAX_PAGE_BYTES:
            more = await asyncio.wait_for(reader.read(65536), UPSTREAM_TIMEOUT_S)
            if not more:
                break
            raw += more
    finally:
        writer.close()
        with contextlib.suppress(OSError):
            await writer.wait_closed()
    if len(raw) > MAX_PAGE_BYTES:
        raise HTTPException(502, f"the viser 3D view answered more than {MAX_PAGE_BYTES} bytes")
    head, sep, body = raw.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    if not sep or len(lines[0].split(" ")) < 2:
        raise HTTPException(502, "the viser 3D view answered something that is not HTTP")
    status = int(lines[0].split(" ")[1])
    headers = {}
    for line in lines[1:]:
        k, _, v = line.partition(":")
        headers[k.strip().lower()] = v.strip()
    n = headers.get("content-length")
    if n is not None and n.isdigit():
        body = body[: int(n)]
    return status, headers, body


@router.get("/viser", include_in_schema=False)
async def viser_root() -> RedirectResponse:
    return RedirectResponse("/viser/", status_code=308)


@router.get("/viser/{path:path}", include_in_schema=False)
async def viser_page(request: Request, path: str) -> Response:
    """viser's page (and any file it serves) from its loopback port."""
    port = _viser_port(request.app)
    if ".." in path.split("/"):
        raise HTTPException(404, "no such file of the viser 3D view")
    gzip = "gzip" if "gzip" in request.headers.get("accept-encoding", "") else "identity"
    try:
        status, headers, body = await fetch(port, "/" + quote(path, safe="/._-~"), gzip)
    except (OSError, TimeoutError) as exc:
        raise HTTPException(502, f"the viser 3D view did not answer ({exc})") from None
    if status != 200:
        raise HTTPException(404 if status == 404 else 502, f"viser answered {status} for /{path}")
    out = {k: v for k, v in headers.items() if k in ("content-type", "content-encoding")}
    return Response(body, status_code=200, headers={**out, **FRAME_HEADERS})


@router.websocket("/viser")  # where viser's page connects (its URL without the slash)
@router.websocket("/viser/{path:path}")
async def viser_socket(ws: WebSocket, path: str = "") -> None:
    """The page's WebSocket, relayed to viser's (message for message, both ways)."""
    if await auth.admit(ws, "viewer") is None:  # the middleware checked too
        return
    try:
        port = _viser_port(ws.app)
    except HTTPException:
        await ws.close(1011, "the viser 3D view is not running")
        return
    offered = [p for p in ws.scope.get("subprotocols", []) if p.startswith("viser-")]
    try:
        upstream = await connect(
            f"ws://{VISER_HOST}:{port}/",
            subprotocols=offered or None,
            max_size=MAX_MESSAGE_BYTES,
            compression=None,
            open_timeout=UPSTREAM_TIMEOUT_S,
            proxy=None,
        )
    except (OSError, TimeoutError, websockets.exceptions.InvalidHandshake) as exc:
        log.warning("viser WebSocket did not open: %s", exc)
        await ws.close(1011, "the viser 3D view did not answer")
        return
    await ws.accept(subprotocol=upstream.subprotocol)
    dropped = 0

    async def browser_to_viser() -> None:
        nonlocal dropped
        while True:
            msg = await ws.receive()
            if msg["type"] == "websocket.disconnect":
                return
            data = msg.get("bytes")
            if data is None:
                data = (msg.get("text") or "").encode()
            if any(name in data for name in SHARE_MESSAGES):
                dropped += 1
                log.warning("viser share request from %s dropped", ws.client)
                continue
            await upstream.send(msg["bytes"] if msg.get("bytes") is not None else msg["text"])

    async def viser_to_browser() -> None:
        async for m in upstream:
            if isinstance(m, bytes):
                await ws.send_bytes(m)
            else:
                await ws.send_text(m)

    tasks = [asyncio.create_task(browser_to_viser()), asyncio.create_task(viser_to_browser())]
    try:
        _, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        for t in pending:
            t.cancel()
        for t in tasks:
            with contextlib.suppress(
                asyncio.CancelledError, WebSocketDisconnect, RuntimeError,
                websockets.exceptions.ConnectionClosed,
            ):  # fmt: skip
                await t
    finally:
        await upstream.close()
        with contextlib.suppress(RuntimeError):
            await ws.close()
